"""ONNX deployment of the depth models: :func:`export_onnx` and the graphs' metadata (:mod:`~prismstereo.export.graph`),
:class:`OnnxDepth`, a graph in onnxruntime (:mod:`~prismstereo.export.session`), and the cache of exported graphs,
request -> graphs (:func:`cached_graphs`, :mod:`~prismstereo.export.cache`). Models run in either runtime through
:class:`~prismstereo.predictor.Predictor`."""

from prismstereo.export.cache import (
    GraphFiles,
    cache_directory,
    cache_path,
    cached_graphs,
    export_cached,
    recall,
    remember,
    request_key,
)
from prismstereo.export.graph import (
    DEFAULT_OPSET,
    NEXT_PRIOR_NAMES,
    PRIOR_NAMES,
    DepthGraph,
    ExportError,
    TemporalGraph,
    describe_graph,
    export_onnx,
    graph_metadata,
    source_digest,
)
from prismstereo.export.session import OPTIMIZATIONS, OnnxDepth, OnnxDepthResult

__all__ = ["DEFAULT_OPSET", "NEXT_PRIOR_NAMES", "OPTIMIZATIONS", "PRIOR_NAMES", "DepthGraph", "ExportError",
           "GraphFiles", "OnnxDepth", "OnnxDepthResult", "TemporalGraph", "cache_directory", "cache_path",
           "cached_graphs", "describe_graph", "export_cached", "export_onnx", "graph_metadata", "recall", "remember",
           "request_key", "source_digest"]
