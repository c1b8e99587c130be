"""ONNX export of :class:`~prismstereo.model.PrismStereo` and an onnxruntime runner for the exported graph.

The graph (``export_onnx``):

* input ``image``: (B, C, H, W) float32 in [0, 1], the full sensor image; B dynamic, C (1 or 3), H and W
  static (the rig's sensor).
* outputs ``depth_mm`` (B, 1, H, W_ref) float32, ``valid`` (B, 1, H, W_ref) bool, ``confidence``
  (B, 1, H, W_ref) float32 in [0, 1] — the reference (left) half, W_ref = the columns left of the split.
* ``metadata_props``: ``prismstereo.version``, ``prismstereo.rig`` (the rig's JSON), ``prismstereo.config``
  (the model's resolved options as JSON: z range, hypotheses, costs, ...), ``prismstereo.num_hypotheses``,
  ``prismstereo.z_range_mm``, ``prismstereo.input_shape``.

The temporal graph (``export_onnx(..., temporal=TemporalOptions())``, :class:`TemporalGraph`) also takes the band's
prior :data:`PRIOR_NAMES` (``prior_inverse_depth`` float32 and ``prior_placed`` bool, (B, 1, h, w): a
:class:`~prismstereo.depth.temporal.BandPrior`, at the band's resolution) and also returns the next frame's,
:data:`NEXT_PRIOR_NAMES`; its options (``downsample`` resolved) are in ``prismstereo.temporal``.

Everything the model precomputes for a rig (the exact sweep polynomials, the prism masks, hypotheses) is
stored as constants, so the graph is specific to one rig, sensor size, range and option set. Exported
with the TorchScript-based exporter (``dynamo=False``) at opset 18: it traces the model once; the
semi-global aggregation's scan loops are unrolled (one step per coarse row / column and direction).

:class:`OnnxDepth` runs such a file in an ``onnxruntime.InferenceSession`` (2 intra-op threads, 1 inter-op
thread, all graph optimisations by default) and checks its input; :mod:`prismstereo.export.cache` keeps exported
graphs per rig and options.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np
import torch
from torch import nn

from prismstereo.errors import OptionError, PrismStereoError, ShapeError, check_option

if TYPE_CHECKING:
    from prismstereo.depth.temporal import BandPrior, TemporalOptions, TrackedDepth

__all__ = [
    "DEFAULT_OPSET",
    "NEXT_PRIOR_NAMES",
    "PRIOR_NAMES",
    "DepthGraph",
    "describe",
    "export_onnx",
    "ExportError",
    "graph_metadata",
    "OnnxDepth",
    "OnnxDepthResult",
    "source_digest",
    "TemporalGraph",
]

DEFAULT_OPSET = 18
INPUT_NAME = "image"
OUTPUT_NAMES = ("depth_mm", "valid", "confidence")
PRIOR_NAMES = ("prior_inverse_depth", "prior_placed")
NEXT_PRIOR_NAMES = ("next_inverse_depth", "next_placed")
Optimization = Literal["all", "extended", "basic", "disable"]
OPTIMIZATIONS: tuple[str, ...] = ("all", "extended", "basic", "disable")


class ExportError(PrismStereoError, ValueError):
    """An ONNX model cannot be exported, loaded or run."""


class OnnxDepthResult(NamedTuple):
    """Outputs of the exported graph, as torch tensors.

    Attributes:
        depth: (B, 1, H, W_ref) depth Z (mm) of the reference half; meaningless where not valid.
        valid: (B, 1, H, W_ref) bool.
        confidence: (B, 1, H, W_ref) in [0, 1].
    """

    depth: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor


class DepthGraph(nn.Module):
    """The exported computation: a :class:`~prismstereo.model.PrismStereo` reduced to its three graph
    outputs ``(depth_mm, valid, confidence)``.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> graph = DepthGraph(PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0)))
        >>> [t.shape for t in graph(torch.rand(1, 1, 96, 128))][0]
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        result = self.model(image)
        return result.depth, result.valid, result.confidence


class TemporalGraph(nn.Module):
    """The exported temporal computation: :meth:`~prismstereo.depth.temporal.TemporalDepth.track` with the inputs
    ``(image, prior_inverse_depth, prior_placed)`` (a :class:`~prismstereo.depth.temporal.BandPrior`) and the
    outputs ``(depth_mm, valid, confidence, next_inverse_depth, next_placed)``.

    Example:
        >>> from prismstereo.depth.temporal import TemporalDepth
        >>> from prismstereo.model import PrismStereo
        >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2})
        >>> tracker = TemporalDepth(model); image = torch.rand(1, 1, 96, 128)
        >>> TemporalGraph(tracker)(image, *tracker.band_prior(*model(image)[:3]))[0].shape
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, tracker: nn.Module) -> None:
        super().__init__()
        self.tracker = tracker

    def forward(self, image: torch.Tensor, prior_inverse: torch.Tensor,
                prior_placed: torch.Tensor) -> tuple[torch.Tensor, ...]:
        from prismstereo.depth.temporal import BandPrior

        result, following = self.tracker.track(image, BandPrior(prior_inverse, prior_placed))
        return result.depth, result.valid, result.confidence, following.inverse, following.placed


@functools.cache
def source_digest() -> str:
    """sha256 (16 hex digits) of the package's Python sources: which code built a graph (stored in its metadata
    and part of :func:`onnx_session`'s cache key, so that a changed algorithm or fitted constant is exported
    again instead of served from the cache under an unchanged version number).

    Example:
        >>> len(source_digest())
        16
    """
    digest = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def graph_metadata(model: nn.Module, channels: int, opset: int,
                   temporal: TemporalOptions | None = None) -> dict[str, str]:
    """The ``prismstereo.*`` metadata of ``model``'s graph (the module docstring): what :func:`export_onnx` stores and
    what names the graph in the cache.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> graph_metadata(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), 1, 18)["prismstereo.opset"]
        '18'
    """
    from prismstereo import __version__

    rig = model.rig
    described = model.describe()
    if temporal is not None:  # the binning resolved: the graph's prior is at its resolution
        from prismstereo.depth.temporal import temporal_downsample

        temporal = dataclasses.replace(temporal, downsample=temporal_downsample(model, temporal))
    return {
        "prismstereo.version": __version__,
        "prismstereo.source": source_digest(),
        "prismstereo.rig": json.dumps(rig.to_dict(), sort_keys=True),
        "prismstereo.config": json.dumps(described, sort_keys=True),
        "prismstereo.num_hypotheses": str(described["num_hypotheses"]),
        "prismstereo.z_range_mm": json.dumps(described["z_range_mm"]),
        "prismstereo.input_shape": json.dumps(["B", channels, rig.image_height, rig.image_width]),
        "prismstereo.opset": str(opset),
        **({} if temporal is None else {"prismstereo.temporal": json.dumps(temporal.to_dict(), sort_keys=True)}),
    }


def export_onnx(model: nn.Module, path: str | Path, *, channels: int = 1, opset: int = DEFAULT_OPSET,
                temporal: TemporalOptions | None = None) -> Path:
    """Export a :class:`~prismstereo.model.PrismStereo` (or a :class:`~prismstereo.learned.LearnedStereo` or
    :class:`~prismstereo.learned.HybridStereo`) to an ONNX file (checked with ``onnx.checker``).

    Args:
        model: the model (its rig, range and options are baked into the graph).
        path: the ``.onnx`` file to write (parent directories are created).
        channels: C of the graph's input, 1 (grey) or 3 (RGB).
        opset: ONNX opset, >= 16 (GridSample).
        temporal: None (the per-frame graph) or :class:`~prismstereo.depth.temporal.TemporalOptions`: the
            temporal graph (:class:`TemporalGraph`: the inputs ``image`` and :data:`PRIOR_NAMES`, the outputs and
            :data:`NEXT_PRIOR_NAMES`; its options in the metadata as ``prismstereo.temporal``), run next to the
            per-frame one by :class:`~prismstereo.stream.DepthStream`.

    Returns:
        The written path.

    Raises:
        ExportError: bad channels / opset, or the exporter or the checker failed.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> import tempfile; out = Path(tempfile.mkdtemp()) / "m.onnx"
        >>> export_onnx(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), out).exists()
        True
    """
    import onnx

    from prismstereo.learned import HybridStereo, LearnedStereo
    from prismstereo.model import PrismStereo

    if not isinstance(model, (PrismStereo, LearnedStereo, HybridStereo)):
        raise ExportError(f"model must be a PrismStereo, LearnedStereo or HybridStereo, got {type(model).__name__}")
    if channels not in (1, 3):
        raise ExportError(f"channels must be 1 or 3, got {channels!r}")
    if not isinstance(opset, int) or not 16 <= opset <= 20:
        raise ExportError(f"opset must be an int in 16..20 (GridSample needs >= 16), got {opset!r}")
    rig = model.rig
    example = torch.rand(1, channels, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(0))
    inputs, names, outputs = (example,), [INPUT_NAME], list(OUTPUT_NAMES)
    prior_size = (rig.image_height, rig.reference_width)
    if temporal is None:
        graph = DepthGraph(model).eval()
    else:
        from prismstereo.depth.temporal import TemporalDepth, TemporalOptions

        if not isinstance(temporal, TemporalOptions):
            raise ExportError(f"temporal must be None or TemporalOptions, got {type(temporal).__name__}")
        try:
            tracker = TemporalDepth(model, temporal)
        except OptionError as exc:
            raise ExportError(f"no temporal graph for this model: {exc}") from exc
        graph = TemporalGraph(tracker).eval()
        with torch.no_grad():
            inputs = (example, *tracker.band_prior(*model(example)[:3]))
        names, outputs = [INPUT_NAME, *PRIOR_NAMES], [*OUTPUT_NAMES, *NEXT_PRIOR_NAMES]
        prior_size = tracker.prior_size
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # tracer warnings about Python ints: shapes are static by design
        try:
            torch.onnx.export(graph, inputs, str(path), opset_version=opset, input_names=names,
                              output_names=outputs, dynamo=False,
                              dynamic_axes={n: {0: "batch"} for n in names + outputs})
        except Exception as exc:  # the exporter raises many types; report them as one
            raise ExportError(f"ONNX export failed: {exc}") from exc
    proto = onnx.load(str(path))
    # the exporter's shape inference names the outputs' height axis after the batch axis: declare them exactly
    for output in proto.graph.output:
        dims = output.type.tensor_type.shape.dim
        del dims[:]
        h, w = prior_size if output.name in NEXT_PRIOR_NAMES else (rig.image_height, rig.reference_width)
        for size in ("batch", 1, h, w):
            dim = dims.add()
            if isinstance(size, str):
                dim.dim_param = size
            else:
                dim.dim_value = size
    for key, value in graph_metadata(model, channels, opset, temporal).items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    try:
        onnx.checker.check_model(proto)
    except onnx.checker.ValidationError as exc:
        raise ExportError(f"exported graph fails onnx.checker: {exc}") from exc
    onnx.save(proto, str(path))
    return path


class OnnxDepth:
    """An exported depth graph in an ``onnxruntime.InferenceSession``.

    Args:
        path: a file written by :func:`export_onnx`.
        threads: intra-op threads (inter-op: 1).
        optimization: onnxruntime graph optimisation level: 'all' (default), 'extended', 'basic', 'disable'.
        spinning: let idle intra-op threads spin for work (onnxruntime's default) instead of sleeping. Spinning
            wins when the cores are the graph's alone and loses when other processes want them (``docs/design.md``,
            *How the model picks its defaults*, implementation choices): pass False where the depth graph shares
            the CPU (an endoscope application's other threads).

    Attributes:
        metadata: the ``prismstereo.*`` metadata_props (str -> str).
        input_shape: (C, H, W) the graph expects.
        load_seconds: time to build the session.
        temporal: a temporal graph's :class:`~prismstereo.depth.temporal.TemporalOptions` (``downsample``
            resolved; it takes a prior: :meth:`track`), None for the per-frame graph.
        prior_size: a temporal graph's (h, w) of its :class:`~prismstereo.depth.temporal.BandPrior`, None for the
            per-frame graph.

    Raises:
        ExportError: missing file, not an ONNX model, or not exported by prismstereo.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> import tempfile; out = Path(tempfile.mkdtemp()) / "m.onnx"
        >>> runner = OnnxDepth(export_onnx(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), out))
        >>> runner(torch.rand(2, 1, 48, 64)).depth.shape
        torch.Size([2, 1, 48, 32])
    """

    def __init__(self, path: str | Path, *, threads: int = 2, optimization: Optimization = "all",
                 spinning: bool = True) -> None:
        import onnxruntime as ort

        check_option(optimization, OPTIMIZATIONS, "optimization")
        if not isinstance(threads, int) or threads < 1:
            raise OptionError(f"threads must be an int >= 1, got {threads!r}")
        self.path = Path(path)
        if not self.path.is_file():
            raise ExportError(f"ONNX model not found: {self.path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
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
            from prismstereo.depth.temporal import TemporalOptions

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

    def _image(self, image: torch.Tensor | np.ndarray) -> np.ndarray:
        """The graph's float32 input from (B, C, H, W) ``image``, checked."""
        array = image.detach().cpu().numpy() if isinstance(image, torch.Tensor) else np.asarray(image)
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

    def __call__(self, image: torch.Tensor | np.ndarray) -> OnnxDepthResult:
        """Depth of a batch ``image`` (B, C, H, W) in [0, 1] (any float dtype; run in float32) by a per-frame graph.

        Raises:
            ShapeError: an image of another shape, or not floating point.
            OptionError: a temporal graph (:meth:`track`).
        """
        self._kind(False)
        depth, valid, confidence = self.session.run(list(OUTPUT_NAMES), {INPUT_NAME: self._image(image)})
        return OnnxDepthResult(torch.from_numpy(depth), torch.from_numpy(valid).bool(), torch.from_numpy(confidence))

    def track(self, image: torch.Tensor | np.ndarray, prior: BandPrior) -> TrackedDepth:
        """Depth of ``image`` (B, C, H, W) searched around ``prior`` by a temporal graph, as
        :meth:`~prismstereo.depth.temporal.TemporalDepth.track`.

        Args:
            image: (B, C, H, W) in [0, 1] (any float dtype; run in float32).
            prior: a :class:`~prismstereo.depth.temporal.BandPrior`, (B, 1, h, w) each (:attr:`prior_size`).

        Returns:
            TrackedDepth(OnnxDepthResult of (B, 1, H, W_ref) tensors, the next frame's BandPrior).

        Raises:
            ShapeError: an image or prior of another shape.
            OptionError: a per-frame graph.
        """
        from prismstereo.depth.temporal import BandPrior, TrackedDepth

        self._kind(True)
        feed = {INPUT_NAME: self._image(image)}
        shape = (feed[INPUT_NAME].shape[0], 1, *self.prior_size)
        for name, t, dtype in zip(PRIOR_NAMES, prior, (np.float32, np.bool_), strict=True):
            value = t.detach().cpu().numpy() if isinstance(t, torch.Tensor) else np.asarray(t)
            if tuple(value.shape) != shape:
                raise ShapeError(f"{name} must have shape {shape}, got {tuple(value.shape)}")
            feed[name] = np.ascontiguousarray(value, dtype=dtype)
        depth, valid, confidence, inverse, placed = self.session.run([*OUTPUT_NAMES, *NEXT_PRIOR_NAMES], feed)
        return TrackedDepth(OnnxDepthResult(torch.from_numpy(depth), torch.from_numpy(valid).bool(),
                                            torch.from_numpy(confidence)),
                            BandPrior(torch.from_numpy(inverse), torch.from_numpy(placed).bool()))

    def band_prior(self, depth: torch.Tensor, valid: torch.Tensor, confidence: torch.Tensor) -> BandPrior:
        """A full-resolution result (B, 1, H, W_ref) each (a key frame's) as a temporal graph's prior
        (:func:`~prismstereo.depth.temporal.band_prior` with the graph's range, options and :attr:`prior_size`),
        computed in torch.

        Raises:
            OptionError: a per-frame graph.
        """
        from prismstereo.depth.temporal import band_prior

        self._kind(True)
        return band_prior(depth, valid, confidence, z_range=self.z_range,
                          min_confidence=self.temporal.min_prior_confidence, downsample=self.temporal.downsample,
                          size=self.prior_size)


def describe(metadata: dict[str, Any]) -> str:
    """One line summarising an exported graph's metadata (for the CLI).

    Example:
        >>> describe({"prismstereo.input_shape": '["B", 1, 48, 64]', "prismstereo.num_hypotheses": "9",
        ...           "prismstereo.z_range_mm": "[400.0, 700.0]", "prismstereo.version": "0.1.0"})
        'input (B, 1, 48, 64), 9 hypotheses over 400.0-700.0 mm, prismstereo 0.1.0'
    """
    shape = ", ".join(str(d) for d in json.loads(metadata["prismstereo.input_shape"]))
    z = json.loads(metadata["prismstereo.z_range_mm"])
    return (f"input ({shape}), {metadata['prismstereo.num_hypotheses']} hypotheses over {z[0]:.1f}-{z[1]:.1f} mm, "
            f"prismstereo {metadata['prismstereo.version']}")
