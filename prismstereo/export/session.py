"""An exported depth graph in onnxruntime: :class:`OnnxDepth`, the session that runs a file written by
:func:`~prismstereo.export.graph.export_onnx` and checks its inputs (2 intra-op threads, 1 inter-op thread, all
graph optimisations by default). :class:`~prismstereo.predictor.Predictor` runs a model's graphs through it; an
application that deploys the file alone may use it directly.

It imports without torch: with ``arrays='numpy'`` it takes and returns numpy arrays, and a process that only runs
graphs (:class:`~prismstereo.export.graphs.GraphPredictor`) never imports torch; with ``arrays='torch'`` (default)
its results are torch tensors.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np

from prismstereo.errors import ExportError, OptionError, ShapeError, check_int, check_option
from prismstereo.names import INPUT_NAME, NEXT_PRIOR_NAMES, OUTPUT_NAMES, PRIOR_NAMES
from prismstereo.threads import thread_plan

if TYPE_CHECKING:
    from prismstereo.classical import BandPrior, TrackedDepth

__all__ = ["ARRAYS", "OPTIMIZATIONS", "OnnxDepth", "OnnxDepthResult"]

Optimization = Literal["all", "extended", "basic", "disable"]
OPTIMIZATIONS: tuple[str, ...] = ("all", "extended", "basic", "disable")
Arrays = Literal["torch", "numpy"]
ARRAYS: tuple[str, ...] = ("torch", "numpy")


def as_array(x: Any) -> np.ndarray:
    """A torch tensor (any device) or array-like as a numpy array (a CPU tensor's memory, not a copy)."""
    if hasattr(x, "detach"):  # a torch tensor, without importing torch
        return x.detach().cpu().numpy()
    return np.asarray(x)


class OnnxDepthResult(NamedTuple):
    """Outputs of the exported graph: torch tensors, or numpy arrays from a session with ``arrays='numpy'``.

    Attributes:
        depth: (B, 1, H, W_ref) depth Z (mm) of the reference half; meaningless where not valid.
        valid: (B, 1, H, W_ref) bool.
        confidence: (B, 1, H, W_ref) in [0, 1].
    """

    depth: Any
    valid: Any
    confidence: Any


class OnnxDepth:
    """An exported depth graph in an ``onnxruntime.InferenceSession``.

    Args:
        path: a file written by :func:`~prismstereo.export.graph.export_onnx`.
        threads: intra-op threads (inter-op: 1); None: :func:`~prismstereo.threads.thread_plan`'s for this graph
            (all the process's cores for a per-frame graph, one for a temporal graph).
        optimization: onnxruntime graph optimisation level: 'all' (default), 'extended', 'basic', 'disable'.
        spinning: let idle intra-op threads spin for work (onnxruntime's default) instead of sleeping. Spinning
            wins when the cores are the graph's alone and loses when other processes want them (``docs/design.md``,
            *How the model picks its defaults*, implementation choices): pass False where the depth graph shares
            the CPU (an endoscope application's other threads).
        arrays: what the results are: 'torch' tensors (default) or 'numpy' arrays (torch never imported).

    Attributes:
        metadata: the ``prismstereo.*`` metadata_props (str -> str).
        input_shape: (C, H, W) the graph expects.
        load_seconds: time to build the session.
        temporal: a temporal graph's :class:`~prismstereo.classical.prior.TemporalOptions` (``downsample``
            resolved; it takes a prior: :meth:`track`), None for the per-frame graph.
        prior_size: a temporal graph's (h, w) of its :class:`~prismstereo.classical.prior.BandPrior`, None for the
            per-frame graph.

    Raises:
        ExportError: missing file, not an ONNX model, or not exported by prismstereo.

    Example:
        >>> from prismstereo.export import export_onnx
        >>> from prismstereo.models import build_model
        >>> import tempfile; out = Path(tempfile.mkdtemp()) / "m.onnx"
        >>> graph = OnnxDepth(export_onnx(build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0)), out))
        >>> graph(torch.rand(2, 1, 48, 64)).depth.shape
        torch.Size([2, 1, 48, 32])
    """

    def __init__(self, path: str | Path, *, threads: int | None = None, optimization: Optimization = "all",
                 spinning: bool = True, arrays: Arrays = "torch") -> None:
        import onnxruntime as ort

        check_option(optimization, OPTIMIZATIONS, "optimization")
        check_option(arrays, ARRAYS, "arrays")
        check_int(threads, "threads", 1, none=True)
        self.path, self.arrays = Path(path), arrays
        if not self.path.is_file():
            raise ExportError(f"ONNX model not found: {self.path}")
        if threads is None:  # the plan's count for the graph's kind (reading its inputs costs an onnx import)
            plan = thread_plan()
            threads = plan.temporal_graph if _is_temporal(self.path) else plan.graph
        self.threads = threads
        options = ort.SessionOptions()
        options.intra_op_num_threads = self.threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # the exporter's stale intermediate shape annotations only warn
        options.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
        options.graph_optimization_level = {
            "all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
            "extended": ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED,
            "basic": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
            "disable": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
        }[optimization]
        t0 = time.perf_counter()
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ExportError(f"onnxruntime cannot load {self.path}: {exc}") from exc
        self.load_seconds = time.perf_counter() - t0
        meta = self.session.get_modelmeta().custom_metadata_map
        self.metadata = {k: v for k, v in meta.items() if k.startswith("prismstereo.")}
        if "prismstereo.input_shape" not in self.metadata:
            raise ExportError(f"{self.path} was not exported by prismstereo (no prismstereo.* metadata)")
        names = [i.name for i in self.session.get_inputs()]
        if names not in ([INPUT_NAME], [INPUT_NAME, *PRIOR_NAMES]):
            raise ExportError(f"{self.path} must have the input {INPUT_NAME!r} (and a temporal graph "
                              f"{', '.join(PRIOR_NAMES)}), got {', '.join(names)}")
        self.input_shape = tuple(int(d) for d in json.loads(self.metadata["prismstereo.input_shape"])[1:])
        self.temporal = self.prior_size = None
        if len(names) > 1:
            from prismstereo.classical.prior import TemporalOptions

            self.temporal = TemporalOptions(**json.loads(self.metadata.get("prismstereo.temporal", "{}")))
            self.prior_size = tuple(int(d) for d in self.session.get_inputs()[1].shape[2:])

    @property
    def rig(self):
        """The :class:`~prismstereo.geometry.rig.BiPrismRig` the graph was exported for (from its metadata)."""
        from prismstereo.geometry.rig import BiPrismRig

        return BiPrismRig.from_dict(json.loads(self.metadata["prismstereo.rig"]))

    @property
    def z_range(self) -> tuple[float, float]:
        """The depth range (mm) the graph searches (from its metadata)."""
        low, high = json.loads(self.metadata["prismstereo.z_range_mm"])
        return float(low), float(high)

    def _image(self, image: Any) -> np.ndarray:
        """The graph's float32 input from (B, C, H, W) ``image``, checked."""
        array = as_array(image)
        if array.ndim != 4 or tuple(array.shape[1:]) != self.input_shape:
            c, h, w = self.input_shape
            raise ShapeError(f"image must have shape (B, {c}, {h}, {w}) for {self.path.name}, "
                             f"got {tuple(array.shape)}")
        if not np.issubdtype(array.dtype, np.floating):
            raise ShapeError(f"image must be floating point in [0, 1], got dtype {array.dtype}")
        return np.ascontiguousarray(array, dtype=np.float32)

    def _kind(self, temporal: bool) -> None:
        if (self.temporal is not None) != temporal:
            raise OptionError(f"{self.path.name} is a {'temporal' if self.temporal else 'per-frame'} graph: "
                              f"{'track(image, prior)' if self.temporal else 'call it on the image alone'}")

    def _out(self, *arrays: np.ndarray) -> tuple[Any, ...]:
        """The graph's outputs as the arrays this runner returns (``arrays``), bool masks as bool."""
        if self.arrays == "numpy":
            return arrays
        import torch

        return tuple(torch.from_numpy(a) for a in arrays)

    def __call__(self, image: Any) -> OnnxDepthResult:
        """Depth of a batch ``image`` (B, C, H, W) in [0, 1] (any float dtype; run in float32) by a per-frame graph.

        Raises:
            ShapeError: an image of another shape, or not floating point.
            OptionError: a temporal graph (:meth:`track`).
        """
        self._kind(False)
        depth, valid, confidence = self.session.run(list(OUTPUT_NAMES), {INPUT_NAME: self._image(image)})
        return OnnxDepthResult(*self._out(depth, valid.astype(bool, copy=False), confidence))

    def track(self, image: Any, prior: BandPrior) -> TrackedDepth:
        """Depth of ``image`` (B, C, H, W) searched around ``prior`` by a temporal graph, as
        :meth:`~prismstereo.classical.temporal.TemporalDepth.track`.

        Args:
            image: (B, C, H, W) in [0, 1] (any float dtype; run in float32).
            prior: a :class:`~prismstereo.classical.prior.BandPrior`, (B, 1, h, w) each (:attr:`prior_size`).

        Returns:
            TrackedDepth(OnnxDepthResult of (B, 1, H, W_ref) tensors or arrays, the next frame's BandPrior).

        Raises:
            ShapeError: an image or prior of another shape.
            OptionError: a per-frame graph.
        """
        from prismstereo.classical.prior import BandPrior, TrackedDepth

        self._kind(True)
        feed = {INPUT_NAME: self._image(image)}
        shape = (feed[INPUT_NAME].shape[0], 1, *self.prior_size)
        for name, t, dtype in zip(PRIOR_NAMES, prior, (np.float32, np.bool_), strict=True):
            value = as_array(t)
            if tuple(value.shape) != shape:
                raise ShapeError(f"{name} must have shape {shape}, got {tuple(value.shape)}")
            feed[name] = np.ascontiguousarray(value, dtype=dtype)
        depth, valid, confidence, inverse, placed = self.session.run([*OUTPUT_NAMES, *NEXT_PRIOR_NAMES], feed)
        depth, valid, confidence, inverse, placed = self._out(depth, valid.astype(bool, copy=False), confidence,
                                                              inverse, placed.astype(bool, copy=False))
        return TrackedDepth(OnnxDepthResult(depth, valid, confidence), BandPrior(inverse, placed))

    def band_prior(self, depth: Any, valid: Any, confidence: Any) -> BandPrior:
        """A full-resolution result (B, 1, H, W_ref) each (a key frame's) as a temporal graph's prior
        (:func:`~prismstereo.classical.prior.band_prior` with the graph's range, options and :attr:`prior_size`),
        computed in numpy (the same prior for either kind of ``arrays``), returned as the runner's arrays.

        Raises:
            OptionError: a per-frame graph.
        """
        from prismstereo.classical.prior import BandPrior, band_prior

        self._kind(True)
        prior = band_prior(as_array(depth), as_array(valid), as_array(confidence), z_range=self.z_range,
                           min_confidence=self.temporal.min_prior_confidence, downsample=self.temporal.downsample,
                           size=self.prior_size)
        return BandPrior(*self._out(*prior))


def _is_temporal(path: Path) -> bool:
    """Whether the graph at ``path`` is a temporal one (it takes a prior), from its inputs, without a session."""
    import onnx

    try:
        graph = onnx.load(str(path), load_external_data=False).graph
    except Exception:  # not an ONNX file: the session reports it
        return False
    return any(i.name == PRIOR_NAMES[0] for i in graph.input)
