"""The temporal prior: the depth of a video frame searched in a narrow band around the previous frame's depth.

Between two frames of a video most pixels move by a fraction of a hypothesis step. :class:`TemporalDepth` takes a
:class:`~prismstereo.model.PrismStereo` and places a band directly on a prior (the previous frame's depth,
validity and confidence, at full resolution) instead of on the binned level's estimate: its full-resolution
level's band, or one on the binned frame (``downsample``, below); no coarse search, and a band of 2 ``band`` + 1
hypotheses (default 3, against the pyramid's 5). With
``band_edges='clamp'`` the sub-pixel fit may move the estimate up to the band's outer sample (``vertex_limit`` 1
of :class:`~prismstereo.matching.band.FineBand`, not the search's half step): a plane moving by one hypothesis
step per frame is then followed in the frame it moves, where a half-step limit left the first tracked frames
off until the extrapolation caught up. Prior pixels that
are invalid or less confident than ``min_prior_confidence`` take the mean sweep coordinate of the others within
``reach`` pixels (:func:`~prismstereo.matching.band.extend_estimate`); where neither exists the pixel is invalid.
The calibrated confidence sees the band's own NCC where the per-frame model sees the binned level's similarity:
evidence of the frame itself, so that a band that a scene cut or fast motion has left behind is judged unsure
(the stream then computes the frame with the full model).

With ``downsample`` k > 1 (by default 2 for a pyramid model) the band runs on the capture binned by k x k instead,
in a level of its own on the binned rig with the model's options (its sweep, calibrated confidence and
smoothing): the prior is binned (the mean sweep coordinate of each block's usable pixels, where at least half of
them are), and the estimate comes back to full resolution by a validity-weighted bilinear interpolation of the
sweep coordinate (computed on the inverse depth, affine in it: one reciprocal at full resolution; valid pixels
interpolate valid neighbours only), with validity and confidence per block: k^2 times fewer voxels for the binned
level's accuracy.

Which frames get the full model instead (the first, every ``keyframe_interval``-th, scene cuts, a prior that lost
too much of its coverage) is :class:`TemporalOptions`' part, applied by :class:`~prismstereo.stream.DepthStream`.
Why each default: ``docs/design.md``, *How the model picks its defaults* (temporal options); measured by
``benchmarks/video_speed.py`` (``docs/benchmarks.md``, *Video: frame times, accuracy and flicker*).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.defaults import resolve_level
from prismstereo.depth.level import DepthLevel, upsample
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.series import series_at
from prismstereo.epipolar.sweep import depth_to_sweep, inverse_to_sweep, sweep_to_inverse
from prismstereo.errors import OptionError, ShapeError, check_int, check_number, check_option, check_shape
from prismstereo.matching.band import FineBand, extend_estimate
from prismstereo.matching.confidence import CLAMPED_WEIGHTS, ConfidenceModel
from prismstereo.runtime import crop

__all__ = ["TEMPORAL_BAND_EDGES", "TemporalDepth", "TemporalOptions", "supports_temporal", "temporal_downsample"]

BandEdges = Literal["reject", "clamp"]
TEMPORAL_BAND_EDGES: tuple[str, ...] = ("reject", "clamp")


@dataclasses.dataclass(frozen=True, kw_only=True)
class TemporalOptions:
    """The temporal prior's options (JSON-friendly; :meth:`to_dict` / ``TemporalOptions(**d)``).

    Attributes:
        band: R: the band around the prior has 2 R + 1 hypotheses (>= 1).
        band_edges: a pixel whose best hypothesis is on the band's edge: invalid ('reject') or refined from the
            edge's inner neighbour, up to the edge ('clamp', default: no winner search, and on small moving
            sequences more coverage).
        reach: invalid prior pixels within this many pixels of valid ones take their mean sweep coordinate (>= 0).
        min_prior_confidence: prior pixels less confident than this count as invalid ones, in [0, 1].
        keyframe_interval: the full model at least every this many frames (>= 1; 1: every frame).
        cut_threshold: a scene cut: the mean absolute grey difference to the previous frame (8 x 8 block means,
            grey in [0, 1]) above this; the frame gets the full model.
        max_invalid_growth: the full model when the share of the reference half invalid in the prior exceeds the
            last key frame's by more than this (a depth step entering the view, occlusions), in [0, 1].
        min_valid_ratio: a tracked frame whose valid share falls below this times the last key frame's is
            computed again by the full model, in [0, 1] (0: never).
        extrapolate: the prior is the last depth extrapolated at constant velocity in inverse depth from the
            frame before (where both are valid), not the last depth itself.
        downsample: k: the band runs on the capture binned by k x k and its estimate is interpolated back to full
            resolution (>= 1; 1: the model's full-resolution band; see the module docstring). None (default): 2 for
            a pyramid (the resolution of its binned level: a fraction of the full-resolution band's work at
            about its accuracy; ``benchmarks/video_speed.py``'s ``temporal k=1`` rows run the other), 1 for a
            one-level model (smaller sensors, where the binned frame costs accuracy).

    Example:
        >>> TemporalOptions(band=2).to_dict()["band"]
        2
    """

    band: int = 1
    band_edges: BandEdges = "clamp"
    reach: int = 4
    min_prior_confidence: float = 0.5
    keyframe_interval: int = 60
    cut_threshold: float = 0.05
    max_invalid_growth: float = 0.02
    min_valid_ratio: float = 0.95
    extrapolate: bool = True
    downsample: int | None = None

    def __post_init__(self) -> None:
        check_option(self.band_edges, TEMPORAL_BAND_EDGES, "band_edges")
        if not isinstance(self.extrapolate, bool):
            raise OptionError(f"extrapolate must be a bool, got {self.extrapolate!r}")
        for name, least in (("band", 1), ("reach", 0), ("keyframe_interval", 1), ("downsample", 1)):
            check_int(getattr(self, name), name, least, none=name == "downsample")
        check_number(self.cut_threshold, "cut_threshold", 0.0, float("inf"), "a number in [0, inf] (inf: never a cut)",
                     infinite=True)
        for name in ("max_invalid_growth", "min_valid_ratio", "min_prior_confidence"):
            check_number(getattr(self, name), name, 0.0, 1.0, "a number in [0, 1]")

    def to_dict(self) -> dict[str, Any]:
        """The options as a JSON-ready dict."""
        return dataclasses.asdict(self)


def supports_temporal(model: nn.Module) -> bool:
    """True for a :class:`~prismstereo.model.PrismStereo` whose final level has a full-resolution band (a pyramid
    or a coarse-to-fine level): what :class:`TemporalDepth` places on a prior.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> supports_temporal(PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2}))
        True
    """
    final = getattr(model, "final", None)  # a model made of DepthLevels (the learned model is not)
    return isinstance(final, DepthLevel) and final.fine is not None and (
        model.downsample == 1 or model.binned is not None)


def temporal_downsample(model: nn.Module, options: TemporalOptions | None = None) -> int:
    """The binning of the temporal band's capture for ``model``: ``options.downsample``, or when it is None 2 for a
    pyramid (:attr:`~prismstereo.model.PrismStereo.binned` set) and 1 for a one-level model.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> temporal_downsample(PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2}))
        1
    """
    options = options or TemporalOptions()
    if options.downsample is not None:
        return options.downsample
    return 2 if getattr(model, "binned", None) is not None else 1


class TemporalDepth(nn.Module):
    """Depth of a frame searched in a band around a prior (the previous frame's result), at full resolution or on
    the binned frame (``options.downsample``), returned at full resolution.

    Args:
        model: a :class:`~prismstereo.model.PrismStereo` with a full-resolution band (:func:`supports_temporal`):
            its final level's sweep, cost, confidence and validity rules are used, its coarse search is not.
        options: the band (``band``, ``band_edges``, ``reach``, ``downsample``); the key-frame rules are the
            stream's.

    Attributes:
        downsample: the binning of the band's capture (``options.downsample`` resolved).
        level: the :class:`~prismstereo.depth.level.DepthLevel` whose sweep, confidence and rules the band uses:
            the model's final level, or with ``downsample`` > 1 a level of the binned rig.

    Raises:
        OptionError: a model without a full-resolution band (a single full-range level, block mode, the learned
            model); a ``downsample`` that leaves the binned rig too few rows for a level.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2})
        >>> image = torch.rand(1, 1, 96, 128); first = model(image)
        >>> TemporalDepth(model)(image, first.depth, first.valid, first.confidence).depth.shape
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, model: nn.Module, options: TemporalOptions | None = None) -> None:
        super().__init__()
        if not supports_temporal(model):
            raise OptionError("the temporal prior needs a PrismStereo with a full-resolution band (a pyramid or "
                              "coarse_factor > 1), not a single full-range level, block mode or the learned model")
        self.options = options or TemporalOptions()
        if not isinstance(self.options, TemporalOptions):
            raise OptionError(f"options must be TemporalOptions, got {type(self.options).__name__}")
        self.model = model
        final = model.final
        k = self.downsample = temporal_downsample(model, self.options)
        if k > 1:  # a level of its own on the k x k-binned capture, with the model's options (its coarse search,
            # which the band does not use, at the smallest factor that gives the level a band)
            config = final.config.replace(search={"num_hypotheses": None, "coarse_factor": 2, "band": None})
            try:
                final = DepthLevel(model.rig.binned(k), final.z_range, config)
            except OptionError as exc:
                raise OptionError(f"downsample {k} leaves no level for the temporal band: {exc}") from exc
        self.level = final
        # the band's own edge rule, and the confidence weights fitted to it (resolved as for any band)
        band_config = resolve_level(final.rig, final.z_range, final.config.replace(
            search={"band_edges": self.options.band_edges}, validity={"confidence_weights": None}),
            placed_by=final.placed_by)
        # 'clamp': the fit may reach the band's outer sample (a prior one step behind the motion is followed within
        # the frame, not over several: see the module docstring)
        limit = 1.0 if self.options.band_edges == "clamp" else 0.5
        self.fine = FineBand(band_config, self.options.band, final.step, final.split.split,
                             with_match=final.fine.with_match, vertex_limit=limit)
        self.calibration = None
        if final.calibration is not None:
            clamped = band_config.validity.confidence_weights == "clamped"
            self.calibration = ConfidenceModel(CLAMPED_WEIGHTS[0] if clamped else None)

    @property
    def rig(self):
        """The model's rig."""
        return self.model.rig

    def forward(self, image: torch.Tensor, prior_depth: torch.Tensor, prior_valid: torch.Tensor,
                prior_confidence: torch.Tensor) -> DepthResult:
        """Depth of ``image`` searched around the prior.

        Args:
            image: (B, C, H, W) the full sensor image in [0, 1].
            prior_depth: (B, 1, H, W_ref) depth (mm) of the previous frame (any value where not valid).
            prior_valid: (B, 1, H, W_ref) bool.
            prior_confidence: (B, 1, H, W_ref) in [0, 1].

        Returns:
            DepthResult of (B, *, H, W_ref) tensors, as the model's.
        """
        check_shape(image, ["B", "C", "H", "W"], "image")
        final = self.model.final
        h, w = self.rig.image_height, self.rig.image_width
        if image.shape[-2:] != (h, w):
            raise ShapeError(f"image is {image.shape[-1]}x{image.shape[-2]} px but the rig's sensor is {w}x{h}")
        shape = (image.shape[0], 1, h, self.rig.reference_width)
        for name, t in (("prior_depth", prior_depth), ("prior_valid", prior_valid),
                        ("prior_confidence", prior_confidence)):
            if tuple(t.shape) != shape:
                raise ShapeError(f"{name} must have shape {shape}, got {tuple(t.shape)}")
        if prior_valid.dtype != torch.bool:
            raise ShapeError(f"prior_valid must be bool, got {prior_valid.dtype}")
        level, k = self.level, self.downsample
        with torch.no_grad():  # the prior only places the band
            placed = prior_valid & (prior_confidence >= self.options.min_prior_confidence)
            z_range = torch.tensor(final.z_range, dtype=image.dtype, device=image.device)
            depth = torch.where(placed, prior_depth.to(image.dtype), z_range[0])  # any finite depth elsewhere
            if k > 1:  # the binned prior: each block's mean over its placed pixels, where half of them are, of the
                # inverse depth within the range (s is affine in it: the mean of s, in fewer full-resolution passes)
                bounds = 1.0 / z_range
                inverse, placed = _binned_prior((1.0 / depth).clamp(bounds[1], bounds[0]), placed, k,
                                                level.rig.image_height, level.rig.reference_width,
                                                (h, self.rig.reference_width))
                s_p = inverse_to_sweep(inverse, z_range).clamp(-1.0, 1.0)
            else:
                s_p = depth_to_sweep(depth, z_range).clamp(-1.0, 1.0)
            s_c, reach = extend_estimate(s_p, placed, self.options.reach)
            s0 = s_c.clamp(-1.0, 1.0)
        if k > 1:
            binned = crop(F.avg_pool2d(image, k), level.rig.image_height, level.rig.image_width)
            ref, other = level.split(binned)
        else:
            ref, other = level.split(image)
        # the band's own NCC is the similarity feature where the per-frame model has the binned level's: evidence
        # of this frame (the prior's confidence would vouch for a band a scene cut or fast motion has left, see the
        # module docstring); moves up to half a step from the prior count as none in the offset feature: on a moving
        # scene a prior one step behind is expected, and the per-frame weights would judge it a misplaced band
        estimate = level.search_band(ref, other, s0, reach, ~placed, None, fine=self.fine,
                                     calibration=self.calibration, free_offset=0.5)
        result = level.finish(estimate)
        return result if k == 1 else self.full_resolution(result)

    def full_resolution(self, result: DepthResult) -> DepthResult:
        """A binned level's result (B, *, h, w) at the model's full resolution (B, *, H, W_ref): the sweep
        coordinate interpolated bilinearly, after each binned pixel without a depth (not valid; dense: not
        covered) took the mean of its neighbours with one (:func:`~prismstereo.matching.band.extend_estimate`,
        radius 1: valid pixels interpolate valid neighbours only); validity and confidence per block, none beyond
        the binned level's last row and column. What :meth:`forward` returns with ``downsample`` > 1.

        Example:
            >>> from prismstereo.model import PrismStereo
            >>> model = PrismStereo(thesis_setup1().downscaled(4), (400.0, 800.0), {"downsample": 2, "full_band": 2})
            >>> tracker = TemporalDepth(model)
            >>> binned = tracker.level.depth(torch.rand(1, 1, 96, 128))
            >>> tracker.full_resolution(binned).depth.shape
            torch.Size([1, 1, 192, 128])
        """
        z_range = torch.tensor(self.model.final.z_range, dtype=result.depth.dtype, device=result.depth.device)
        final, k = self.model.final, self.downsample
        size = (self.rig.image_height, self.rig.reference_width)
        dense = final.config.validity.dense
        has = result.confidence > 0 if dense else result.valid
        s = extend_estimate(depth_to_sweep(result.depth, z_range), has, 1).s.clamp(-1.0, 1.0)
        # the inverse depth interpolated (s is affine in it): the depth one reciprocal away at full resolution
        inverse = upsample(sweep_to_inverse(s, z_range), k, size, "bilinear")
        s = inverse_to_sweep(inverse, z_range)  # the index and the match (not outputs of the exported graph)
        maps = [has.to(s.dtype), result.confidence] + ([result.valid.to(s.dtype)] if dense else [])
        shown, confidence, *dense_valid = upsample(torch.cat(maps, 1), k, size, beyond="zero").split(1, 1)
        valid = (dense_valid[0] if dense else shown) > 0.5
        return DepthResult(1.0 / inverse, valid, confidence * shown, (s + 1.0) / final.step,
                           torch.cat(series_at(final.series, s), 1))


def _binned_prior(x: torch.Tensor, placed: torch.Tensor, k: int, h: int, w: int,
                  full: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, 1, H, W_ref) values (inverse depths) and usable-prior mask binned by k x k to the binned level's
    (B, 1, h, w): the mean over each block's usable pixels (0 in a block without any), usable where at least half of
    them are. ``full``: (H, W_ref) as ints (static in an exported graph)."""
    weight = placed.to(x.dtype)
    # ceil_mode: a reference half whose width k does not divide (512 / 3) has a last binned column of fewer pixels
    # (only then: onnxruntime's pooling with ceil_mode is slower, where it changes nothing)
    ceil = bool(full[0] % k or full[1] % k)
    share = crop(F.avg_pool2d(weight, k, ceil_mode=ceil), h, w)
    mean = crop(F.avg_pool2d(x * weight, k, ceil_mode=ceil), h, w) / share.clamp_min(1e-6)
    return mean, share >= 0.5
