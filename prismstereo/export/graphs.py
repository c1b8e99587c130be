"""A model's exported graphs behind the predictor's calls, without torch: :class:`GraphPredictor`.

It is what :class:`~prismstereo.predictor.Predictor` runs with the ONNX backend (on tensors), and what a host that
deploys the graphs alone runs on numpy arrays: ``prismstereo depth --backend onnx`` serves a request it exported
before (:func:`~prismstereo.export.index.recall`) through it, and then imports neither torch nor the models: numpy,
OpenCV and onnxruntime (``docs/usage.md``, *Deploying without torch*).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from prismstereo.errors import OptionError, check_int
from prismstereo.export.index import GraphFiles, describe_graph
from prismstereo.export.session import Arrays, OnnxDepth, OnnxDepthResult, as_array
from prismstereo.names import OUTPUT_NAMES
from prismstereo.threads import thread_plan

__all__ = ["GraphPredictor"]


class GraphPredictor:
    """A model's exported graphs in onnxruntime: the per-frame graph and, for videos, the temporal band's graph,
    behind the calls of :class:`~prismstereo.predictor.Predictor` (``depth``, ``track``, ``band_prior``).

    Args:
        graph: the per-frame graph (a file written by :func:`~prismstereo.export.export_onnx`, or its cache entry's
            :class:`~prismstereo.export.GraphFiles`, which may name the temporal graph, the summary and whether it
            was served from the cache).
        temporal_graph: the temporal graph of the same sensor (with a path ``graph``), or None.
        threads: the cores it runs on (:func:`~prismstereo.threads.thread_plan`: the per-frame graph on all, the
            temporal graph on one); None: the machine's.
        spinning: onnxruntime's idle threads spin (:class:`~prismstereo.export.OnnxDepth`).
        arrays: 'numpy' (default: arrays in, arrays out, no torch) or 'torch' (tensors out).

    Attributes:
        backend: 'onnx'. summary: the model's line. cached: served by a remembered request.
        metadata: the per-frame graph's ``prismstereo.*`` metadata.
        image_size: (H, W) of the sensor. reference_width: W_ref, the reference half's columns.
        z_range: (z_min, z_max) mm. channels: the input channels (1 or 3).
        temporal: the band's :class:`~prismstereo.classical.TemporalOptions` when it can track, else None.
        files: the graphs' :class:`~prismstereo.export.GraphFiles`.

    Raises:
        OptionError: a temporal graph as ``graph``, a per-frame one as ``temporal_graph``, graphs of two sensors.
        ExportError: a file that is not a prismstereo graph.

    Example:
        >>> predictor = GraphPredictor("depth.onnx")  # doctest: +SKIP
        >>> predictor.depth(np.zeros((1, 1, 768, 1024), np.float32)).depth.shape  # doctest: +SKIP
        (1, 1, 768, 512)
    """

    backend = "onnx"

    def __init__(self, graph: str | Path | GraphFiles, temporal_graph: str | Path | None = None, *,
                 threads: int | None = None, spinning: bool = True, arrays: Arrays = "numpy") -> None:
        check_int(threads, "threads", 1, none=True)
        if isinstance(graph, GraphFiles):
            if temporal_graph is not None:
                raise OptionError("the temporal graph of a GraphFiles is its own (files.temporal)")
            files = graph
        else:
            files = GraphFiles(Path(graph), "", None if temporal_graph is None else Path(temporal_graph))
        self.threads, self.spinning, self.arrays = threads, bool(spinning), arrays
        self.files = files
        self._sessions: dict[str, OnnxDepth] = {}
        main = self.graph
        if main.temporal is not None:
            raise OptionError(f"{files.path.name} is a temporal graph: pass it as temporal_graph")
        self.metadata = main.metadata
        self.summary, self.cached = files.summary or describe_graph(main.metadata), files.cached
        self.z_range = main.z_range
        self.channels, height, width = main.input_shape
        self.image_size = (height, width)
        self.reference_width = int(main.session.get_outputs()[OUTPUT_NAMES.index("depth_mm")].shape[-1])
        self.temporal = None
        if files.temporal is not None:
            band = self.temporal_graph
            if band.temporal is None:
                raise OptionError(f"{files.temporal.name} is a per-frame graph, not a temporal one")
            if band.input_shape[1:] != main.input_shape[1:]:
                raise OptionError(f"the temporal graph takes {band.input_shape}, the graph {main.input_shape}")
            self.temporal = band.temporal

    def _session(self, name: str) -> OnnxDepth:
        """The graph ``name`` ('graph' or 'temporal') in onnxruntime, opened on first use in this process."""
        if name not in self._sessions:
            plan = thread_plan(cores=self.threads)
            path = self.files.path if name == "graph" else self.files.temporal
            count = plan.graph if name == "graph" else plan.temporal_graph
            self._sessions[name] = OnnxDepth(path, threads=count, spinning=self.spinning, arrays=self.arrays)
        return self._sessions[name]

    @property
    def graph(self) -> OnnxDepth:
        """The per-frame graph's session."""
        return self._session("graph")

    @property
    def temporal_graph(self) -> OnnxDepth | None:
        """The temporal graph's session, None without one."""
        return None if self.files.temporal is None else self._session("temporal")

    @property
    def prior_size(self) -> tuple[int, int] | None:
        """(h, w) of the band's :class:`~prismstereo.classical.BandPrior` when it can track, else None."""
        return None if self.temporal is None else self.temporal_graph.prior_size

    @property
    def dense(self) -> bool:
        """Whether the model writes a depth wherever it has one (a classical model's ``validity.dense``, from the
        graph's metadata), not only where it is valid; False for the other models."""
        config = json.loads(self.metadata.get("prismstereo.config", "{}")).get("config")
        return bool(isinstance(config, dict) and config.get("validity", {}).get("dense", False))

    @property
    def rig(self):
        """The :class:`~prismstereo.geometry.rig.BiPrismRig` of the graphs (from their metadata; imports torch)."""
        return self.graph.rig

    def _input(self, image: Any) -> Any:
        """A graph's input: a colour batch converted to grey for a one-channel graph (the models' rule)."""
        if self.channels != 1 or getattr(image, "ndim", 0) != 4 or image.shape[1] != 3:
            return image
        if hasattr(image, "detach"):  # a tensor: the models' own conversion
            from prismstereo.conventions import to_grey

            return to_grey(image)
        from prismstereo.io import grey_array

        return grey_array(as_array(image).astype("float32", copy=False))

    def depth(self, image: Any) -> OnnxDepthResult:
        """Depth of a batch ``image`` (B, C, H, W) in [0, 1] (colour: its grey for a one-channel graph).

        Returns:
            OnnxDepthResult(depth, valid, confidence), (B, 1, H, W_ref) each.

        Raises:
            ShapeError: an image of another sensor or channel count, or not floating point.
        """
        return self.graph(self._input(image))

    def _band(self) -> OnnxDepth:
        if self.temporal is None:
            raise OptionError("these graphs have no temporal band: export the model with temporal options "
                              "(export_onnx(model, path, temporal=TemporalOptions())) and pass the temporal graph")
        return self.temporal_graph

    def track(self, image: Any, prior: Any) -> Any:
        """Depth of ``image`` (B, C, H, W) searched around ``prior`` by the temporal graph, and the prior it leaves
        for the next frame (:meth:`~prismstereo.export.OnnxDepth.track`).

        Raises:
            OptionError: graphs without a band. ShapeError: an image or prior of another size.
        """
        return self._band().track(self._input(image), prior)

    def band_prior(self, result: Any) -> Any:
        """A full-resolution result (a key frame's ``depth``, ``valid``, ``confidence``) as the band's prior.

        Raises:
            OptionError: graphs without a band.
        """
        return self._band().band_prior(result.depth, result.valid, result.confidence)

    def for_process(self, threads: int | None = None) -> GraphPredictor:
        """These graphs for another process (sessions of its own) on ``threads`` cores.

        Example:
            >>> GraphPredictor("depth.onnx").for_process(1).threads  # doctest: +SKIP
            1
        """
        twin = GraphPredictor.__new__(GraphPredictor)
        twin.__dict__.update(self.__getstate__())
        twin.threads = threads
        return twin

    def __getstate__(self) -> dict[str, Any]:
        """Pickled as the graphs' paths: a process opens its own sessions."""
        return {**self.__dict__, "_sessions": {}}

    def __repr__(self) -> str:
        return f"GraphPredictor({self.summary})"

