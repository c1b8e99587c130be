"""ONNX deployment of the depth models: :func:`export_onnx` and the graphs' metadata (:mod:`~prismstereo.export.graph`),
:class:`OnnxDepth`, a graph in onnxruntime (:mod:`~prismstereo.export.session`), and the cache of exported graphs,
request -> graphs (:func:`cached_graphs`, :mod:`~prismstereo.export.cache`, its index without torch in
:mod:`~prismstereo.export.index`). Models run in either runtime through :class:`~prismstereo.predictor.Predictor`."""

import importlib

__all__ = ["DEFAULT_OPSET", "NEXT_PRIOR_NAMES", "OPTIMIZATIONS", "PRIOR_NAMES", "DepthGraph", "ExportError",
           "GraphFiles", "OnnxDepth", "OnnxDepthResult", "TemporalGraph", "cache_directory", "cache_path",
           "cached_graphs", "describe_graph", "export_cached", "export_onnx", "graph_metadata", "recall", "remember",
           "request_key", "source_digest"]


_LAZY = {
    **dict.fromkeys(["GraphFiles", "cache_directory", "recall", "remember", "request_key", "source_digest"],
                    "prismstereo.export.index"),
    **dict.fromkeys(["cache_path", "cached_graphs", "export_cached"], "prismstereo.export.cache"),
    **dict.fromkeys(["DEFAULT_OPSET", "NEXT_PRIOR_NAMES", "PRIOR_NAMES", "DepthGraph", "ExportError", "TemporalGraph",
                     "describe_graph", "export_onnx", "graph_metadata"], "prismstereo.export.graph"),
    **dict.fromkeys(["OPTIMIZATIONS", "OnnxDepth", "OnnxDepthResult"], "prismstereo.export.session"),
}


def __getattr__(name: str):
    """The names, imported on first use (PEP 562): the cache's index (:mod:`~prismstereo.export.index`) needs no
    torch, the exporter and the session do."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'prismstereo.export' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
