"""``PrismStereo``: one bi-prism capture in, metric depth of the reference (left) half out.

The layers, in order:

1. :class:`~prismstereo.matching.split.SplitImage` at the apex column (moves with the prism offset).
2. The exact sweep m(u, v, s) (:mod:`prismstereo.epipolar.sweep`): where reference pixel (u, v) appears in
   the other half at sweep coordinate s (linear in 1/Z), fitted once per rig to ~1e-10 px.
3. **Coarse level** (``coarse_factor`` f > 1): both halves box-downsampled by f and searched over the full
   range (hypotheses <= 1 coarse px apart) with one of two samplings behind the same interface:

   * ``'rectified'`` (default here): both halves are row-rectified by vertical warps fitted to the exact sweep
     (:mod:`prismstereo.epipolar.row_rectify`; correspondences share a row to 2e-4 px with ``thesis_setup1``,
     0.1 px with ``thesis_setup2``), so every hypothesis is an integer column shift: a 1-D cost volume built by
     one gather (:func:`~prismstereo.matching.sweep_cost.shift_cost`), the winning shift turned into the
     sweep coordinate exactly (:func:`~prismstereo.epipolar.table.column_to_sweep`);
   * ``'sweep'``: every hypothesis warps the other half onto the reference pixels with the exact per-pixel
     sweep (:func:`~prismstereo.matching.sweep_cost.warp_slices`, one ``grid_sample`` of D x H x W samples).

   Then matching cost (ZNCC by default), box + semi-global aggregation (4 directions), winner-take-all with
   sub-pixel refinement, uniqueness confidence; the estimate is extended by ``coarse_reach`` coarse pixels
   into invalid neighbours (:func:`~prismstereo.matching.levels.extend_estimate`).
4. **Fine level**: the coarse estimate upsampled to full resolution; a band of 2 R + 1 hypotheses (<= 1 px
   apart) around it per pixel, evaluated on the exact per-pixel sweep (truncated power series,
   :mod:`prismstereo.epipolar.table`, within ~2e-4 px of the polynomials); cost, box, winner and
   sub-pixel refinement (equiangular, parabola or a differentiable local soft-argmin).
   With f = 1 the full range is searched at full resolution in one level (the reference mode).
5. Depth from the sweep coordinate (exact: s is linear in 1/Z), a confidence (the calibrated probability of a
   depth within 1 %, :mod:`prismstereo.matching.confidence`), validity (inside the common field of view, winner
   inside the band, confidence) and a z-buffer occlusion test in the other half; with ``dense`` every pixel of
   the common field of view keeps its depth and confidence.

With ``downsample`` k and ``full_band`` R the coarse level of step 3 is a whole model of the k x k-binned capture
(:attr:`PrismStereo.binned`, steps 1-5 on the binned rig), and step 4 a band of 2 R + 1 full-resolution
hypotheses around its estimate: a pyramid with full lateral resolution in about half the time of the
full-resolution coarse level. It is the default on sensors whose reference half is >= 384 px on its shorter
side (k = 2, R = 2: the thesis setups at 1024 x 768; :meth:`PrismStereo.default_downsample`); smaller sensors
get steps 3-4 at full resolution (``downsample=1``), as any sensor does when asked.

Why these defaults (coarse-to-fine, the rectified coarse level, the pyramid, each option's value) and what the
alternatives measured: ``docs/design.md`` (*How the model picks its defaults*; the rules: :mod:`prismstereo.defaults`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.batching import per_image
from prismstereo.config import StereoConfig, preset
from prismstereo.defaults import default_coarse_factor, default_downsample, pyramid_band, pyramid_coarse_factor
from prismstereo.depth.occlusion import zbuffer_visible
from prismstereo.depth.range import default_z_range
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.series import series_at, sweep_series
from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients, sweep_hypotheses, sweep_to_depth
from prismstereo.epipolar.sweep_table import tabulate_sweep, valid_interval
from prismstereo.errors import OptionError, ShapeError, check_option, check_shape
from prismstereo.geometry.optics import check_rig_images, trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.aggregate import box_std
from prismstereo.matching.build import build_search
from prismstereo.matching.confidence import (
    CLAMPED_WEIGHTS,
    FITTED_PLACEMENT,
    SMOOTHED_FEATURES,
    ConfidenceModel,
    confidence_features,
    smoothed_features,
)
from prismstereo.matching.cost import COSTS, Cost
from prismstereo.matching.levels import FineBand, SearchOptions, extend_estimate
from prismstereo.matching.postprocess import robust_mean
from prismstereo.matching.split import SplitImage

__all__ = [
    "ConfidenceInputs", "DepthResult", "PrismStereo", "Refinement", "Sampling", "Validity", "sweep_hypotheses",
]

Refinement = Literal["equiangular", "parabola", "soft_argmin"]
Sampling = Literal["sweep", "rectified"]
BandEdges = Literal["reject", "clamp"]
Validity = Literal["calibrated", "thresholds"]
VALIDITIES: tuple[str, ...] = ("calibrated", "thresholds")
BAND_EDGES: tuple[str, ...] = ("reject", "clamp")
SAMPLINGS: tuple[str, ...] = ("sweep", "rectified")
REFINEMENTS: tuple[str, ...] = ("equiangular", "parabola", "soft_argmin")
Matcher = Literal["classical", "learned"]
MATCHERS: tuple[str, ...] = ("classical", "learned")


class ConfidenceInputs(NamedTuple):
    """:meth:`PrismStereo.confidence_inputs`' result.

    Attributes:
        features: (B, 6, H, W_ref) :func:`~prismstereo.matching.confidence.confidence_features`.
        depth: (B, 1, H, W_ref) the depth (mm) they describe.
        sampled: (B, 1, H, W_ref) bool, pixels with an estimate (the confidence applies there).
        smoothed_features: (B, 3, H, W_ref) :func:`~prismstereo.matching.confidence.smoothed_features` of the
            smoothed estimate (``smoothing`` > 0), else None.
        smoothed_depth: (B, 1, H, W_ref) the depth (mm) after smoothing (what they describe), else None.
    """

    features: torch.Tensor
    depth: torch.Tensor
    sampled: torch.Tensor
    smoothed_features: torch.Tensor | None = None
    smoothed_depth: torch.Tensor | None = None


class _Estimate(NamedTuple):
    s: torch.Tensor
    ok: torch.Tensor
    confidence: torch.Tensor
    match: torch.Tensor | None
    features: torch.Tensor | None
    sampled: torch.Tensor


def _learned_model(rig: BiPrismRig, z_range_mm: tuple[float, float] | None = None, num_hypotheses: int | None = None,
                   *, matcher: str = "learned", weights: str = "default", **options: object) -> nn.Module:
    """``PrismStereo(..., matcher='learned')``: the :class:`~prismstereo.learned.LearnedStereo` of the rig."""
    from prismstereo.learned import LearnedStereo

    if options:
        raise OptionError(f"matcher='learned' takes z_range_mm, num_hypotheses and weights, not "
                          f"{', '.join(sorted(options))}")
    check_rig_images(rig)  # before default_z_range traces it
    z_range = default_z_range(rig) if z_range_mm is None else z_range_mm
    return LearnedStereo(rig, tuple(z_range), num_hypotheses=num_hypotheses or 48, weights=weights)


class PrismStereo(nn.Module):
    """Depth from one bi-prism capture: exact plane sweep, coarse-to-fine.

    Args:
        rig: the rig; its geometry is checked first (:func:`~prismstereo.geometry.optics.check_rig_images`:
            :class:`~prismstereo.errors.RigError` if a half-image sees nothing through the prism).
        z_range_mm: (z_min, z_max) depth range searched; default
            :func:`~prismstereo.depth.range.default_z_range` (from the rig's common field of view).
        num_hypotheses: D at full resolution, uniform in 1/Z; default: neighbours <= 1 px apart.
        cost: cost of the coarse (or single) level: 'zncc' (default; invariant to gain and offset differences
            between the halves), 'census' or 'sad' (:mod:`prismstereo.matching.sweep_cost`).
        fine_cost: cost of the fine band, default 'zncc' (sub-pixel accurate with the parabola fit).
        sampling: how the coarse (or single) level samples the other half: 'rectified' (a 1-D shift volume on
            row-rectified halves) or 'sweep' (the exact per-pixel plane sweep); None (default): 'rectified'
            for a coarse level, 'sweep' for a single full-resolution level (:mod:`prismstereo.defaults`).
        window: census / ZNCC window (odd).
        census_threshold: census bits count neighbours darker than the centre by more than this (the default
            keeps torch and onnxruntime bitwise equal on 8-bit captures).
        box: box aggregation window of the coarse (or single) level.
        fine_box: box window of the fine band.
        aggregation: 'sgm' (semi-global after the box) or 'box'.
        directions: SGM scan directions, 2, 4 (default: horizontal and vertical) or 8.
        p1, p2: SGM penalties in units of the box-averaged cost (ZNCC: 1 - NCC in [0, 2]).
        coarse_factor: f, the coarse level's downsampling (1 = one full-resolution level); default
            :meth:`default_coarse_factor`.
        band: R, the fine band is s0 + j step, j = -R..R; default f + 1, and
            :func:`~prismstereo.defaults.pyramid_band` (ceil(3 f / 4)) for the binned model of a pyramid
            (``full_band``), whose estimate only places the full-resolution band.
        refinement: sub-pixel refinement of the final level: None (default) picks the fit matching each
            level's cost (equiangular for L1-type census/SAD, parabola for ZNCC); 'equiangular',
            'parabola', or 'soft_argmin' (a local soft-argmin, differentiable w.r.t. the cost: gradients reach
            the image with 'sad' or 'zncc').
        min_confidence: pixels with a lower ``confidence`` are invalid (with ``validity`` 'calibrated' the
            probability of a depth within 1 %; with 'thresholds' the final level's NCC).
        min_uniqueness: with ``validity`` 'thresholds' (a calibrated model's coarse level keeps the thresholds the
            confidence was fitted with, :data:`~prismstereo.matching.confidence.FITTED_PLACEMENT`): pixels whose
            coarse (or single) level winner is not unique enough, 1 - best / second best aggregated cost outside
            winner +- 1 below this, are invalid (false matches of pixels that the other half does not see have a
            runner-up close to the winner).
        occlusion_tolerance: relative depth margin of the z-buffer occlusion test, None to skip it.
        occluder_confidence: only valid pixels with at least this confidence occlude others in that test (None:
            every valid pixel): a false match would otherwise push the true match of the other-half pixel it
            claims out.
        lr_threshold: left-right check of the rectified level (``sampling='rectified'``; the sweep has no
            cheap view from the other half): the other half's winners over the same aggregated shift volume
            must agree with the reference's to this many level pixels; None (default) skips it (it rejected
            true matches near the edge of the common field of view of ``thesis_setup1``).
        downsample: k > 1 matches on the capture box-averaged over k x k pixel blocks (the rig seen through
            that binning, :meth:`~prismstereo.geometry.rig.BiPrismRig.binned`: exact geometry, pixels k times
            larger) and returns the depth on the full-resolution reference grid: re-estimated there by a
            full-resolution band with ``full_band`` > 0 (the pyramid), else each pixel with its block's values
            (nearest; ``match`` in full-sensor pixels), a speed knob of ~k^2 less work at k times coarser
            lateral and disparity resolution. ``num_hypotheses``, ``coarse_factor`` and ``band`` then refer to
            the binned image. None (default): :meth:`default_downsample`, with ``full_band`` 2 when that is > 1
            (the pyramid on 1024 x 768 sensors); 1 is the full-resolution coarse level of steps 3-4.
        coarse_reach: invalid coarse pixels within this many coarse pixels of valid ones take their valid
            neighbours' mean s (:func:`~prismstereo.matching.levels.extend_estimate`) before it is upsampled
            for the fine band (the coarse level loses a margin of about its window at the edges of the common
            field of view); 0 leaves the coarse estimate as it is.
        reach_confidence: with ``validity`` 'thresholds': the fine band's NCC a pixel needs when only its coarse
            neighbours were valid (the others need ``min_confidence``).
        full_band: with ``downsample`` k > 1, R > 0 makes a pyramid: the model of the binned capture (every
            option above applies to it; :attr:`binned`) estimates s, which is extended by 2 ``coarse_reach``
            times its coarse factor binned pixels and upsampled bilinearly to place a band of 2 R + 1 hypotheses
            (<= 1 px apart) at full resolution around every pixel, evaluated like the fine band on the exact
            full-resolution sweep. Full lateral resolution at about the binned model's price plus a thin band;
            0 gives each pixel its block's values; None (default): 2 with the default ``downsample`` when that
            is > 1, else 0 (an explicit ``downsample`` keeps block values unless ``full_band`` is given).
        band_edges: what a fine band (the pyramid's full-resolution band, and the fine band of every coarse-to-fine
            level) does with a pixel whose best hypothesis is on the band's edge, i.e. whose match lies beyond
            the band: 'reject' (default) makes it invalid; 'clamp' takes the edge's inner neighbour as the winner
            and refines there, so s moves at most half a step beyond it, with that hypothesis' confidence (still
            subject to ``min_confidence`` / ``reach_confidence``). With ``full_band=1`` (a band of 3) it is the
            fast full-resolution setting (faster; more false matches on ``thesis_setup2``).
        validity: how ``confidence`` and ``valid`` are decided. 'calibrated' (the default of coarse-to-fine
            models): every pixel gets a final band (around the coarse estimate extended to its neighbours, or
            beyond their reach the coarse level's own rejected estimate), and the confidence is the probability
            that the pixel's depth is within 1 % of the truth, from its final NCC, the coarse level's NCC (0 where
            its thresholds rejected it), the estimate's roughness, the band's offset from the coarse placement,
            the window's texture and whether the coarse level rejected it
            (:mod:`prismstereo.matching.confidence`, fitted on renders by ``benchmarks/fit_confidence.py``;
            the reliability on held-out scenes: ``benchmarks/dense_depth.py``). 'thresholds' (single levels):
            the NCC, ``min_uniqueness`` and ``reach_confidence`` rules.
        dense: a depth for every reference pixel the final band can sample (the common field of view): pixels
            beyond the coarse estimate's reach get a band around the coarse level's own (rejected) estimate, a
            match beyond the band keeps the band's nearest estimate (``band_edges`` 'clamp' for the final band),
            and ``confidence`` is > 0 exactly where there is a depth (0 elsewhere); ``valid`` stays the mask of
            the confident pixels (``min_confidence``, occlusion test).
        wide_box: where the reference has little texture, the final band's box-averaged cost is blended with
            the cost averaged over this wider box (0: off; :class:`~prismstereo.matching.levels.FineBand`; not in
            the binned model of a pyramid, which only places the band): weak texture and defocus leave a small
            window's minimum to noise.
        weak_texture: the grey standard deviation over the cost window below which that blend starts (full at 0).
        dense_fill: with ``dense``, the pixels with a depth that are not valid take the mean sweep coordinate of
            the valid pixels within this many pixels (a normalised box convolution; 0: their own estimates),
            where there are any (:func:`~prismstereo.matching.levels.extend_estimate`); their confidence stays
            their own match's.
        smoothing: the final estimate (and the binned model's) becomes the confidence-weighted mean of the
            estimates within a ``smoothing`` x ``smoothing`` window that agree with the window's mean to
            ``smoothing_tolerance`` hypothesis steps (:func:`~prismstereo.matching.postprocess.robust_mean`; 0:
            off): sub-pixel noise of weak texture and defocus averages out, depth steps stay, confident pixels
            that disagree (thin structures) keep their own estimate, and a calibrated model re-scores each
            pixel's confidence from the evidence around it
            (:data:`~prismstereo.matching.confidence.SMOOTHED_FEATURES`).
        smoothing_tolerance: see ``smoothing`` (hypothesis steps, > 0).
        matcher: 'classical' (this model) or 'learned': then the constructor returns a
            :class:`~prismstereo.learned.LearnedStereo` (shipped weights, or ``weights=PATH``; it takes
            ``z_range_mm`` and ``num_hypotheses`` (default 48), no other option) with the same
            :class:`DepthResult` output, which is not a ``PrismStereo`` instance.

    The measurements behind each default and the alternatives: ``docs/design.md``.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> model = PrismStereo(small, (400.0, 700.0))
        >>> model(torch.rand(1, 1, 96, 128)).depth.shape
        torch.Size([1, 1, 96, 64])
    """

    def __new__(cls, *args: object, **kwargs: object):
        """``matcher='learned'`` returns the learned model instead (see the class docstring)."""
        if kwargs.get("matcher") == "learned":
            return _learned_model(*args, **kwargs)
        return super().__new__(cls)

    def __init__(
        self,
        rig: BiPrismRig,
        z_range_mm: tuple[float, float] | None = None,
        num_hypotheses: int | None = None,
        *,
        cost: Cost = "zncc",
        fine_cost: Cost = "zncc",
        sampling: Sampling | None = None,
        window: int = 5,
        census_threshold: float = 0.4 / 255,
        box: int = 5,
        fine_box: int = 7,
        aggregation: Literal["sgm", "box"] = "sgm",
        directions: int = 4,
        p1: float = 1.0,
        p2: float = 8.0,
        coarse_factor: int | None = None,
        band: int | None = None,
        refinement: Refinement | None = None,
        min_confidence: float = 0.5,
        min_uniqueness: float = 0.3,
        occlusion_tolerance: float | None = 0.01,
        occluder_confidence: float | None = 0.8,
        lr_threshold: float | None = None,
        downsample: int | None = None,
        coarse_reach: int = 1,
        reach_confidence: float = 0.9,
        full_band: int | None = None,
        band_edges: BandEdges = "reject",
        validity: Validity | None = None,
        dense: bool = False,
        wide_box: int = 21,
        weak_texture: float = 8.0 / 255,
        dense_fill: int = 15,
        smoothing: int = 15,
        smoothing_tolerance: float = 4.0,
        matcher: Matcher = "classical",
    ) -> None:
        super().__init__()
        check_rig_images(rig)  # the rig's geometry, before anything traces it
        check_option(matcher, MATCHERS, "matcher")  # 'learned' never gets here: see __new__
        if validity is not None:
            check_option(validity, VALIDITIES, "validity")
        if not isinstance(dense, bool):
            raise OptionError(f"dense must be a bool, got {dense!r}")
        level_options = dict(  # everything but the resolution: the binned model of a pyramid gets the same
            cost=cost, fine_cost=fine_cost, sampling=sampling, window=window, census_threshold=census_threshold,
            box=box, fine_box=fine_box, aggregation=aggregation, directions=directions, p1=p1, p2=p2,
            coarse_factor=coarse_factor, band=band, refinement=refinement, min_confidence=min_confidence,
            min_uniqueness=min_uniqueness, occlusion_tolerance=occlusion_tolerance,
            occluder_confidence=occluder_confidence, lr_threshold=lr_threshold, coarse_reach=coarse_reach,
            reach_confidence=reach_confidence, band_edges=band_edges, wide_box=wide_box, weak_texture=weak_texture,
            smoothing=smoothing, smoothing_tolerance=smoothing_tolerance)
        # the binned model of a pyramid places the final band: its thresholds decide which estimates are
        # extended to their neighbours; its NCC is a feature of the calibrated confidence
        placement = dict(level_options, validity="thresholds", dense=False, wide_box=0)
        if validity in (None, "calibrated"):  # the coarse validity the confidence was fitted with
            placement.update(FITTED_PLACEMENT)
        check_option(cost, COSTS, "cost")
        check_option(band_edges, BAND_EDGES, "band_edges")
        check_option(fine_cost, COSTS, "fine_cost")
        if sampling is not None:
            check_option(sampling, SAMPLINGS, "sampling")
        check_option(aggregation, ("sgm", "box"), "aggregation")
        if refinement is not None:
            check_option(refinement, REFINEMENTS, "refinement")
        for name, value in (("box", box), ("fine_box", fine_box), ("window", window)):
            if not isinstance(value, int) or value < 1 or value % 2 == 0:
                raise OptionError(f"{name} must be a positive odd int, got {value!r}")
        if isinstance(wide_box, bool) or not isinstance(wide_box, int) or wide_box < 0 or (
                wide_box and wide_box % 2 == 0):
            raise OptionError(f"wide_box must be 0 (off) or a positive odd int, got {wide_box!r}")
        if isinstance(weak_texture, bool) or not (isinstance(weak_texture, (int, float))
                                                  and 0 < weak_texture < math.inf):
            raise OptionError(f"weak_texture must be a finite number > 0, got {weak_texture!r}")
        if isinstance(dense_fill, bool) or not isinstance(dense_fill, int) or dense_fill < 0:
            raise OptionError(f"dense_fill must be an int >= 0, got {dense_fill!r}")
        if isinstance(smoothing, bool) or not isinstance(smoothing, int) or smoothing < 0 or (
                smoothing and (smoothing < 3 or smoothing % 2 == 0)):
            raise OptionError(f"smoothing must be 0 (off) or an odd int >= 3, got {smoothing!r}")
        if isinstance(smoothing_tolerance, bool) or not (isinstance(smoothing_tolerance, (int, float))
                                                         and 0 < smoothing_tolerance < math.inf):
            raise OptionError(f"smoothing_tolerance must be a finite number > 0, got {smoothing_tolerance!r}")
        if downsample is None:  # the default: the pyramid on large sensors
            downsample = self.default_downsample(rig)
            full_band = (2 if downsample > 1 else 0) if full_band is None else full_band
        full_band = 0 if full_band is None else full_band
        if not isinstance(downsample, int) or downsample < 1 or rig.image_height // downsample < 16:
            raise OptionError(f"downsample must be an int >= 1 leaving >= 16 rows, got {downsample!r}")
        if not isinstance(full_band, int) or full_band < 0 or (full_band and downsample == 1):
            raise OptionError(f"full_band must be an int >= 0, and > 0 only with downsample > 1, got {full_band!r}")
        self.rig, self.downsample = rig, downsample
        z_range_mm = default_z_range(rig) if z_range_mm is None else z_range_mm
        self.binned: PrismStereo | None = None
        if full_band:  # a pyramid: the binned model places a full-resolution band of 2 full_band + 1 hypotheses
            binned = rig.binned(downsample)
            self.binned = PrismStereo(binned, z_range_mm, num_hypotheses, downsample=1, full_band=0, **placement)
            factor = pyramid_coarse_factor(self.binned.num_hypotheses, binned.image_height, binned.reference_width)
            if coarse_factor is None and factor != self.binned.factor:  # its estimate only places the final band
                self.binned = PrismStereo(binned, z_range_mm, self.binned.num_hypotheses, downsample=1, full_band=0,
                                          **{**placement, "coarse_factor": factor})
            if band is None and self.binned.factor > 1:  # its band only places the final one: see ``band``
                self.binned._set_band(pyramid_band(self.binned.factor))
            num_hypotheses, coarse_factor, band = None, downsample, full_band
            sampling = self.binned.sampling
        elif downsample > 1:  # everything below works on the binned capture
            rig = rig.binned(downsample)
        self.split = SplitImage(rig)
        fit = fit_sweep(rig, z_range_mm)
        h, w_ref = rig.image_height, rig.reference_width
        self.z_range = tuple(float(z) for z in z_range_mm)
        f64 = torch.float64
        uv = torch.stack(torch.meshgrid(torch.arange(w_ref, dtype=f64), torch.arange(h, dtype=f64),
                                        indexing="xy"), -1)  # (H, W_ref, 2)
        fine = sweep_coefficients(fit, uv).permute(2, 0, 1, 3).contiguous()  # (N, H, W_ref, 2) pixels
        if num_hypotheses is None:
            num_hypotheses = sweep_hypotheses(fine)
        elif not isinstance(num_hypotheses, int) or num_hypotheses < 2:
            raise OptionError(f"num_hypotheses must be an int >= 2 or None, got {num_hypotheses!r}")
        if coarse_factor is None:
            coarse_factor = self.default_coarse_factor(num_hypotheses, h, w_ref)
        if not isinstance(coarse_factor, int) or coarse_factor < 1 or h // coarse_factor < 8:
            raise OptionError(f"coarse_factor must be an int >= 1 leaving >= 8 rows, got {coarse_factor!r}")
        self.factor = coarse_factor
        self.band = coarse_factor + 1 if band is None else band
        if not isinstance(self.band, int) or self.band < 1:
            raise OptionError(f"band must be an int >= 1, got {band!r}")
        self.fine_cost = fine_cost
        self.sampling = sampling or ("rectified" if coarse_factor > 1 else "sweep")
        self.cost, self.window, self.box, self.fine_box = cost, window, box, fine_box
        if not (isinstance(census_threshold, (int, float)) and census_threshold >= 0):
            raise OptionError(f"census_threshold must be a number >= 0, got {census_threshold!r}")
        self.census_threshold = float(census_threshold)
        if directions not in (2, 4, 8):
            raise OptionError(f"directions must be 2, 4 or 8, got {directions!r}")
        self.aggregation, self.directions, self.p1, self.p2 = aggregation, directions, p1, p2
        self.refinement, self.min_confidence, self.min_uniqueness = refinement, min_confidence, min_uniqueness
        self.occlusion_tolerance = occlusion_tolerance
        if occluder_confidence is not None and not 0 <= occluder_confidence <= 1:
            raise OptionError(f"occluder_confidence must be in [0, 1] or None, got {occluder_confidence!r}")
        self.occluder_confidence = occluder_confidence
        if lr_threshold is not None and not lr_threshold > 0:
            raise OptionError(f"lr_threshold must be > 0 or None, got {lr_threshold!r}")
        self.lr_threshold = lr_threshold
        if not isinstance(coarse_reach, int) or coarse_reach < 0:
            raise OptionError(f"coarse_reach must be an int >= 0, got {coarse_reach!r}")
        if not 0 <= reach_confidence <= 1:
            raise OptionError(f"reach_confidence must be in [0, 1], got {reach_confidence!r}")
        self.coarse_reach, self.reach_confidence = coarse_reach, float(reach_confidence)
        self.band_edges = band_edges
        self.num_hypotheses = num_hypotheses
        if validity is None:
            validity = "calibrated" if coarse_factor > 1 else "thresholds"
        if validity == "calibrated" and coarse_factor == 1:
            raise OptionError("validity 'calibrated' needs a coarse-to-fine model (coarse_factor > 1 or a pyramid); "
                              "a single level has 'thresholds'")
        if dense and coarse_factor == 1:
            raise OptionError("dense needs a coarse-to-fine model (coarse_factor > 1 or a pyramid): a single level "
                              "has no band to place everywhere")
        self.validity, self.dense = validity, dense
        self.wide_box, self.weak_texture, self.dense_fill = wide_box, float(weak_texture), dense_fill
        self.smoothing, self.smoothing_tolerance = smoothing, float(smoothing_tolerance)
        # a final band that clamps its edges (not a dense model's, fitted with the default) has its own weights
        self.clamped_band = band_edges == "clamp" and not dense
        stage1, stage2 = CLAMPED_WEIGHTS if self.clamped_band else (None, None)
        calibrated = validity == "calibrated"
        self.calibration = ConfidenceModel(stage1) if calibrated else None
        self.smoothed_calibration = ConfidenceModel(stage2, SMOOTHED_FEATURES) if calibrated and smoothing else None

        w_o = rig.image_width - w_ref
        rays = trace_pixels(rig, uv.view(-1, 2))
        self.register_buffer("reference_valid", (rays.valid & rays.left).view(h, w_ref))
        uv_o = torch.stack(torch.meshgrid(torch.arange(w_ref, rig.image_width, dtype=f64),
                                          torch.arange(h, dtype=f64), indexing="xy"), -1)
        rays_o = trace_pixels(rig, uv_o.view(-1, 2))
        other_valid = (rays_o.valid & ~rays_o.left).view(h, w_o)
        self.register_buffer("other_valid", other_valid)
        self.register_buffer("depths", sweep_to_depth(torch.linspace(-1, 1, num_hypotheses, dtype=f64),
                                                      fit.z_range).float())
        # the fine level and the match output evaluate the sweep as truncated power series in s (Horner's rule:
        # no table lookups; ~2e-4 px from the polynomials) and the band's validity from each pixel's interval of
        # real samples (found on a table of positions, at build time only); the single-level search keeps the
        # polynomials (one matrix product for all hypotheses)
        self.register_buffer("series", sweep_series(fine).float())
        self.register_buffer("interval", valid_interval(tabulate_sweep(fine).float(), other_valid, self.split.split))
        options = SearchOptions(cost=cost, window=window, census_threshold=self.census_threshold, box=box,
                                aggregation=aggregation, directions=directions, p1=p1, p2=p2, refinement=refinement,
                                min_uniqueness=FITTED_PLACEMENT["min_uniqueness"] if validity == "calibrated"
                                else min_uniqueness)
        # the coarse level: a pyramid's is the binned model
        self.search = None
        if self.binned is None:
            built = build_search(rig, fit, fine, options, self.sampling, coarse_factor, num_hypotheses, other_valid,
                                 lr_threshold)
            self.search = built.search
            if built.rectification_residual_px is not None:
                self.rectification_residual_px = built.rectification_residual_px
        self.coarse_hypotheses = (self.search if self.binned is None else self.binned).num_hypotheses
        if coarse_factor > 1:
            fine_options = dataclasses.replace(options, cost=fine_cost, box=fine_box,
                                               band_edges="clamp" if dense else band_edges, wide_box=wide_box,
                                               weak_texture=float(weak_texture))
            self.fine = FineBand(fine_options, self.band, 2.0 / (num_hypotheses - 1), self.split.split,
                                 with_match=not smoothing)  # a smoothed s gets its match afterwards

    def _set_band(self, band: int) -> None:
        """Rebuild the fine band after the coarse level with half width ``band``."""
        self.band = band
        self.fine = FineBand(self.fine.options, band, self.fine.step, self.fine.split, self.fine.with_match)

    @classmethod
    def from_config(
        cls, rig: BiPrismRig, z_range_mm: tuple[float, float] | None = None,
        config: StereoConfig | str | None = None,
    ) -> PrismStereo:
        """The model of a :class:`~prismstereo.config.StereoConfig` or a preset's name ('accurate' (default),
        'fast', 'dense', 'reference'; :data:`~prismstereo.config.PRESETS`).

        Example:
            >>> PrismStereo.from_config(thesis_setup1().downscaled(8), (400.0, 700.0), "fast").summary()
            '2x2-binned model (8 hypotheses in one level), then a full-resolution band +-1 of 15, band edges clamped'
        """
        resolved = preset("accurate" if config is None else config) if isinstance(config, str) or config is None \
            else config
        if not isinstance(resolved, StereoConfig):
            raise OptionError(f"config must be a StereoConfig or a preset name, got {type(config).__name__}")
        return cls(rig, z_range_mm, **resolved.to_kwargs())

    def config(self) -> dict[str, object]:
        """The constructor's options as resolved (defaults filled in), JSON-ready; with the rig
        (:meth:`BiPrismRig.to_dict`) they rebuild the same model: ``PrismStereo(rig, **model.config())``.

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0))
            >>> PrismStereo(model.rig, **model.config()).num_hypotheses == model.num_hypotheses
            True
        """
        if self.binned is not None:  # the options went to the binned model (its own thresholds: this model's)
            return {**self.binned.config(), "downsample": self.downsample, "full_band": self.band,
                    "min_confidence": self.min_confidence, "min_uniqueness": self.min_uniqueness,
                    "validity": self.validity, "dense": self.dense, "wide_box": self.wide_box,
                    "weak_texture": self.weak_texture, "dense_fill": self.dense_fill, "smoothing": self.smoothing,
                    "smoothing_tolerance": self.smoothing_tolerance}
        return {
            "z_range_mm": list(self.z_range), "num_hypotheses": self.num_hypotheses, "cost": self.cost,
            "fine_cost": self.fine_cost, "sampling": self.sampling, "window": self.window,
            "census_threshold": self.census_threshold,
            "box": self.box, "fine_box": self.fine_box, "aggregation": self.aggregation,
            "directions": self.directions, "p1": self.p1, "p2": self.p2, "coarse_factor": self.factor,
            "band": self.band, "refinement": self.refinement, "min_confidence": self.min_confidence,
            "min_uniqueness": self.min_uniqueness, "occlusion_tolerance": self.occlusion_tolerance,
            "occluder_confidence": self.occluder_confidence, "lr_threshold": self.lr_threshold,
            "downsample": self.downsample, "coarse_reach": self.coarse_reach,
            "reach_confidence": self.reach_confidence, "full_band": 0, "band_edges": self.band_edges,
            "validity": self.validity, "dense": self.dense, "wide_box": self.wide_box,
            "weak_texture": self.weak_texture, "dense_fill": self.dense_fill, "smoothing": self.smoothing,
            "smoothing_tolerance": self.smoothing_tolerance,
        }

    def summary(self) -> str:
        """The model's levels in one line (for logs, the CLI and the benchmarks).

        Example:
            >>> PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0)).summary()
            '15 hypotheses in one level'
            >>> PrismStereo(thesis_setup1(), (228.0, 1374.0)).summary()
            '2x2-binned model (192 hypotheses, rectified coarse level ... +-3), then a full-resolution band +-2 of 382'
        """
        def level(m: PrismStereo) -> str:
            if m.factor == 1:
                return f"{m.num_hypotheses} hypotheses in one level"
            return (f"{m.num_hypotheses} hypotheses, {m.sampling} coarse level with factor {m.factor} "
                    f"({m.coarse_hypotheses} hypotheses), band +-{m.band}")

        k = self.downsample
        has_band = self.binned is not None or self.factor > 1  # a single level has no band to clamp
        edges = ", band edges clamped" if self.band_edges == "clamp" and has_band else ""
        if self.binned is not None:
            return (f"{k}x{k}-binned model ({level(self.binned)}), then a full-resolution band +-{self.band} of "
                    f"{self.num_hypotheses}{edges}")
        return level(self) + (f", on {k}x{k}-binned pixels" if k > 1 else "") + edges

    @staticmethod
    def default_downsample(rig: BiPrismRig) -> int:
        """:func:`prismstereo.defaults.default_downsample` (the model calls it through here).

        Example:
            >>> [PrismStereo.default_downsample(thesis_setup1().downscaled(k)) for k in (1, 2)]
            [2, 1]
        """
        return default_downsample(rig)

    @staticmethod
    def default_coarse_factor(num_hypotheses: int, height: int, width: int) -> int:
        """:func:`prismstereo.defaults.default_coarse_factor`.

        Example:
            >>> PrismStereo.default_coarse_factor(368, 768, 512), PrismStereo.default_coarse_factor(40, 96, 64)
            (4, 1)
        """
        return default_coarse_factor(num_hypotheses, height, width)

    def _downsample(self, image: torch.Tensor) -> torch.Tensor:
        f = self.factor
        h, w = image.shape[-2:]
        padded = F.pad(image, (0, math.ceil(w / f) * f - w, 0, math.ceil(h / f) * f - h), mode="replicate")
        return F.avg_pool2d(padded, f)

    def forward(self, image: torch.Tensor) -> DepthResult:
        """Depth of the reference half of ``image`` (B, C, H, W) in [0, 1], C = 1 or 3.

        In torch eager a batch is evaluated image by image on worker threads, each with a share of the caller's
        intra-op threads and its grad / inference mode (:func:`~prismstereo.batching.per_image`, which also gives
        the measurements behind it); traced or exported it is one graph for the whole batch.
        """
        check_shape(image, ["B", "C", "H", "W"], "image")
        if image.shape[0] > 1 and not (torch.jit.is_tracing() or torch.onnx.is_in_onnx_export()):
            parts = per_image(self._forward, image)
            return DepthResult(*(torch.cat(ts, 0) for ts in zip(*parts, strict=True)))
        return self._forward(image)

    def _forward(self, image: torch.Tensor) -> DepthResult:
        k = self.downsample
        if k == 1:
            return self._depth(image)
        h, w = self.rig.image_height, self.rig.image_width
        if image.shape[-2:] != (h, w):
            raise ShapeError(f"image is {image.shape[-1]}x{image.shape[-2]} px but the rig's sensor is {w}x{h}")
        if self.binned is not None:
            return self._depth(image)
        res = self._depth(F.avg_pool2d(image, k))  # drops the last H mod k rows / W mod k columns, as binned()
        w_ref = self.rig.reference_width

        def up(t: torch.Tensor) -> torch.Tensor:  # nearest: each pixel gets its block's value; 0 beyond
            t = F.interpolate(t, scale_factor=k, mode="nearest")
            return F.pad(t, (0, w_ref - t.shape[-1], 0, h - t.shape[-2]))

        match = res.match * k + (k - 1) / 2  # binned -> full-sensor pixels (block centres)
        valid = up(res.valid.to(res.depth.dtype)) > 0.5
        return DepthResult(up(res.depth), valid, up(res.confidence), up(res.index), up(match))

    def confidence_inputs(self, image: torch.Tensor) -> ConfidenceInputs:
        """What the calibrated confidence sees: the features (:data:`~prismstereo.matching.confidence.FEATURES`)
        of every pixel of ``image`` (B, C, H, W) with the depth they describe, for fitting a confidence to a
        rig or a kind of scene (:func:`~prismstereo.matching.confidence.fit_confidence`,
        ``benchmarks/fit_confidence.py``). Needs ``validity='calibrated'``.

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(4), (400.0, 700.0), coarse_factor=2)
            >>> model.confidence_inputs(torch.rand(1, 1, 192, 256)).features.shape
            torch.Size([1, 6, 192, 128])
        """
        if self.calibration is None:
            raise OptionError("confidence_inputs needs validity='calibrated'")
        check_shape(image, ["B", "C", "H", "W"], "image")
        if self.downsample > 1 and self.binned is None:
            raise OptionError("confidence_inputs needs the full-resolution model (downsample 1 or a pyramid)")
        est = self._estimate(image)
        z_range = torch.tensor(self.z_range, dtype=est.s.dtype, device=est.s.device)
        s = est.s.clamp(-1.0, 1.0)
        sampled = est.ok & self.reference_valid
        if not self.smoothing:
            return ConfidenceInputs(est.features, sweep_to_depth(s, z_range), sampled)
        smoothed, _, features = self._smooth(s, est.confidence, est.sampled)
        return ConfidenceInputs(est.features, sweep_to_depth(s, z_range), sampled, features,
                                sweep_to_depth(smoothed, z_range))

    def _estimate(self, image: torch.Tensor) -> _Estimate:
        """The final level's s, validity, raw confidence (NCC) or calibrated confidence, match and features."""
        ref, other = self.split(image)
        h, w_ref = ref.shape[-2:]
        step = 2.0 / (self.num_hypotheses - 1)
        features = None
        if self.factor == 1:
            s, ok, confidence, match = self.search(ref, other, final=True)
            sampled = ok
        else:
            f = self.factor
            with torch.no_grad():  # the coarse level only places the fine band (its s0 is detached)
                if self.binned is None:
                    coarse = self.search(self._downsample(ref), self._downsample(other), final=False)
                    s_c, valid_c, radius = coarse.s, coarse.valid, self.coarse_reach
                    similar_c = coarse.confidence * valid_c.to(coarse.confidence.dtype)
                else:  # the binned model's final estimate, extended twice as far as its own coarse level reached
                    low = self.binned._depth(F.avg_pool2d(image, f))
                    s_c, valid_c = low.index * (2.0 / (self.binned.num_hypotheses - 1)) - 1.0, low.valid
                    radius = 2 * self.coarse_reach * self.binned.factor
                    similar_c = low.confidence  # its NCC, 0 where invalid (validity 'thresholds')
                s_c, reach = extend_estimate(s_c, valid_c, radius)

            def up(t: torch.Tensor, mode: str = "nearest") -> torch.Tensor:
                # level pixel i covers full pixels f i ... f i + f - 1; a binned level may end short of the
                # reference half (its width rounded down): replicate its last row / column
                corners = {} if mode == "nearest" else {"align_corners": False}
                t = F.interpolate(t.to(ref.dtype), scale_factor=f, mode=mode, **corners)
                if t.shape[-2] < h or t.shape[-1] < w_ref:
                    t = F.pad(t, (0, max(0, w_ref - t.shape[-1]), 0, max(0, h - t.shape[-2])), mode="replicate")
                return t[..., :h, :w_ref]

            s0 = up(s_c, "bilinear").detach().clamp(-1.0, 1.0)
            # the reference's texture (grey std over the cost window): the wide box's weight and a feature
            texture = None
            if self.validity == "calibrated" or self.wide_box > self.fine_box:
                texture = box_std(ref if ref.shape[1] == 1 else ref.mean(1, keepdim=True), self.window).detach()
            if self.validity == "calibrated" or self.dense:  # beyond the reach: the coarse level's own estimate
                ok0 = torch.ones_like(s0, dtype=torch.bool)
            else:
                ok0 = up(reach) > 0.5
            s, ok, confidence, match = self.fine(ref, other, s0, ok0, self.series, self.interval, texture)
            rejected = up(valid_c) < 0.5
            sampled = ok  # the band had a real sample (a dense model's depths), before the validity rules
            if self.validity == "calibrated":  # the probability of a depth within 1 % (matching.confidence)
                features = confidence_features(confidence, up(similar_c, "bilinear"), s.detach(), s0, texture, step,
                                               rejected)
                confidence = self.calibration(features)
            elif self.coarse_reach:  # pixels the coarse level only reached from a neighbour: a stricter match
                ok = ok & (~rejected | (confidence >= self.reach_confidence))
        return _Estimate(s, ok, confidence, match, features, sampled)

    def _smooth(self, s: torch.Tensor, confidence: torch.Tensor, sampled: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """The confidence-weighted robust mean of the estimates around each pixel (``smoothing``; the confidence
        a weight, not a path of gradients), and for calibrated models the confidence re-scored from the evidence
        around the pixel with those features (None otherwise: the confidence stays as it is)."""
        step = 2.0 / (self.num_hypotheses - 1)
        weight = confidence.detach().clamp(0.0, 1.0) * (sampled & self.reference_valid).to(s.dtype)
        smoothed = robust_mean(s, weight, self.smoothing, self.smoothing_tolerance * step)
        if self.smoothed_calibration is None:
            return smoothed.values, confidence, None
        features = smoothed_features(weight, smoothed.agreement, smoothed.support)
        return smoothed.values, self.smoothed_calibration(features), features

    def _depth(self, image: torch.Tensor) -> DepthResult:
        s, ok, confidence, match, _, sampled = self._estimate(image)
        step = 2.0 / (self.num_hypotheses - 1)
        s = s.clamp(-1.0, 1.0)
        if self.smoothing:  # its fine band returned no match (with_match=False): the series at the smoothed s
            s, confidence, _ = self._smooth(s, confidence, sampled)
        z_range = torch.tensor(self.z_range, dtype=s.dtype, device=s.device)
        depth = sweep_to_depth(s, z_range)
        if match is None:  # the series at s (the search's own match unless the estimate was smoothed)
            match = torch.cat(series_at(self.series, s), 1)
        valid = ok & self.reference_valid & (confidence >= self.min_confidence)
        covered = sampled & self.reference_valid  # dense: a depth wherever the band had a real sample
        if self.occlusion_tolerance is not None:
            occluders = None if self.occluder_confidence is None else valid & (confidence >= self.occluder_confidence)
            valid = valid & self.visible(match, depth, valid, occluders)
        if self.dense and self.dense_fill:  # the depths that are not valid: the mean of the valid ones around
            s = torch.where(covered, extend_estimate(s, valid, self.dense_fill).s, s)
            depth, match = sweep_to_depth(s, z_range), torch.cat(series_at(self.series, s), 1)
        # confidence in [0, 1] times the mask: 0 where invalid, or in a dense model where there is no depth
        # (onnxruntime runs a Where on one thread, ~0.26 ms on a 768 x 512 plane; the product ~0.05 ms)
        if self.dense:  # > 0 exactly where there is a depth (an NCC of 0 too)
            confidence = confidence.clamp_min(torch.finfo(confidence.dtype).tiny) * covered.to(confidence.dtype)
        else:
            confidence = confidence * valid.to(confidence.dtype)
        index = (s + 1.0) / step
        return DepthResult(depth, valid, confidence, index, match)

    def visible(
        self, match: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor, occluders: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Z-buffer occlusion test in the other half (:func:`~prismstereo.depth.occlusion.zbuffer_visible`
        with this model's split and ``occlusion_tolerance``): a valid pixel is visible when no occluder (a
        pixel of ``occluders``, default ``valid``) with a point nearer than ``depth (1 - occlusion_tolerance)``
        claims its match's other-half pixel. ``match`` (B, 2, H, W_ref); returns (B, 1, H, W_ref) bool.

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0))
            >>> m = torch.zeros(1, 2, 96, 64); z = torch.full((1, 1, 96, 64), 500.0)
            >>> bool(model.visible(m, z, torch.ones(1, 1, 96, 64, dtype=torch.bool)).all())
            True
        """
        return zbuffer_visible(match, depth, valid, self.split.split, self.split.width - self.split.split,
                               self.occlusion_tolerance or 0.0, occluders)
