"""The temporal prior: the depth of a video frame searched in a narrow band around the previous frame's depth.

Between two frames of a video most pixels move by a fraction of a hypothesis step. :class:`TemporalDepth` takes a
:class:`~prismstereo.classical.model.PrismStereo` and places a band directly on a prior (the previous frame's inverse
depth where it is valid and confident, :class:`BandPrior`) instead of on the binned level's estimate: its
full-resolution level's band, or one on the binned frame (``downsample``, below); no coarse search, and a band of 2
``band`` + 1 hypotheses (default 3, against the pyramid's 5). With ``band_edges='clamp'`` the sub-pixel fit may move the
estimate up to the band's outer sample (``vertex_limit`` 1 of :class:`~prismstereo.matching.band.FineBand`, not the
search's half step): a plane moving by one hypothesis step per frame is then followed in the frame it moves, where a
half-step limit left the first tracked frames off until the extrapolation caught up. Prior pixels that are invalid
or less confident than ``min_prior_confidence`` take the mean sweep coordinate of the others within ``reach`` pixels
(:func:`~prismstereo.matching.band.extend_estimate`); where neither exists the pixel is invalid. The calibrated
confidence sees the band's own NCC where the per-frame model sees the binned level's similarity: evidence of the
frame itself, so that a band that a scene cut or fast motion has left behind is judged unsure (the stream then
computes the frame with the full model).

With ``downsample`` k > 1 (by default 2 for a pyramid model) the band runs on the capture binned by k x k instead,
in a level of its own on the binned rig with the model's options (its sweep, calibrated confidence and
smoothing): the prior is binned (the mean sweep coordinate of each block's usable pixels, where at least half of
them are), and the estimate comes back to full resolution by a validity-weighted bilinear interpolation of the
sweep coordinate (computed on the inverse depth, affine in it: one reciprocal at full resolution; valid pixels
interpolate valid neighbours only), with validity and confidence per block: k^2 times fewer voxels for the binned
level's accuracy.

The prior lives at the band's resolution (:class:`BandPrior`: the clipped inverse depth, in which the sweep
coordinate is affine, and where it places the band). :meth:`TemporalDepth.track` takes one and returns, beside
the frame's full-resolution result, the one its band found for the next frame (:class:`TrackedDepth`): a video
binned and interpolated once per frame, not binned again from the interpolated result. :func:`band_prior` makes
one from a full-resolution result (a key frame's; :meth:`TemporalDepth.forward` takes a previous result that way).

Which frames get the full model instead (the first, every ``keyframe_interval``-th, scene cuts, a prior that lost
too much of its coverage) is :class:`TemporalOptions`' part, applied by :class:`~prismstereo.stream.DepthStream`.
Why each default: ``docs/design.md``, *How the model picks its defaults* (temporal options); measured by
``benchmarks/video_speed.py`` (``docs/benchmarks.md``, *Video: frame times, accuracy and flicker*).
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.classical.defaults import resolve_level
from prismstereo.classical.level import DepthLevel
from prismstereo.classical.prior import BandPrior, TemporalOptions, TrackedDepth, band_prior
from prismstereo.depth.bad_pixels import discard
from prismstereo.depth.resample import upsample
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.series import series_at
from prismstereo.epipolar.sweep import depth_to_sweep, inverse_to_sweep, sweep_to_inverse
from prismstereo.errors import OptionError, ShapeError, check_shape
from prismstereo.matching.band import FineBand, extend_estimate
from prismstereo.matching.confidence import CLAMPED_WEIGHTS, ConfidenceModel
from prismstereo.runtime import crop

__all__ = ["TemporalDepth", "supports_temporal", "temporal_downsample"]


def supports_temporal(model: nn.Module) -> bool:
    """True for a :class:`~prismstereo.classical.model.PrismStereo` whose final level has a full-resolution band (a
    pyramid or a coarse-to-fine level): what :class:`TemporalDepth` places on a prior.

    Example:
        >>> from prismstereo.classical.model import PrismStereo
        >>> supports_temporal(PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2}))
        True
    """
    final = getattr(model, "final", None)  # a model made of DepthLevels (the learned model is not)
    return isinstance(final, DepthLevel) and final.fine is not None and (
        model.downsample == 1 or model.binned is not None)


def temporal_downsample(model: nn.Module, options: TemporalOptions | None = None) -> int:
    """The binning of the temporal band's capture for ``model``: ``options.downsample``, or when it is None 2 for a
    pyramid (:attr:`~prismstereo.classical.model.PrismStereo.binned` set) and 1 for a one-level model.

    Example:
        >>> from prismstereo.classical.model import PrismStereo
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
        model: a :class:`~prismstereo.classical.model.PrismStereo` with a full-resolution band
            (:func:`supports_temporal`): its final level's sweep, cost, confidence and validity rules are used, its
        coarse search is not. options: the band (``band``, ``band_edges``, ``reach``, ``downsample``); the key-frame
            rules are the stream's.

    Attributes:
        options: the options, ``downsample`` resolved.
        downsample: the binning of the band's capture (``options.downsample`` resolved).
        level: the :class:`~prismstereo.classical.level.DepthLevel` whose sweep, confidence and rules the band uses:
            the model's final level, or with ``downsample`` > 1 a level of the binned rig.

    Raises:
        OptionError: a model without a full-resolution band (a single full-range level, block mode, the learned
            model); a ``downsample`` that leaves the binned rig too few rows for a level.

    Example:
        >>> from prismstereo.classical.model import PrismStereo
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
        self.options = dataclasses.replace(self.options, downsample=k)  # resolved, as an exported graph's
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
        self.fine = FineBand(band_config.band_options(), self.options.band, final.step, final.split.split,
                             with_match=final.fine.with_match, vertex_limit=limit)
        self.calibration = None
        if final.calibration is not None:
            clamped = band_config.validity.confidence_weights == "clamped"
            self.calibration = ConfidenceModel(CLAMPED_WEIGHTS[0] if clamped else None)

    @property
    def rig(self):
        """The model's rig."""
        return self.model.rig

    def summary(self) -> str:
        """The band in a few words (for logs and the CLI).

        Example:
            >>> from prismstereo.classical.model import PrismStereo
            >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2})
            >>> TemporalDepth(model).summary()
            'temporal prior on sequences (a band +-1 around the previous depth between key frames)'
        """
        k = self.downsample
        binned = f" on the {k}x{k}-binned frame" if k > 1 else ""
        return f"temporal prior on sequences (a band +-{self.options.band}{binned} around the previous depth between " \
               "key frames)"

    @property
    def prior_size(self) -> tuple[int, int]:
        """(h, w) of the band's prior: the level's reference half (binned with ``downsample`` > 1)."""
        return self.level.rig.image_height, self.level.rig.reference_width

    def band_prior(self, depth: torch.Tensor, valid: torch.Tensor, confidence: torch.Tensor) -> BandPrior:
        """A full-resolution result (B, 1, H, W_ref) each (a key frame's) as this band's prior (B, 1, h, w):
        :func:`band_prior` with the model's range, ``min_prior_confidence`` and ``downsample``.

        Example:
            >>> from prismstereo.classical.model import PrismStereo
            >>> model = PrismStereo(thesis_setup1().downscaled(4), (400.0, 800.0), {"downsample": 2, "full_band": 2})
            >>> first = model(torch.rand(1, 1, 192, 256))
            >>> TemporalDepth(model).band_prior(*first[:3]).inverse.shape
            torch.Size([1, 1, 96, 64])
        """
        shape = (depth.shape[0], 1, self.rig.image_height, self.rig.reference_width)
        if tuple(depth.shape) != shape:
            raise ShapeError(f"the prior's depth must have shape {shape}, got {tuple(depth.shape)}")
        return band_prior(depth, valid, confidence, z_range=self.model.final.z_range,
                          min_confidence=self.options.min_prior_confidence, downsample=self.downsample,
                          size=self.prior_size)

    def track(self, image: torch.Tensor, prior: BandPrior) -> TrackedDepth:
        """Depth of ``image`` searched around ``prior``, and the prior it leaves for the next frame.

        Args:
            image: (B, C, H, W) the full sensor image in [0, 1].
            prior: BandPrior, (B, 1, h, w) each (:attr:`prior_size`): a key frame's (:meth:`band_prior`), the last
                tracked frame's, or one extrapolated from them.

        Returns:
            TrackedDepth: the DepthResult of (B, *, H, W_ref) tensors, as the model's, and this frame's BandPrior.

        Raises:
            ShapeError: an image of another sensor, a prior of another size or a non-bool ``placed``.

        Example:
            >>> from prismstereo.classical.model import PrismStereo
            >>> model = PrismStereo(thesis_setup1().downscaled(4), (400.0, 800.0), {"downsample": 2, "full_band": 2})
            >>> tracker = TemporalDepth(model); image = torch.rand(1, 1, 192, 256)
            >>> tracked = tracker.track(image, tracker.band_prior(*model(image)[:3]))
            >>> tracked.result.depth.shape, tracked.prior.placed.shape
            (torch.Size([1, 1, 192, 128]), torch.Size([1, 1, 96, 64]))
        """
        check_shape(image, ["B", "C", "H", "W"], "image")
        final = self.model.final
        h, w = self.rig.image_height, self.rig.image_width
        if image.shape[-2:] != (h, w):
            raise ShapeError(f"image is {image.shape[-1]}x{image.shape[-2]} px but the rig's sensor is {w}x{h}")
        shape = (image.shape[0], 1, *self.prior_size)
        for name, t in zip(BandPrior._fields, prior, strict=True):
            if tuple(t.shape) != shape:
                raise ShapeError(f"the prior's {name} must have shape {shape}, got {tuple(t.shape)}")
        if prior.placed.dtype != torch.bool:
            raise ShapeError(f"the prior's placed must be bool, got {prior.placed.dtype}")
        image, touched = self.model.bad_pixels(image)  # non-finite pixels: the model's rule (no depth where they reach)
        level, k = self.level, self.downsample
        with torch.no_grad():  # the prior only places the band
            z_range = torch.tensor(final.z_range, dtype=image.dtype, device=image.device)
            s_p = inverse_to_sweep(prior.inverse.to(image.dtype), z_range).clamp(-1.0, 1.0)
            s_c, reach = extend_estimate(s_p, prior.placed, self.options.reach)
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
        estimate = level.search_band(ref, other, s0, reach, ~prior.placed, None, fine=self.fine,
                                     calibration=self.calibration, free_offset=0.5)
        result = level.finish(estimate)
        if k > 1:
            binned = F.max_pool2d(touched.to(result.confidence), k, ceil_mode=True) > 0
            result = discard(result, crop(binned, *result.depth.shape[-2:]))
        else:
            result = discard(result, touched)
        with torch.no_grad():  # the next frame's prior, from the band's own result (not binned again from its
            # interpolation)
            following = band_prior(result.depth, result.valid, result.confidence, z_range=final.z_range,
                                   min_confidence=self.options.min_prior_confidence)
        return TrackedDepth(result if k == 1 else discard(self.full_resolution(result), touched), following)

    def forward(self, image: torch.Tensor, prior_depth: torch.Tensor, prior_valid: torch.Tensor,
                prior_confidence: torch.Tensor) -> DepthResult:
        """Depth of ``image`` searched around a previous full-resolution result: :meth:`track` of its
        :meth:`band_prior` (a video keeps the :class:`BandPrior` :meth:`track` returns instead).

        Args:
            image: (B, C, H, W) the full sensor image in [0, 1].
            prior_depth: (B, 1, H, W_ref) depth (mm) of the previous frame (any value where not valid).
            prior_valid: (B, 1, H, W_ref) bool.
            prior_confidence: (B, 1, H, W_ref) in [0, 1].

        Returns:
            DepthResult of (B, *, H, W_ref) tensors, as the model's.
        """
        check_shape(image, ["B", "C", "H", "W"], "image")
        shape = (image.shape[0], 1, self.rig.image_height, self.rig.reference_width)
        for name, t in (("prior_depth", prior_depth), ("prior_valid", prior_valid),
                        ("prior_confidence", prior_confidence)):
            if tuple(t.shape) != shape:
                raise ShapeError(f"{name} must have shape {shape}, got {tuple(t.shape)}")
        if prior_valid.dtype != torch.bool:
            raise ShapeError(f"prior_valid must be bool, got {prior_valid.dtype}")
        with torch.no_grad():
            prior = self.band_prior(prior_depth.to(image.dtype), prior_valid, prior_confidence)
        return self.track(image, prior).result

    def full_resolution(self, result: DepthResult) -> DepthResult:
        """A binned level's result (B, *, h, w) at the model's full resolution (B, *, H, W_ref): the sweep
        coordinate interpolated bilinearly, after each binned pixel without a depth (not valid; dense: not
        covered) took the mean of its neighbours with one (:func:`~prismstereo.matching.band.extend_estimate`,
        radius 1: valid pixels interpolate valid neighbours only); validity and confidence per block, none beyond
        the binned level's last row and column. What :meth:`forward` returns with ``downsample`` > 1.

        Example:
            >>> from prismstereo.classical.model import PrismStereo
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
