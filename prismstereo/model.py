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
5. Depth from the sweep coordinate (exact: s is linear in 1/Z), validity (inside the common field of view,
   winner inside the band, confidence) and a z-buffer occlusion test in the other half.

With ``downsample`` k and ``full_band`` R the coarse level of step 3 is a whole model of the k x k-binned capture
(:attr:`PrismStereo.binned`, steps 1-5 on the binned rig), and step 4 a band of 2 R + 1 full-resolution
hypotheses around its estimate: a pyramid with full lateral resolution in about half the time of the
full-resolution coarse level. It is the default on sensors whose reference half is >= 384 px on its shorter
side (k = 2, R = 2: the thesis setups at 1024 x 768; :meth:`PrismStereo.default_downsample`); smaller sensors
get steps 3-4 at full resolution (``downsample=1``), as any sensor does when asked.

Why coarse-to-fine by default: over the thesis' working range the correspondence moves ~365 px across the
other half (``thesis_setup1``); a full-resolution search touches H x W_ref x 368 voxels per pass, the
coarse level (f = 4) 1/64 of that and the fine band 11 / 368. ``benchmarks/depth_targets.py`` measures
both modes.

Why the rectified coarse level by default (``benchmarks/depth_targets.py --sampling``, full resolution, both
thesis setups, 205-1511 mm, with ``coarse_reach=1``): the final depth comes from the same exact fine band either
way, and the rectified coarse level lands inside it more often: coverage 97.2-99.6 % against the sweep's
96.3-99.4 % (setup 1) and 96.4-98.6 % against 95.1-98.8 % (setup 2; 228 mm: 97.2 vs 95.1 %, the sweep's lowest,
near the 95 % target). The sweep is the more precise placement on setup 2 (whose row rectification leaves
0.1 px): mean errors 0.010-0.071 % against 0.012-0.087 % and fewer valid pixels that are not co-visible (0.0-2.6
% against 0.0-4.6 %); on setup 1 the two are within 0.007 points. onnxruntime runs the rectified frame faster
(1024 x 768, 228-1374 mm, four runs: 175-270 ms against 216-322 ms; the volume is a gather
of rows instead of a bilinear ``grid_sample`` of 2.3 M samples). It is not exact as a
*final* level: a shift compares windows of equal width, while the other half's image of a surface is
stretched or squeezed across the window (anamorphic virtual cameras), which the per-pixel sweep follows.
Measured as a single level at half resolution, setup 2, 1192 mm: 0.26 % mean error / 88.9 % coverage against
the sweep's 0.11 % / 95.3 %. So a single level (f = 1) uses the sweep by default.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.batching import per_image
from prismstereo.depth.occlusion import zbuffer_visible
from prismstereo.depth.range import default_z_range
from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients, sweep_to_depth
from prismstereo.epipolar.table import (
    series_at,
    sweep_hypotheses,
    sweep_series,
    tabulate_sweep,
    valid_interval,
)
from prismstereo.errors import OptionError, ShapeError, check_option, check_shape
from prismstereo.geometry.optics import trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.matching.build import build_search
from prismstereo.matching.cost import COSTS, Cost
from prismstereo.matching.levels import FineBand, SearchOptions, extend_estimate
from prismstereo.matching.split import SplitImage

__all__ = ["DepthResult", "PrismStereo", "Refinement", "Sampling", "sweep_hypotheses"]

Refinement = Literal["equiangular", "parabola", "soft_argmin"]
Sampling = Literal["sweep", "rectified"]
BandEdges = Literal["reject", "clamp"]
BAND_EDGES: tuple[str, ...] = ("reject", "clamp")
SAMPLINGS: tuple[str, ...] = ("sweep", "rectified")
REFINEMENTS: tuple[str, ...] = ("equiangular", "parabola", "soft_argmin")


class DepthResult(NamedTuple):
    """Depth of the reference half.

    Attributes:
        depth: (B, 1, H, W_ref) depth Z (mm); meaningless where not valid.
        valid: (B, 1, H, W_ref) bool.
        confidence: (B, 1, H, W_ref) in [0, 1] (0 where invalid).
        index: (B, 1, H, W_ref) fractional index into the model's ``depths`` (uniform in 1/Z).
        match: (B, 2, H, W_ref) (u, v) of each pixel's match in the other half, full-sensor pixels (the
            generalised disparity); like the depth, meaningful where valid.
    """

    depth: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    index: torch.Tensor
    match: torch.Tensor


class PrismStereo(nn.Module):
    """Depth from one bi-prism capture: exact plane sweep, coarse-to-fine.

    Args:
        rig: the rig.
        z_range_mm: (z_min, z_max) depth range searched; default
            :func:`~prismstereo.depth.range.default_z_range` (from the rig's common field of view).
        num_hypotheses: D at full resolution, uniform in 1/Z; default: neighbours <= 1 px apart.
        cost: cost of the coarse (or single) level: 'zncc' (default; invariant to gain and offset differences
            between the halves), 'census' or 'sad' (:mod:`prismstereo.matching.sweep_cost`). Measured at half
            resolution (512 x 384, f = 2, 205-1511 mm, 4 planes + slanted + step per setup): ZNCC with 4-direction
            SGM beat census with 8 directions on every capture of both setups in error and false matches
            (228 mm: setup 1 0.56 % -> 0.14 %, 10.7 % -> 7.8 % false; setup 2 11.9 % -> 2.9 % false) and
            coverage (setup 2 at 1192 mm 91.9 % -> 95.0 %), and ZNCC's five box filters cost far less than the
            24 shifted comparisons of a 5 x 5 census.
        fine_cost: cost of the fine band, default 'zncc' (sub-pixel accurate with the parabola fit).
        sampling: how the coarse (or single) level samples the other half: 'rectified' (a 1-D shift volume on
            row-rectified halves) or 'sweep' (the exact per-pixel plane sweep); None (default): 'rectified'
            for a coarse level, 'sweep' for a single full-resolution level (see the module docstring).
        window: census / ZNCC window (odd).
        census_threshold: census bits count neighbours darker than the centre by more than this. The default
            0.4 / 255 is no multiple of 1 / (255 f^2) (5 does not divide 2 f^2 for any f not a multiple of 5), so
            differences of 8-bit pixels and of their f x f coarse averages never sit exactly on it: equal
            neighbours count as "not darker" robustly and torch and onnxruntime agree bit for bit (0.5 / 255
            is such a multiple at f = 2 and 4 and made the coarse levels of the two runtimes differ).
        box: box aggregation window of the coarse (or single) level.
        fine_box: box window of the fine band.
        aggregation: 'sgm' (semi-global after the box) or 'box'.
        directions: SGM scan directions, 2, 4 (default: horizontal and vertical) or 8. Over 600-1450 mm 2 saved
            ~9 % of the default pyramid's onnxruntime time but covered down to 94.1 % on setup 2 (1374 mm; 4
            directions: 95.7 %; ``benchmarks/depth_targets.py --z-range 600 1450 --slanted 900 --step 700 1000
            --directions 2``, session 10).
        p1, p2: SGM penalties in units of the box-averaged cost (ZNCC: 1 - NCC in [0, 2]). The defaults 1 and 8
            are strong for ZNCC (measured better than 0.3 / 2.4 and 0.1 / 0.8 on the same captures): the coarse
            level only has to land within the fine band, which then re-estimates every pixel on its own.
        coarse_factor: f, the coarse level's downsampling (1 = one full-resolution level); default
            :meth:`default_coarse_factor`.
        band: R, the fine band is s0 + j step, j = -R..R; default f + 1, and ceil(3 f / 4) for the binned model
            of a pyramid (``full_band``), whose estimate only places the full-resolution band: f = 4 -> 3, f = 2 ->
            2. Measured with ``benchmarks/depth_targets.py --band 3`` against 5 (the default pyramid, binned
            coarse factor 4, 205-1511 mm): mean errors 0.015-0.088 % / 0.012-0.064 % (setups 1 / 2; with 5:
            0.015-0.088 / 0.012-0.065 %), coverage 97.2-99.5 % / 95.9-98.7 % (97.2-99.5 / 95.8-98.7 %), fewer
            valid pixels that are not co-visible (228 mm: 2.8 / 1.6 % against 3.2 / 2.3 %; setup 2 at 1374 mm 0.7
            against 1.2 %), the slanted plane 0.028 / 0.019 % on 98.8 / 95.8 % (0.029 / 0.020 % on 98.8 / 96.2 %);
            ~9 % less onnxruntime time (paired A/B). Over 600-1450 mm (binned coarse factor 2) R = 2 against 3:
            the same coverage to 0.3 points, errors equal or lower, fewer false matches; R = 1 lost up to 1.7 points
            (setup 2, step scene 93.9 %).
        refinement: sub-pixel refinement of the final level: None (default) picks the fit matching each
            level's cost (equiangular for L1-type census/SAD, parabola for ZNCC); 'equiangular',
            'parabola', or 'soft_argmin' (a local soft-argmin, differentiable w.r.t. the cost: gradients reach
            the image with 'sad' or 'zncc').
        min_confidence: pixels with lower confidence (the final level's NCC) are invalid.
        min_uniqueness: pixels whose coarse (or single) level winner is not unique enough, 1 - best / second
            best aggregated cost outside winner +- 1 below this, are invalid (false matches of pixels that the
            other half does not see have a runner-up close to the winner).
        occlusion_tolerance: relative depth margin of the z-buffer occlusion test, None to skip it.
        occluder_confidence: only valid pixels with at least this confidence occlude others in that test (None:
            every valid pixel). A false match (a pixel the other half does not see, matched to some texture)
            claims an other-half pixel and used to push the true match of that pixel out; measured at full
            resolution, ``thesis_setup2`` at 1374 mm, two noise realisations: coverage 94.4 / 95.4 % -> 95.6 /
            96.0 % with 0.8 (0.7: 95.2 / 95.8 %), at the price of a few more false matches kept elsewhere
            (setup 1 at 228 mm 7.6 -> 8.7 % of the valid pixels, step scene 1.6 -> 2.1 %).
        lr_threshold: left-right check of the rectified level (``sampling='rectified'``; the sweep has no
            cheap view from the other half): the other half's winners over the same aggregated shift volume
            must agree with the reference's to this many level pixels; None (default) skips it. Measured at full
            resolution with 1 (coarse px): on ``thesis_setup2`` it removes nearly all false matches of far
            planes (780 / 1374 mm: 1.6 / 1.1 % -> 0.03 / 0.1 % of the valid pixels), but on ``thesis_setup1`` it
            rejects true matches (228 mm: coverage 95.5 -> 83.7 %, 780 mm 98.7 -> 94.0 %; the same with 2 or 3
            px: the other half's winner is far off, not slightly): the other half's pixel picks the lowest
            aggregated cost among all reference pixels that could see it, and where many reference pixels have
            no true match (near the common field of view's edge) one of their spurious minima wins. So it is
            off by default; the z-buffer test (``occlusion_tolerance``) handles occlusions.
        downsample: k > 1 matches on the capture box-averaged over k x k pixel blocks (the rig seen through
            that binning, :meth:`~prismstereo.geometry.rig.BiPrismRig.binned`: exact geometry, pixels k times
            larger) and returns the depth on the full-resolution reference grid: re-estimated there by a
            full-resolution band with ``full_band`` > 0 (the pyramid), else each pixel with its block's values
            (nearest; ``match`` in full-sensor pixels), a speed knob of ~k^2 less work at k times coarser
            lateral and disparity resolution. ``num_hypotheses``, ``coarse_factor`` and ``band`` then refer to
            the binned image. None (default): :meth:`default_downsample`, with ``full_band`` 2 when that is > 1
            (the pyramid on 1024 x 768 sensors); 1 is the full-resolution coarse level of steps 3-4. Block
            values (k = 2, ``full_band=0``) measured at 1024 x 768: onnxruntime 0.38-0.44x OpenCV SGBM's time
            against 2.09-2.11x with ``downsample=1`` (setup 1, 228-1374 mm, two runs of
            ``benchmarks/onnx_speed.py`` in session 9, medians of same-round ratios), slanted plane 0.040 % mean
            error on 98.3 % of the co-visible pixels
            (``downsample=1``: 0.027 % on 98.8 %). On the thesis planes (``benchmarks/depth_targets.py
            --downsample 2 --full-band 0``, 205-1511 mm) the mean error stays <= 0.123 % (setup 1) / 0.132 %
            (setup 2), coverage 94.0-99.2 % / 93.4-97.0 % (``downsample=1``: 97.2-99.6 / 96.4-98.5 %; both with
            ``coarse_reach=1``, without it 90.2-98.6 / 92.6-95.9 %): below the 95 % target at the nearest plane
            (setup 1) and the far ones (setup 2, 780-1374 mm).
        coarse_reach: invalid coarse pixels within this many coarse pixels of valid ones take their valid
            neighbours' mean s (:func:`~prismstereo.matching.levels.extend_estimate`) before it is upsampled
            for the fine band; 0 leaves the coarse estimate as it is. The coarse level loses a margin of about
            its window at the edges of the common field of view (at 228 mm with ``thesis_setup1`` that field is
            a strip of 144 of the 512 reference columns), and the bilinear upsampling of s blended the values
            of its invalid pixels into the valid ones next to them, misplacing the band there (on a half-size
            setup 1 at 240 mm the coverage went 91.8 -> 95.2 % from that alone, 95.7 % with the reached pixels).
            Measured with 1 (``benchmarks/depth_targets.py``, ``downsample=1``, 205-1511 mm, against 0): coverage
            of the co-visible pixels 95.5-99.4 -> 97.2-99.6 % (setup 1) and 96.0-98.1 -> 96.4-98.5 % (setup 2),
            mean errors within 0.002 points on setup 1 (up to +0.002 at 525 / 936 mm and the step scene) and
            equal or lower on setup 2 (1374 mm 0.092 -> 0.087 %); the share of valid pixels that are not
            co-visible fell on every setup 1 capture but 1374 mm (equal; 228 mm 8.65 -> 8.46 %, 312 mm 0.78 ->
            0.47 %) and rose by 0.0-0.8 points on setup 2 (228 mm 3.85 -> 4.64 %, 1192 mm 1.79 -> 2.10 %). A
            radius of 2 covered more but let in more false matches (setup 2, 228 mm: 12.2 % false without the
            confidence rule).
        reach_confidence: the fine band's confidence (NCC) a pixel needs when only its coarse neighbours were
            valid (the others need ``min_confidence``); 0.8 instead of 0.9 gave the same coverage to 0.1 point
            with up to 0.5 points more false matches (setup 2, 228 mm 5.11 %).
        full_band: with ``downsample`` k > 1, R > 0 makes a pyramid: the model of the binned capture (every
            option above applies to it; :attr:`binned`) estimates s, which is extended by 2 ``coarse_reach``
            times its coarse factor binned pixels and upsampled bilinearly to place a band of 2 R + 1 hypotheses
            (<= 1 px apart) at full resolution around every pixel, evaluated like the fine band on the exact
            full-resolution sweep. Full lateral resolution at about the binned model's price plus a thin band;
            0 gives each pixel its block's values; None (default): 2 with the default ``downsample`` when that
            is > 1, else 0 (an explicit ``downsample`` keeps block values unless ``full_band`` is given).
            ``benchmarks/depth_targets.py`` (205-1511 mm) against ``downsample=1``: mean errors 0.015-0.088 % vs
            0.016-0.083 % (setup 1) and 0.012-0.064 % vs 0.012-0.087 % (setup 2), coverage 97.2-99.5 % vs
            97.2-99.6 % and 95.9-98.7 % vs 96.4-98.5 %, fewer valid pixels that are not co-visible (228 mm: 2.8 vs
            8.5 % / 1.6 vs 4.6 %), slanted plane 0.028 / 0.019 % (0.026 / 0.023 %), step 0.042 / 0.029 % (0.049 /
            0.033 %), at ~0.45x the time (``benchmarks/onnx_speed.py``, setup 1 at 1024 x 768, 228-1374 mm, two
            runs in session 9: onnxruntime 0.93-0.95x OpenCV SGBM's time against 2.09-2.11x, torch 1.11-1.24x
            against 2.44-2.56x). The extension radius (binned pixels; setup 2 at 1374 / 936 mm, setup 1 at
            228 mm): 4 gave 93.5 / 94.8 / 96.2 % coverage, 8 (the default's) 95.8 / 96.6 / 97.2 %, 12 and 16 no
            more (96.0 / 96.6 / 97.0 and 95.9 / 96.4 / 96.6 %): the binned level loses a margin of about its
            windows near the edges of the other half, which its own coarse reach does not bridge (a coarse reach
            of 2 inside the binned model instead gave 95.2 / 96.3 / 96.8 %).
            With a radius of 2: R = 3 covered 0.1-1.2 points more on setup 2 with more false matches and ~15 %
            more time; R = 1 was ~7 % faster in onnxruntime and covered 1.2 points less on the slanted plane.
        band_edges: what a fine band (the pyramid's full-resolution band, and the fine band of every coarse-to-fine
            level) does with a pixel whose best hypothesis is on the band's edge, i.e. whose match lies beyond
            the band: 'reject' (default) makes it invalid; 'clamp' takes the edge's inner neighbour as the winner
            and refines there, so s moves at most half a step beyond it, with that hypothesis' confidence (still
            subject to ``min_confidence`` / ``reach_confidence``). With ``full_band=1`` (a band of 3) it is the
            fast full-resolution setting: ``benchmarks/depth_targets.py --downsample 2 --full-band 1
            --band-edges clamp`` (205-1511 mm) gave mean errors 0.014-0.096 % (setup 1) and 0.012-0.079 %
            (setup 2), coverage 96.9-99.6 % and 96.3-98.7 %, slanted plane 0.030 / 0.025 %, step 0.046 /
            0.034 % (the default pyramid: 0.015-0.088 %, 0.012-0.065 %, 97.2-99.5 %, 95.8-98.7 %, 0.029 / 0.020 %,
            0.043 / 0.029 %), false matches at setup 2's 1374 mm 2.0 % of the valid pixels (1.2 %), in 0.86-0.92x the
            default's onnxruntime time (session 8). Session 9, with the binned band +-3: 0.014-0.096 % / 0.012-0.081
            %, 96.9-99.6 % / 96.3-98.7 %, slanted 0.030 / 0.027 %, step 0.046 / 0.035 %, false 1.6 % at setup 2's
            1374 mm; onnxruntime 0.64-0.75x OpenCV SGBM's time (``benchmarks/onnx_speed.py``, setup 1, 228-1374 mm,
            two runs; the default pyramid 0.93-0.95x); without 'clamp' R = 1 covered 91.3-96.9 % on setup 2. With
            R = 2, 'clamp' covered 0.1-1.2 points more on setup 2 (worst 96.3 %) at up to +0.008 points of mean
            error and ~1.8x the false matches at 1374 mm. Session 10, over 600-1450 mm (``--z-range 600 1450
            --slanted 900 --step 700 1000``): the fast setting 0.95-0.97x OpenCV SGBM's time (96 disparities;
            the default pyramid 1.14-1.24x), errors 0.039-0.100 % / 0.041-0.098 % (default 0.038-0.091 % /
            0.031-0.072 %), coverage 98.3-99.5 % / 96.3-98.2 % (98.2-99.4 % / 95.6-97.3 %), but on setup 2 up to
            3.9 % false matches (default 2.2 %) and 0.67 % of pixels off by > 2 % (0.20 %).

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> model = PrismStereo(small, (400.0, 700.0))
        >>> model(torch.rand(1, 1, 96, 128)).depth.shape
        torch.Size([1, 1, 96, 64])
    """

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
    ) -> None:
        super().__init__()
        level_options = dict(  # everything but the resolution: the binned model of a pyramid gets the same
            cost=cost, fine_cost=fine_cost, sampling=sampling, window=window, census_threshold=census_threshold,
            box=box, fine_box=fine_box, aggregation=aggregation, directions=directions, p1=p1, p2=p2,
            coarse_factor=coarse_factor, band=band, refinement=refinement, min_confidence=min_confidence,
            min_uniqueness=min_uniqueness, occlusion_tolerance=occlusion_tolerance,
            occluder_confidence=occluder_confidence, lr_threshold=lr_threshold, coarse_reach=coarse_reach,
            reach_confidence=reach_confidence, band_edges=band_edges)
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
            self.binned = PrismStereo(rig.binned(downsample), z_range_mm, num_hypotheses, downsample=1, full_band=0,
                                      **level_options)
            if band is None and self.binned.factor > 1:  # its band only places the final one: see ``band``
                self.binned._set_band(math.ceil(3 * self.binned.factor / 4))
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
                                min_uniqueness=min_uniqueness)
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
            fine_options = dataclasses.replace(options, cost=fine_cost, box=fine_box, band_edges=band_edges)
            self.fine = FineBand(fine_options, self.band, 2.0 / (num_hypotheses - 1), self.split.split)

    def _set_band(self, band: int) -> None:
        """Rebuild the fine band after the coarse level with half width ``band``."""
        self.band = band
        self.fine = FineBand(self.fine.options, band, self.fine.step, self.fine.split)

    def config(self) -> dict[str, object]:
        """The constructor's options as resolved (defaults filled in), JSON-ready; with the rig
        (:meth:`BiPrismRig.to_dict`) they rebuild the same model: ``PrismStereo(rig, **model.config())``.

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0))
            >>> PrismStereo(model.rig, **model.config()).num_hypotheses == model.num_hypotheses
            True
        """
        if self.binned is not None:  # the options went to the binned model
            return {**self.binned.config(), "downsample": self.downsample, "full_band": self.band}
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
        """k = 2 (the pyramid, with ``full_band`` 2) when the reference half is at least 384 px on its shorter side,
        else 1 (coarse-to-fine at full resolution). At 1024 x 768 (the thesis setups, 205-1511 mm) the pyramid
        met the same depth targets as the full-resolution coarse level with lower errors on setup 2 (0.012-0.065
        against 0.012-0.087 %), fewer false matches (228 mm: 3.2 / 2.3 % against 8.5 / 4.6 %), coverage within
        -0.6 / +0.2 points on the planes and 0.2-1.1 points lower on the slanted and step scenes, in ~0.55x the
        time (see ``full_band``); on smaller sensors the binned image is too small for its own f = 4 coarse
        level.

        Example:
            >>> [PrismStereo.default_downsample(thesis_setup1().downscaled(k)) for k in (1, 2)]
            [2, 1]
        """
        return 2 if min(rig.image_height, rig.reference_width) >= 384 else 1

    @staticmethod
    def default_coarse_factor(num_hypotheses: int, height: int, width: int) -> int:
        """f = the largest power of two (<= 4) leaving >= 24 hypotheses and >= 32 rows and columns at the
        coarse level; 1 (a single full-resolution level) for small searches. (f = 8 on a 1024 x 768 sensor
        loses the pixels within ~40 px of the other half's edge: the coarse windows span 72 px.) A narrow range
        at full resolution (600-1450 mm, 103 hypotheses) gets f = 4: onnxruntime 267 ms per frame at 0.048 %
        mean error, against 506 ms (0.053 %) with f = 2 and ~9x the time with a single level
        (``benchmarks/onnx_speed.py``, measured before the onnxruntime tuning that brought f = 4 to 156-220 ms).
        The pyramid's binned model of that range (52 / 94 hypotheses with setup 1 / 2) gets f = 2; f = 4 there
        (``coarse_factor=4``, session 10) took 0.84x the onnxruntime time (1.00x OpenCV SGBM's) with errors as low
        or lower, but covered 93.7 % of setup 2's step scene (700 / 1000 mm; f = 2: 95.6 %): the 1/8-resolution
        windows straddle the step (neither ``coarse_reach=2`` nor a binned band of +-4 recovered it: 93.6 / 93.5
        %).

        Example:
            >>> PrismStereo.default_coarse_factor(368, 768, 512), PrismStereo.default_coarse_factor(103, 768, 512)
            (4, 4)
            >>> PrismStereo.default_coarse_factor(40, 96, 64)
            1
        """
        f = 1
        while f < 4 and num_hypotheses / (2 * f) >= 24 and min(height, width) / (2 * f) >= 32:
            f *= 2
        return f

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

    def _depth(self, image: torch.Tensor) -> DepthResult:
        ref, other = self.split(image)
        h, w_ref = ref.shape[-2:]
        step = 2.0 / (self.num_hypotheses - 1)
        if self.factor == 1:
            s, ok, confidence, match = self.search(ref, other, final=True)
        else:
            f = self.factor
            with torch.no_grad():  # the coarse level only places the fine band (its s0 is detached)
                if self.binned is None:
                    coarse = self.search(self._downsample(ref), self._downsample(other), final=False)
                    s_c, valid_c, radius = coarse.s, coarse.valid, self.coarse_reach
                else:  # the binned model's final estimate, extended twice as far as its own coarse level reached
                    low = self.binned._depth(F.avg_pool2d(image, f))
                    s_c, valid_c = low.index * (2.0 / (self.binned.num_hypotheses - 1)) - 1.0, low.valid
                    radius = 2 * self.coarse_reach * self.binned.factor
                s_c, reach = extend_estimate(s_c, valid_c, radius)

            def up(t: torch.Tensor, mode: str = "nearest") -> torch.Tensor:
                # level pixel i covers full pixels f i ... f i + f - 1; a binned level may end short of the
                # reference half (its width rounded down): replicate its last row / column
                corners = {} if mode == "nearest" else {"align_corners": False}
                t = F.interpolate(t.to(ref.dtype), scale_factor=f, mode=mode, **corners)
                if t.shape[-2] < h or t.shape[-1] < w_ref:
                    t = F.pad(t, (0, max(0, w_ref - t.shape[-1]), 0, max(0, h - t.shape[-2])), mode="replicate")
                return t[..., :h, :w_ref]

            s0 = up(s_c, "bilinear")
            s, ok, confidence, match = self.fine(ref, other, s0.detach().clamp(-1.0, 1.0), up(reach) > 0.5,
                                                 self.series, self.interval)
            if self.coarse_reach:  # pixels the coarse level only reached from a neighbour: a stricter match
                ok = ok & ((up(valid_c) > 0.5) | (confidence >= self.reach_confidence))
        s = s.clamp(-1.0, 1.0)
        z_range = torch.tensor(self.z_range, dtype=s.dtype, device=s.device)
        depth = sweep_to_depth(s, z_range)
        if match is None:  # the fine band interpolates its samples; otherwise the series at s
            match = torch.cat(series_at(self.series, s), 1)
        valid = ok & self.reference_valid & (confidence >= self.min_confidence)
        if self.occlusion_tolerance is not None:
            occluders = None if self.occluder_confidence is None else valid & (confidence >= self.occluder_confidence)
            valid = valid & self.visible(match, depth, valid, occluders)
        confidence = torch.where(valid, confidence, confidence.new_tensor(0.0))  # a scalar fill (see _fill)
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
