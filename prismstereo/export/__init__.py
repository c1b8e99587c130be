"""ONNX deployment of the depth model: :func:`export_onnx`, :class:`OnnxDepth` (:mod:`prismstereo.export.onnx`), and
the cache of exported graphs, :func:`onnx_session` (:mod:`prismstereo.export.cache`); this package's names are
theirs ``__all__``."""

from prismstereo.export import cache, onnx
from prismstereo.export.cache import *  # noqa: F403 (each module's public names, listed once, in its __all__)
from prismstereo.export.onnx import *  # noqa: F403

__all__ = [*onnx.__all__, *cache.__all__]
