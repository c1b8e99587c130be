"""ONNX deployment of the depth model: :func:`export_onnx`, :class:`OnnxDepth`, :func:`onnx_session`
(see :mod:`prismstereo.export.onnx`, whose ``__all__`` is this package's)."""

from prismstereo.export.onnx import *  # noqa: F403 (the one module's public names, listed once, in its __all__)
from prismstereo.export.onnx import __all__  # noqa: F401
