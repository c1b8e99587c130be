"""One depth model run in either runtime: :class:`Predictor`, a model in torch or its exported graphs in onnxruntime
behind one set of calls.

A predictor computes the depth of batches (:meth:`Predictor.depth`) and, for videos, tracks it between key frames
with the band the model offers (:meth:`Predictor.track` around a :class:`~prismstereo.classical.BandPrior`, which
:meth:`Predictor.band_prior` makes of a key frame's result). In torch the band is the model's ``tracker``
(:class:`~prismstereo.classical.TemporalDepth`); in onnxruntime it is that band's exported graph. The ONNX backend
takes its graphs from the cache (:func:`~prismstereo.export.cached_graphs`): a model asked for by its
:class:`~prismstereo.models.ModelSpec` is then served without building the torch model. Deployed graph files open
with :meth:`Predictor.from_graphs`.

A predictor pickles as what it runs (the torch model, or the graphs' paths): a worker process or a Ray actor opens
its own sessions (:meth:`Predictor.for_process`). :class:`~prismstereo.stream.DepthStream` and the jobs
(:class:`~prismstereo.jobs.Pipeline`) each hold one predictor; its threads come from
:func:`~prismstereo.threads.thread_plan`.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from prismstereo.errors import OptionError, check_int, check_option
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.models import DepthModel, ModelSpec
from prismstereo.names import BACKENDS, Backend
from prismstereo.threads import torch_threads

if TYPE_CHECKING:
    from prismstereo.classical import BandPrior, TemporalOptions, TrackedDepth
    from prismstereo.export import GraphFiles, OnnxDepth

__all__ = ["BACKENDS", "Backend", "Predictor"]



class Predictor:
    """A depth model in torch, or its exported graphs in onnxruntime, behind one set of calls.

    Args:
        model: a depth model (:class:`~prismstereo.models.DepthModel`), or what to build
            (:class:`~prismstereo.models.ModelSpec`: with the ONNX backend a cached request runs without building
            the model).
        backend: 'torch' (the module, in inference mode) or 'onnx' (its exported graphs from the cache).
        temporal: for videos, the temporal band's options: the band the model offers
            (:meth:`~prismstereo.models.DepthModel.tracker`, or its graph) tracks between key frames; None: every
            frame on its own. A model without a band tracks nothing (:attr:`temporal` None; the summary says so).
        threads: the cores this predictor runs on: torch's intra-op threads around its calls, and its graphs'
            threads by :func:`~prismstereo.threads.thread_plan`; None: the caller's torch threads, and the
            machine's cores for the graphs.
        spinning: onnxruntime's idle threads spin (see :class:`~prismstereo.export.OnnxDepth`; False where the
            graph shares the cores with other work).
        cache_dir: the ONNX cache (default :func:`~prismstereo.export.cache_directory`).

    Attributes:
        backend: 'torch' or 'onnx'.
        rig: the sensor's rig. z_range: (z_min, z_max) mm.
        temporal: the band's :class:`~prismstereo.classical.TemporalOptions` (``downsample`` resolved) when the
            predictor can track, else None.
        summary: one line: the model and how it tracks videos (:func:`~prismstereo.models.describe_model`).
        cached: its graphs were served by a request the cache remembered (no model was built).
        channels: the input channels a graph takes (1 or 3), None in torch (either).

    Raises:
        OptionError: an unknown backend, bad threads or temporal options, a model that is not a depth model.

    Example:
        >>> from prismstereo.models import build_model
        >>> predictor = Predictor(build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0)))
        >>> predictor.depth(torch.rand(2, 1, 48, 64)).depth.shape, predictor.backend
        (torch.Size([2, 1, 48, 32]), 'torch')
    """

    def __init__(self, model: DepthModel | ModelSpec, *, backend: Backend = "torch",
                 temporal: TemporalOptions | None = None, threads: int | None = None, spinning: bool = True,
                 cache_dir: str | Path | None = None) -> None:
        from prismstereo.classical import TemporalOptions

        check_option(backend, BACKENDS, "backend")
        check_int(threads, "threads", 1, none=True)
        if temporal is not None and not isinstance(temporal, TemporalOptions):
            raise OptionError(f"temporal must be None or TemporalOptions, got {type(temporal).__name__}")
        if not isinstance(model, (ModelSpec, DepthModel)):
            raise OptionError(f"model must be a depth model (prismstereo.models.DepthModel) or a ModelSpec, got "
                              f"{type(model).__name__}")
        self.backend, self.threads, self.spinning = backend, threads, bool(spinning)
        self._model = self._tracker = self._graphs = None
        if backend == "onnx":
            from prismstereo.export import cached_graphs

            self._attach_graphs(cached_graphs(model, temporal=temporal, cache_dir=cache_dir))
            return
        from prismstereo.models import describe_model

        built = model.build() if isinstance(model, ModelSpec) else model.eval()
        self._model = built
        self._tracker = None if temporal is None else built.tracker(temporal)
        if self._tracker is not None:
            self._tracker.eval()
        self.summary = describe_model(built, temporal, self._tracker)
        self.rig, self.z_range = built.rig, tuple(float(z) for z in built.z_range)
        self.temporal = None if self._tracker is None else self._tracker.options
        self.channels, self.cached = None, False

    @classmethod
    def from_graphs(cls, graph: str | Path | OnnxDepth, temporal_graph: str | Path | OnnxDepth | None = None, *,
                    threads: int | None = None, spinning: bool = True) -> Predictor:
        """A predictor of deployed graph files (written by :func:`~prismstereo.export.export_onnx`): the per-frame
        graph and, for videos, the temporal graph of the same sensor (an :class:`~prismstereo.export.OnnxDepth`
        given: its file, opened again with the predictor's threads).

        Raises:
            OptionError: a temporal graph as ``graph``, a per-frame one as ``temporal_graph``, or graphs of two
                sensors. ExportError: a file that is not a prismstereo graph.

        Example:
            >>> from prismstereo.export import export_onnx
            >>> from prismstereo.models import build_model
            >>> import tempfile; path = Path(tempfile.mkdtemp()) / "m.onnx"
            >>> model = build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0))
            >>> Predictor.from_graphs(export_onnx(model, path)).depth(torch.rand(1, 1, 48, 64)).depth.shape
            torch.Size([1, 1, 48, 32])
        """
        from prismstereo.export import GraphFiles, OnnxDepth

        check_int(threads, "threads", 1, none=True)
        self = cls.__new__(cls)
        self.backend, self.threads, self.spinning = "onnx", threads, bool(spinning)
        self._model = self._tracker = None
        paths = [None if item is None else Path(item.path if isinstance(item, OnnxDepth) else item)
                 for item in (graph, temporal_graph)]
        self._attach_graphs(GraphFiles(paths[0], "", paths[1]))
        return self

    def _attach_graphs(self, files: GraphFiles) -> None:
        """Open the graphs (:class:`~prismstereo.export.graphs.GraphPredictor` on tensors) and read what the
        predictor is from their metadata."""
        from prismstereo.export.graphs import GraphPredictor

        self._graphs = graphs = GraphPredictor(files, threads=self.threads, spinning=self.spinning, arrays="torch")
        self.summary, self.cached, self.z_range = graphs.summary, graphs.cached, graphs.z_range
        self.rig = BiPrismRig.from_dict(json.loads(graphs.metadata["prismstereo.rig"]))
        self.channels, self.temporal = graphs.channels, graphs.temporal

    @property
    def files(self) -> GraphFiles | None:
        """The graphs' files (ONNX backend: the cache entry, or the deployed files), else None."""
        return None if self._graphs is None else self._graphs.files

    @property
    def image_size(self) -> tuple[int, int]:
        """(H, W) of the sensor's captures."""
        return self.rig.image_height, self.rig.image_width

    @property
    def reference_width(self) -> int:
        """W_ref, the reference half's columns (the outputs' width)."""
        return self.rig.reference_width

    @property
    def model(self) -> DepthModel:
        """The torch model (torch backend only)."""
        if self._model is None:
            raise OptionError("an ONNX predictor has graphs, not a torch model (graph, temporal_graph)")
        return self._model

    @property
    def graph(self) -> OnnxDepth:
        """The per-frame graph's session (ONNX backend only)."""
        if self._graphs is None:
            raise OptionError("a torch predictor has a model, not graphs")
        return self._graphs.graph

    @property
    def temporal_graph(self) -> OnnxDepth | None:
        """The temporal graph's session (ONNX backend with a band), else None."""
        return None if self._graphs is None else self._graphs.temporal_graph

    @property
    def prior_size(self) -> tuple[int, int] | None:
        """(h, w) of the band's :class:`~prismstereo.classical.BandPrior` when the predictor can track, else None."""
        if self.temporal is None:
            return None
        return self._tracker.prior_size if self._tracker is not None else self._graphs.prior_size

    def _torch(self):
        """Around a torch run: inference mode, and the predictor's threads if it has its own."""
        stack = contextlib.ExitStack()
        stack.enter_context(torch.inference_mode())
        if self.threads is not None:
            stack.enter_context(torch_threads(self.threads))
        return stack

    def depth(self, image: torch.Tensor) -> Any:
        """Depth of a batch of captures ``image`` (B, C, H, W) in [0, 1] (colour: its
        :func:`~prismstereo.conventions.to_grey`).

        Returns:
            ``depth``, ``valid``, ``confidence`` (B, 1, H, W_ref) each: the model's
            :class:`~prismstereo.depth.result.DepthResult`, or the graph's
            :class:`~prismstereo.export.OnnxDepthResult`.

        Raises:
            ShapeError: an image of another sensor or channel count, or not floating point.
        """
        if self._graphs is not None:
            return self._graphs.depth(image)
        with self._torch():
            return self._model(torch.from_numpy(image) if isinstance(image, np.ndarray) else image)

    def _band(self) -> Any:
        if self.temporal is None:
            raise OptionError("this predictor has no temporal band: Predictor(model, temporal=TemporalOptions()) "
                              "of a model that offers one (model.tracker)")
        return self._tracker if self._tracker is not None else self._graphs

    def track(self, image: torch.Tensor, prior: BandPrior) -> TrackedDepth:
        """Depth of ``image`` (B, C, H, W) searched around ``prior`` by the temporal band, and the prior it leaves
        for the next frame (:meth:`~prismstereo.classical.TemporalDepth.track`).

        Raises:
            OptionError: a predictor without a band. ShapeError: an image or prior of another size.
        """
        band = self._band()
        if self._graphs is not None:
            return band.track(image, prior)
        with self._torch():
            return band.track(torch.from_numpy(image) if isinstance(image, np.ndarray) else image, prior)

    def band_prior(self, result: Any) -> BandPrior:
        """A full-resolution result (a key frame's ``depth``, ``valid``, ``confidence``) as the band's prior.

        Raises:
            OptionError: a predictor without a band.
        """
        if self._graphs is not None:
            return self._graphs.band_prior(result)
        band = self._band()
        with torch.inference_mode():
            return band.band_prior(result.depth, result.valid, result.confidence)

    def for_process(self, threads: int | None = None) -> Predictor:
        """This predictor for another process (a worker's, after fork or unpickling): the same model, or the same
        graphs in sessions of its own, on ``threads`` cores.

        Example:
            >>> from prismstereo.models import build_model
            >>> predictor = Predictor(build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0)))
            >>> predictor.for_process(1).threads
            1
        """
        twin = Predictor.__new__(Predictor)
        twin.__dict__.update(self.__dict__)
        twin.threads = threads
        if self._graphs is not None:
            twin._graphs = self._graphs.for_process(threads)
        return twin

    def __getstate__(self) -> dict[str, Any]:
        """Pickled as what it runs: the torch model, or the graphs' paths (a process opens its own sessions)."""
        state = dict(self.__dict__)
        if self._graphs is not None:
            state["_graphs"] = self._graphs.for_process(self.threads)
        return state

    def __repr__(self) -> str:
        return f"Predictor({self.backend}: {self.summary})"
