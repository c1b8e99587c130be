"""One way to a depth model: the interface every model satisfies (:class:`DepthModel`), what a user asks for
(:class:`ModelSpec`) and the builder (:func:`build_model`).

Three models compute depth of the reference (left) half of a capture, all on the exact sweep and with one output,
:class:`~prismstereo.depth.result.DepthResult`:

* ``'hybrid'`` (:class:`~prismstereo.learned.HybridStereo`): the classical chain on binned blocks refined by small
  learned 2-D stages and the classical band's exact fit; the default from 512 x 384 up (:func:`default_kind`);
* ``'classical'`` (:class:`~prismstereo.classical.PrismStereo`): window costs, coarse to fine, every option in a
  :class:`~prismstereo.classical.StereoConfig`; the default on very small sensors;
* ``'learned'`` (:class:`~prismstereo.learned.LearnedStereo`): a 3-D cost volume at 1/4 (dense, slow).

The CLI, the ONNX export and its cache, the jobs, the stream and the notebooks all build models here, and run them
through :class:`~prismstereo.predictor.Predictor` (torch or onnxruntime).
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import torch

from prismstereo.errors import OptionError, check_option
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.names import MODEL_KINDS, ModelKind

if TYPE_CHECKING:
    from prismstereo.classical import StereoConfig, TemporalDepth, TemporalOptions
    from prismstereo.depth.result import DepthResult

__all__ = ["HYBRID_MIN_SIDE", "HYBRID_OPTIONS", "MODEL_KINDS", "DepthModel", "ModelKind", "ModelSpec", "build_model",
           "default_kind", "describe_model"]

HYBRID_MIN_SIDE = 192
"""The shorter side (px) of the reference half from which the hybrid is the default (:func:`default_kind`)."""
HYBRID_OPTIONS: tuple[str, ...] = ("last_stage",)
"""The options a ``'hybrid'`` model takes in ``config`` (keyword arguments of
:class:`~prismstereo.learned.HybridStereo`: ``{"last_stage": "learned"}`` leaves out the exact last stage)."""
LEARNED_OPTIONS: tuple[str, ...] = ("num_hypotheses", "scale", "with_match")
"""The options a ``'learned'`` model takes in ``config`` (keyword arguments of
:class:`~prismstereo.learned.LearnedStereo`)."""


@runtime_checkable
class DepthModel(Protocol):
    """What every depth model is and offers (a ``torch.nn.Module``).

    Attributes:
        kind: ``'hybrid'``, ``'classical'`` or ``'learned'`` (:data:`MODEL_KINDS`).
        rig: the :class:`~prismstereo.geometry.rig.BiPrismRig` of the sensor it was built for.
        z_range: (z_min, z_max) searched, mm.

    Methods:
        ``model(image)``: (B, C, H, W) captures in [0, 1] (C = 1, or 3: its
        :func:`~prismstereo.conventions.to_grey`) -> :class:`~prismstereo.depth.result.DepthResult` of
        (B, *, H, W_ref) tensors (NaN or infinite pixels: no depth where they reach,
        :mod:`~prismstereo.depth.bad_pixels`; values outside [0, 1]: :class:`~prismstereo.errors.ImageValueError`);
        ``describe()``: what the model is, JSON-ready (the ONNX metadata and cache key); ``summary()``: one line;
        ``tracker(options)``: the temporal band that tracks its depth through a video
        (:class:`~prismstereo.classical.TemporalDepth`), or None.

    Example:
        >>> isinstance(build_model(thesis_setup1().downscaled(8), "classical", (400.0, 700.0)), DepthModel)
        True
    """

    kind: str
    rig: BiPrismRig

    @property
    def z_range(self) -> tuple[float, float]: ...

    def __call__(self, image: torch.Tensor) -> DepthResult: ...

    def describe(self) -> dict[str, Any]: ...

    def summary(self) -> str: ...

    def tracker(self, options: TemporalOptions | None = None) -> TemporalDepth | None: ...


def default_kind(rig: BiPrismRig) -> Literal["hybrid", "classical"]:
    """The model a capture of ``rig`` gets by default: ``'hybrid'`` where the reference half is at least
    :data:`HYBRID_MIN_SIDE` px on its shorter side and the sensor divides into its first stage's cells (8 x 8 pixels
    where its stages run 2 x 2-binned, else 4 x 4), else ``'classical'``. The hybrid's stages run where the classical
    default fits its band (2 x 2 bins from 384 px, else the full sensor), so they see a surface in about as many pixels
    on every sensor; below that side its classical level's blocks are large against the surfaces and the classical chain
    matches it (``docs/benchmarks.md``, *One default*: the hybrid ahead on every capture at 512 x 384, mixed at 256 x
    192).

    Example:
        >>> [default_kind(thesis_setup1().downscaled(k)) for k in (1, 2, 4)]
        ['hybrid', 'hybrid', 'classical']
    """
    from prismstereo.classical.defaults import default_downsample  # the hybrid's stages' binning b

    cell = 4 * default_downsample(rig)
    cells = rig.image_width % cell == 0 and rig.image_height % cell == 0
    return "hybrid" if cells and min(rig.image_height, rig.reference_width) >= HYBRID_MIN_SIDE else "classical"


@dataclasses.dataclass(frozen=True, kw_only=True)
class ModelSpec:
    """A depth model as asked for, before anything is built: picklable, and the key of its exported graphs in the
    ONNX cache (:meth:`request`), so that a cached graph runs without building the torch model.

    Attributes:
        rig: the sensor's rig.
        kind: ``'hybrid'``, ``'classical'``, ``'learned'`` or None: ``'classical'`` when ``config`` is given, else
            the rig's default (:func:`default_kind`).
        z_range: (z_min, z_max) mm; None: :func:`~prismstereo.depth.range.default_z_range` of the rig.
        config: the model's options: for ``'classical'`` a :class:`~prismstereo.classical.StereoConfig`, a preset's
            name or a dict of options on top of the default; for ``'learned'`` a dict of :data:`LEARNED_OPTIONS`,
            for ``'hybrid'`` one of :data:`HYBRID_OPTIONS`.
        weights: ``'hybrid'`` and ``'learned'``: a weights file written by ``prismstereo train``; None: the
            shipped weights.

    Raises:
        OptionError: an unknown kind, options or weights of another model.

    Example:
        >>> spec = ModelSpec(rig=thesis_setup1().downscaled(8), z_range=(400.0, 700.0), config="fast")
        >>> spec.resolved_kind, spec.build().summary()
        ('classical', '2x2-binned model (...), then a full-resolution band +-1 of 15, band edges clamped')
    """

    rig: BiPrismRig
    kind: ModelKind | None = None
    z_range: tuple[float, float] | None = None
    config: StereoConfig | str | Mapping[str, Any] | None = None
    weights: str | Path | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.rig, BiPrismRig):
            raise OptionError(f"rig must be a BiPrismRig, got {type(self.rig).__name__}")
        if self.kind is not None:
            check_option(self.kind, MODEL_KINDS, "kind")
        if self.z_range is not None:
            object.__setattr__(self, "z_range", tuple(float(z) for z in self.z_range))
        kind = self.resolved_kind
        if kind == "classical" and self.weights is not None:
            raise OptionError("weights are the hybrid's or the learned model's, not the classical model's")
        if kind in ("hybrid", "learned") and self.config is not None:
            options = HYBRID_OPTIONS if kind == "hybrid" else LEARNED_OPTIONS
            if not isinstance(self.config, Mapping) or set(self.config) - set(options):
                raise OptionError(f"the {kind} model's config is a dict of {', '.join(options)}, got "
                                  f"{self.config!r}")
        if self.weights is not None and not Path(self.weights).is_file():
            from prismstereo.learned import WeightsError

            raise WeightsError(f"weights file {self.weights} does not exist")

    @property
    def resolved_kind(self) -> ModelKind:
        """``kind``, or when None: ``'classical'`` with a ``config``, else the rig's default (:func:`default_kind`)."""
        if self.kind is not None:
            return self.kind
        return "classical" if self.config is not None else default_kind(self.rig)

    def build(self) -> DepthModel:
        """The model, in eval mode (:func:`build_model`)."""
        from prismstereo.depth.range import check_z_range, default_z_range

        kind, weights = self.resolved_kind, "default" if self.weights is None else self.weights
        z_range = default_z_range(self.rig) if self.z_range is None else check_z_range(self.rig, self.z_range)
        if kind == "classical":
            from prismstereo.classical import PrismStereo

            return PrismStereo(self.rig, z_range, self.config).eval()
        if kind == "hybrid":
            from prismstereo.learned import HybridStereo

            return HybridStereo(self.rig, z_range, weights=weights, **dict(self.config or {})).eval()
        from prismstereo.learned import LearnedStereo

        return LearnedStereo(self.rig, z_range, weights=weights, **dict(self.config or {})).eval()

    def request(self) -> dict[str, Any]:
        """What was asked, JSON-ready, before the rig resolves it (the kind, range and options as given; a weights
        file by its content's hash): with the rig, the ONNX cache's key of this model's graphs
        (:func:`~prismstereo.export.cache.request_key`).

        Example:
            >>> ModelSpec(rig=thesis_setup1(), kind="hybrid").request()
            {'kind': 'hybrid', 'z_range_mm': None, 'config': None, 'weights': 'default'}
        """
        from prismstereo.classical import as_config

        config: Any = self.config
        if self.resolved_kind == "classical":
            config = as_config(config).to_dict()
        elif isinstance(config, Mapping):
            config = dict(sorted(config.items()))
        if self.weights is None:
            weights = "default"
        else:
            weights = hashlib.sha256(Path(self.weights).read_bytes()).hexdigest()
        return {"kind": self.resolved_kind, "z_range_mm": None if self.z_range is None else list(self.z_range),
                "config": config, "weights": weights}


def build_model(rig: BiPrismRig, kind: ModelKind | None = None, z_range: tuple[float, float] | None = None,
                config: StereoConfig | str | Mapping[str, Any] | None = None,
                weights: str | Path | None = None) -> DepthModel:
    """The depth model of ``rig``, in eval mode: the one builder of the CLI, the export, the jobs, the stream and
    the notebooks.

    Args:
        rig: the sensor's rig (its geometry is checked: :class:`~prismstereo.errors.RigError`).
        kind: ``'hybrid'``, ``'classical'`` or ``'learned'``; None: ``'classical'`` with a ``config``, else the
            rig's default (:func:`default_kind`).
        z_range: (z_min, z_max) mm; None: the rig's default (:func:`~prismstereo.depth.range.default_z_range`).
        config: the model's options (:class:`ModelSpec`): the classical model's config, preset or dict of options,
            or the learned model's dict of :data:`LEARNED_OPTIONS` (the hybrid's: :data:`HYBRID_OPTIONS`).
        weights: the hybrid's or the learned model's weights file; None: the shipped weights.

    Returns:
        A :class:`DepthModel`.

    Raises:
        OptionError: an unknown kind, options or weights of another model. WeightsError: an unreadable weights
            file. RigError: a rig or range the models cannot use.

    Example:
        >>> model = build_model(thesis_setup1().downscaled(8), z_range=(400.0, 700.0))
        >>> model.kind, model(torch.rand(1, 1, 96, 128)).depth.shape
        ('classical', torch.Size([1, 1, 96, 64]))
    """
    return ModelSpec(rig=rig, kind=kind, z_range=z_range, config=config, weights=weights).build()


def describe_model(model: DepthModel, temporal: TemporalOptions | None = None,
                   tracker: TemporalDepth | None = None) -> str:
    """One line for logs and the CLI: the model's summary and, when ``temporal`` options were asked for, how it
    tracks videos: by ``tracker`` (its own band, or another model's: the hybrid's classical one), or every frame
    on its own when it offers none.

    Example:
        >>> model = build_model(thesis_setup1().downscaled(8), "classical", (400.0, 700.0))
        >>> describe_model(model)
        '15 hypotheses in one level'
        >>> from prismstereo.classical import TemporalOptions
        >>> describe_model(model, TemporalOptions(), model.tracker())
        '15 hypotheses in one level, every frame on its own (this model has no full-resolution band for the ...)'
    """
    line = model.summary()
    if temporal is None:
        return line
    if tracker is None:
        return line + ", every frame on its own (this model has no full-resolution band for the temporal prior)"
    if tracker.model is not model:
        line += f"; tracked between key frames by the classical model ({tracker.model.summary()})"
    return f"{line}, {tracker.summary()}"
