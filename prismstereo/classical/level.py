"""One resolution of :class:`~prismstereo.classical.model.PrismStereo`: a rig's sweep searched, refined and judged.

A :class:`DepthLevel` holds everything the model computes for one rig (the full sensor, or the sensor seen
through k x k binning): the exact sweep m(u, v, s) and its power series, the prism masks, the placement of the
final band and the final band itself, the confidence, the smoothing of the estimate and the validity rules.
Its band is placed in one of two ways:

* by its own coarse level (``coarse_factor`` f > 1): both halves box-downsampled by f and searched over the whole
  range (:func:`~prismstereo.matching.search.build_search`), the estimate extended by ``coarse_reach`` coarse
  pixels and upsampled; with f = 1 that search is the only (full-resolution) level;
* by a coarser level's estimate (a pyramid's full-resolution level, ``placed_by`` = k): the model passes the
  binned level's :meth:`~DepthLevel.placement` to :meth:`DepthLevel.depth`.

Then a band of 2 R + 1 hypotheses around every pixel on the exact sweep
(:class:`~prismstereo.matching.band.FineBand`), depth from the sweep coordinate (s is linear in 1/Z), the
calibrated confidence (:mod:`prismstereo.matching.confidence`), validity and a z-buffer occlusion test in the
other half. :class:`~prismstereo.classical.model.PrismStereo` composes one level, or a binned level and a
full-resolution level (the pyramid). A level's options are resolved by
:func:`~prismstereo.classical.defaults.resolve_level` (the model resolves them all at once,
:func:`~prismstereo.classical.defaults.resolve_config`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.classical.config import StereoConfig
from prismstereo.classical.defaults import resolve_level
from prismstereo.classical.level_geometry import fine_coefficients, level_geometry
from prismstereo.classical.search import build_search
from prismstereo.depth.resample import upsample
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.series import series_at
from prismstereo.epipolar.sweep import fit_sweep, sweep_to_depth
from prismstereo.errors import OptionError
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.band import FineBand, extend_estimate, texture_of
from prismstereo.matching.confidence import (
    CLAMPED_WEIGHTS,
    SMOOTHED_FEATURES,
    ConfidenceModel,
    confidence_features,
    local_spread,
    smoothed_features,
)
from prismstereo.matching.cost import reference_moments
from prismstereo.matching.occlusion import zbuffer_visible
from prismstereo.matching.postprocess import robust_mean
from prismstereo.matching.split import SplitImage

__all__ = ["DepthLevel", "LevelEstimate", "Placement"]


class Placement(NamedTuple):
    """A coarser level's estimate that places a level's band (:meth:`DepthLevel.placement`), at the coarser
    level's resolution.

    Attributes:
        s: (B, 1, h, w) sweep coordinate.
        valid: (B, 1, h, w) bool.
        similarity: (B, 1, h, w) its confidence (a feature of the calibrated confidence).
        reach: how many of its pixels the estimate is extended into invalid neighbours.
    """

    s: torch.Tensor
    valid: torch.Tensor
    similarity: torch.Tensor
    reach: int


class LevelEstimate(NamedTuple):
    """:meth:`DepthLevel.estimate`'s result, (B, *, H, W_ref) at the level's resolution.

    Attributes:
        s: (B, 1, H, W_ref) sweep coordinate (not yet clamped to [-1, 1]).
        ok: (B, 1, H, W_ref) bool, the search's own validity (before the confidence and occlusion rules).
        confidence: (B, 1, H, W_ref) the final NCC, or with ``validity='calibrated'`` the calibrated confidence.
        match: (B, 2, H, W_ref) full-sensor (u, v) of the match, or None (the smoothing recomputes it).
        features: (B, 6, H, W_ref) the calibrated confidence's features, else None.
        sampled: (B, 1, H, W_ref) bool, pixels whose band had a real sample.
    """

    s: torch.Tensor
    ok: torch.Tensor
    confidence: torch.Tensor
    match: torch.Tensor | None
    features: torch.Tensor | None
    sampled: torch.Tensor


class DepthLevel(nn.Module):
    """The depth of one rig's reference half: placement of the final band, the band, confidence, validity.

    Args:
        rig: the level's rig (the sensor, or the sensor binned by the model's ``downsample``).
        z_range_mm: (z_min, z_max) searched.
        config: the options (:class:`~prismstereo.classical.config.StereoConfig`), resolved by
            :func:`~prismstereo.classical.defaults.resolve_level` (a resolved config stays as it is) and kept as
            :attr:`config`.
        placed_by: k > 1: the band is placed by the estimate of a level binned by k (the pyramid's
            full-resolution level: f = k, R = ``full_band``, no search of its own); 0: its own coarse search.

    Raises:
        OptionError: options that do not fit the rig (:func:`~prismstereo.classical.defaults.resolve_level`).

    Example:
        >>> level = DepthLevel(thesis_setup1().downscaled(8), (400.0, 700.0), StereoConfig())
        >>> level.depth(torch.rand(1, 1, 96, 128)).depth.shape, level.config.validity.validity
        (torch.Size([1, 1, 96, 64]), 'thresholds')
    """

    def __init__(self, rig: BiPrismRig, z_range_mm: tuple[float, float], config: StereoConfig, *,
                 placed_by: int = 0) -> None:
        super().__init__()
        self.z_range = tuple(float(z) for z in z_range_mm)
        self.config = config = resolve_level(rig, self.z_range, config, placed_by=placed_by)
        search, validity = config.search, config.validity
        self.rig, self.split = rig, SplitImage(rig)
        fit = fit_sweep(rig, self.z_range)
        self.num_hypotheses, self.factor, self.band = search.num_hypotheses, search.coarse_factor, search.band
        self.placed_by = placed_by
        calibrated = validity.validity == "calibrated"
        smoothing = config.refinement.smoothing
        stage1, stage2 = CLAMPED_WEIGHTS if validity.confidence_weights == "clamped" else (None, None)
        self.calibration = ConfidenceModel(stage1) if calibrated else None
        self.smoothed_calibration = ConfidenceModel(stage2, SMOOTHED_FEATURES) if calibrated and smoothing else None

        # the masks of rays through the prism; the final band and the match output evaluate the sweep as truncated
        # power series in s (Horner's rule, within a fraction of a thousandth of a pixel of the polynomials) and the
        # band's validity from each pixel's interval of real samples (found on a table of positions, at build time
        # only): computed once per rig and range (level_geometry); a single-level search keeps the polynomials
        fine = None if placed_by else fine_coefficients(rig, fit)  # the search's polynomials
        geometry = level_geometry(rig, self.z_range, fit, self.split.split, fine)
        self.register_buffer("reference_valid", geometry.reference_valid)
        self.register_buffer("other_valid", geometry.other_valid)
        self.register_buffer("depths", sweep_to_depth(torch.linspace(-1, 1, self.num_hypotheses,
                                                                     dtype=torch.float64), fit.z_range).float())
        self.register_buffer("series", geometry.series)
        self.register_buffer("interval", geometry.interval)
        self.search = None
        self.rectification_residual_px: float | None = None
        if not placed_by:
            built = build_search(rig, fit, fine, config, geometry.other_valid)
            self.search, self.rectification_residual_px = built.search, built.rectification_residual_px
        self.fine = None
        if self.factor > 1:  # a smoothed s gets its match afterwards
            self.fine = FineBand(config.band_options(), self.band, self.step, self.split.split,
                                 with_match=not smoothing)

    @property
    def step(self) -> float:
        """The hypotheses' spacing in s (2 / (D - 1))."""
        return 2.0 / (self.num_hypotheses - 1)

    def coarse(self, image: torch.Tensor) -> torch.Tensor:
        """``image`` (B, C, H, W) box-averaged over f x f blocks (the last ones padded by replication): the coarse
        level's input, (B, C, ceil(H / f), ceil(W / f))."""
        f = self.factor
        h, w = image.shape[-2:]
        padded = F.pad(image, (0, math.ceil(w / f) * f - w, 0, math.ceil(h / f) * f - h), mode="replicate")
        return F.avg_pool2d(padded, f)

    def placement(self, image: torch.Tensor) -> Placement:
        """This level's estimate of ``image`` (B, C, h, w) as the placement of a finer level's band: its depth,
        extended twice as far as its own coarse level reached. A level that searches the whole range at its own
        resolution (``coarse_factor=1``) with the 'guided' aggregation passes its search's estimates unsmoothed,
        unfilled and without the similarity threshold (valid where the search had a real winner): its weakly
        textured pixels are placed by their own estimates, which the filter carries there, and the final band and
        its confidence judge them (the semi-global search's estimates placed that way give the thesis planes larger
        errors: ``docs/design.md``, *How the model picks its defaults*, the 'dense' preset)."""
        reach = 2 * self.config.search.coarse_reach * self.factor
        if self.factor == 1 and self.config.aggregation.aggregation == "guided":  # its estimates as they are
            ref, other = self.split(image)
            s, ok, confidence, _ = self.search(ref, other, final=False)
            ok = ok & self.reference_valid
            return Placement(s.clamp(-1.0, 1.0), ok, confidence * ok.to(confidence.dtype), reach)
        low = self.depth(image)
        return Placement(low.index * self.step - 1.0, low.valid, low.confidence, reach)

    def estimate(self, image: torch.Tensor, placement: Placement | None = None) -> LevelEstimate:
        """The final band's estimate of ``image`` (B, C, H, W) at this level's resolution.

        Args:
            image: (B, C, H, W) the level's capture.
            placement: with ``placed_by`` k: the k-binned level's :meth:`placement`, (B, 1, H / k, W_ref / k).

        Returns:
            LevelEstimate.
        """
        if (placement is None) != (not self.placed_by):
            raise OptionError("a placed level needs the coarser level's result, a level with its own search none")
        ref, other = self.split(image)
        h, w_ref = ref.shape[-2:]
        if self.factor == 1:
            s, ok, confidence, match = self.search(ref, other, final=True)
            return LevelEstimate(s, ok, confidence, match, None, ok)
        f, config = self.factor, self.config
        with torch.no_grad():  # the coarse level only places the fine band (its s0 is detached)
            if placement is None:
                coarse = self.search(self.coarse(ref), self.coarse(other), final=False)
                s_c, valid_c, radius = coarse.s, coarse.valid, config.search.coarse_reach
                similar_c = coarse.confidence * valid_c.to(coarse.confidence.dtype)
            else:  # the binned level's final estimate
                s_c, valid_c, similar_c, radius = placement
            s_c, reach = extend_estimate(s_c, valid_c, radius)

        def up(t: torch.Tensor, mode: str = "nearest") -> torch.Tensor:
            return upsample(t.to(ref.dtype), f, (h, w_ref), mode)

        s0 = up(s_c, "bilinear").detach().clamp(-1.0, 1.0)
        calibrated = config.validity.validity == "calibrated"
        if calibrated or config.validity.dense:  # beyond the reach: the coarse level's own estimate
            ok0 = torch.ones_like(s0, dtype=torch.bool)
        else:
            ok0 = up(reach) > 0.5
        similarity = up(similar_c, "bilinear") if calibrated else None
        return self.search_band(ref, other, s0, ok0, up(valid_c) < 0.5, similarity)

    def search_band(self, ref: torch.Tensor, other: torch.Tensor, s0: torch.Tensor, ok0: torch.Tensor,
                    rejected: torch.Tensor, similarity: torch.Tensor | None, *, fine: FineBand | None = None,
                    calibration: ConfidenceModel | None = None, free_offset: float = 0.0) -> LevelEstimate:
        """The final band around a placement, judged: the band (:class:`~prismstereo.matching.band.FineBand`),
        then the calibrated confidence, or the stricter match of pixels the placement only reached from a
        neighbour. :meth:`estimate` places it by a coarser estimate,
        :class:`~prismstereo.classical.temporal.TemporalDepth` by the previous frame.

        Args:
            ref, other: (B, C, H, W_ref) and (B, C, H, W_o) the two halves.
            s0: (B, 1, H, W_ref) the placement (detached, in [-1, 1]).
            ok0: (B, 1, H, W_ref) bool, where the placement holds.
            rejected: (B, 1, H, W_ref) bool, pixels the placement had no estimate of its own for (extended from a
                neighbour, or none).
            similarity: (B, 1, H, W_ref) the placement's similarity (a feature of the calibrated confidence); None:
                the band's own NCC where not ``rejected``.
            fine: the band (default: this level's).
            calibration: the calibrated confidence (default: this level's).
            free_offset: moves of the band's fit from s0 up to this many steps count as no move in the
                confidence's offset feature (a prior that lags a moving scene, :mod:`~prismstereo.classical.temporal`).

        Returns:
            LevelEstimate.
        """
        config = self.config
        fine = self.fine if fine is None else fine
        calibration = self.calibration if calibration is None else calibration
        # a feature of the calibrated confidence: the reference's texture (grey std over the cost window), the root of
        # its window moments' variance, which the band then takes too (ZNCC's, the wide box's weight; it computes
        # them itself otherwise)
        calibrated = config.validity.validity == "calibrated"
        moments = texture = None
        if calibrated:
            moments = reference_moments(ref, config.cost.window)  # ZNCC's gradients pass through these
            texture = texture_of(moments[1]).detach()
        s, ok, confidence, match = fine(ref, other, s0, ok0, self.series, self.interval, moments)
        sampled = ok  # the band had a real sample (a dense model's depths), before the validity rules
        features = None
        if calibrated:  # the probability of a depth within 1 % (matching.confidence)
            if similarity is None:
                similarity = confidence.detach().clamp(0.0, 1.0) * (~rejected).to(confidence.dtype)
            placed_at = s0
            if free_offset:
                free = free_offset * self.step
                placed_at = s0 + (s.detach() - s0).clamp(-free, free)
            features = confidence_features(confidence, similarity, s.detach(), placed_at, texture, self.step,
                                           rejected)
            confidence = calibration(features)
        elif config.search.coarse_reach:  # pixels the placement only reached from a neighbour: a stricter match
            ok = ok & (~rejected | (confidence >= config.validity.reach_confidence))
        return LevelEstimate(s, ok, confidence, match, features, sampled)

    def smooth(self, s: torch.Tensor, confidence: torch.Tensor, sampled: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """The confidence-weighted robust mean of the estimates around each pixel (``smoothing``; the confidence
        a weight, not a path of gradients), and for calibrated levels the confidence re-scored from the evidence
        around the pixel with those features (None otherwise: the confidence stays as it is). All (B, *, H, W_ref).
        """
        weight = confidence.detach().clamp(0.0, 1.0) * (sampled & self.reference_valid).to(s.dtype)
        refinement = self.config.refinement
        smoothed = robust_mean(s, weight, refinement.smoothing, refinement.smoothing_tolerance * self.step)
        if self.smoothed_calibration is None:
            return smoothed.values, confidence, None
        spread = local_spread(smoothed.values.detach() / self.step, weight > 0, refinement.smoothing)
        features = smoothed_features(weight, smoothed.agreement, smoothed.support, spread)
        return smoothed.values, self.smoothed_calibration(features), features

    def depth(self, image: torch.Tensor, placement: Placement | None = None) -> DepthResult:
        """Depth, validity, confidence, hypothesis index and match of the level's reference half.

        Args:
            image: (B, C, H, W) the level's capture in [0, 1].
            placement: see :meth:`estimate`.

        Returns:
            DepthResult, (B, *, H, W_ref).
        """
        return self.finish(self.estimate(image, placement))

    def finish(self, estimate: LevelEstimate) -> DepthResult:
        """An estimate of this level (:meth:`estimate`, or another placement's band such as
        :class:`~prismstereo.classical.temporal.TemporalDepth`'s) judged and converted: the smoothing, depth, the
        validity rules, the occlusion test and the masked confidence of :meth:`depth`.

        Args:
            estimate: (B, *, H, W_ref) at this level's resolution.

        Returns:
            DepthResult, (B, *, H, W_ref).
        """
        s, ok, confidence, match, _, sampled = estimate
        validity = self.config.validity
        s = s.clamp(-1.0, 1.0)
        if self.config.refinement.smoothing:  # its band returned no match: the series at the smoothed s
            s, confidence, _ = self.smooth(s, confidence, sampled)
        z_range = torch.tensor(self.z_range, dtype=s.dtype, device=s.device)
        depth = sweep_to_depth(s, z_range)
        if match is None:  # the series at s (the search's own match unless the estimate was smoothed)
            match = torch.cat(series_at(self.series, s), 1)
        valid = ok & self.reference_valid & (confidence >= validity.min_confidence)
        covered = sampled & self.reference_valid  # dense: a depth wherever the band had a real sample
        if validity.occlusion_tolerance is not None:
            occluders = None if validity.occluder_confidence is None else valid & (
                confidence >= validity.occluder_confidence)
            valid = valid & self.visible(match, depth, valid, occluders)
        if validity.dense and validity.dense_fill:  # the depths that are not valid: the mean of the valid around
            s = torch.where(covered, extend_estimate(s, valid, validity.dense_fill).s, s)
            depth, match = sweep_to_depth(s, z_range), torch.cat(series_at(self.series, s), 1)
        # confidence in [0, 1] times the mask: 0 where invalid, or in a dense model where there is no depth
        # (onnxruntime runs a Where on one thread, the product on all of them)
        if validity.dense:  # > 0 exactly where there is a depth (an NCC of 0 too)
            confidence = confidence.clamp_min(torch.finfo(confidence.dtype).tiny) * covered.to(confidence.dtype)
        else:
            confidence = confidence * valid.to(confidence.dtype)
        return DepthResult(depth, valid, confidence, (s + 1.0) / self.step, match)

    def visible(self, match: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor,
                occluders: torch.Tensor | None = None) -> torch.Tensor:
        """Z-buffer occlusion test in the other half (:func:`~prismstereo.matching.occlusion.zbuffer_visible` with
        this level's split and ``occlusion_tolerance``). ``match`` (B, 2, H, W_ref), ``depth`` and ``valid``
        (B, 1, H, W_ref); returns (B, 1, H, W_ref) bool."""
        return zbuffer_visible(match, depth, valid, self.split.split, self.split.width - self.split.split,
                               self.config.validity.occlusion_tolerance or 0.0, occluders)

    def summary(self) -> str:
        """The level in a few words (:meth:`PrismStereo.summary`)."""
        if self.factor == 1:
            return f"{self.num_hypotheses} hypotheses in one level"
        return (f"{self.num_hypotheses} hypotheses, {self.config.search.sampling} coarse level with factor "
                f"{self.factor} ({self.search.num_hypotheses} hypotheses), band +-{self.band}")
