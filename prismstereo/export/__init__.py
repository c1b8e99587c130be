"""ONNX deployment of the depth model: :func:`export_onnx`, :class:`OnnxDepth`, :func:`onnx_session`
(see :mod:`prismstereo.export.onnx`)."""

from prismstereo.export.onnx import (
    DEFAULT_OPSET,
    DepthGraph,
    ExportError,
    OnnxDepth,
    OnnxDepthResult,
    cache_directory,
    describe,
    export_onnx,
    onnx_session,
)

__all__ = [
    "DEFAULT_OPSET",
    "DepthGraph",
    "ExportError",
    "OnnxDepth",
    "OnnxDepthResult",
    "cache_directory",
    "describe",
    "export_onnx",
    "onnx_session",
]
