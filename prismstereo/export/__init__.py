"""ONNX deployment of the depth models: :func:`export_onnx` and the graphs' metadata (:mod:`~prismstereo.export.graph`),
:class:`OnnxDepth`, a graph in onnxruntime (:mod:`~prismstereo.export.session`), :class:`GraphPredictor`, a model's
graphs without torch (:mod:`~prismstereo.export.graphs`), and the cache of exported graphs, request -> graphs
(:func:`cached_graphs`, :mod:`~prismstereo.export.cache`, its index without torch in :mod:`~prismstereo.export.index`).
Models run in either runtime through :class:`~prismstereo.predictor.Predictor`."""

from prismstereo.lazy import lazy_names

__all__ = ["DEFAULT_OPSET", "NEXT_PRIOR_NAMES", "OPTIMIZATIONS", "PRIOR_NAMES", "DepthGraph", "ExportError",
           "GraphFiles", "GraphPredictor", "OnnxDepth", "OnnxDepthResult", "TemporalGraph", "cache_directory",
           "cache_path", "cached_graphs", "describe_graph", "export_cached", "export_onnx", "graph_metadata", "recall",
           "remember", "request_key", "source_digest"]


_LAZY = {
    **dict.fromkeys(["GraphFiles", "cache_directory", "describe_graph", "recall", "remember", "request_key",
                     "source_digest"], "prismstereo.export.index"),
    **dict.fromkeys(["cache_path", "cached_graphs", "export_cached"], "prismstereo.export.cache"),
    **dict.fromkeys(["DEFAULT_OPSET", "NEXT_PRIOR_NAMES", "PRIOR_NAMES", "DepthGraph", "ExportError", "TemporalGraph",
                     "export_onnx", "graph_metadata"], "prismstereo.export.graph"),
    **dict.fromkeys(["OPTIMIZATIONS", "OnnxDepth", "OnnxDepthResult"], "prismstereo.export.session"),
    "GraphPredictor": "prismstereo.export.graphs",
}


__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
