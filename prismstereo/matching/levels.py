"""The search levels of :class:`~prismstereo.model.PrismStereo`, as swappable modules.

A *search* covers the whole depth range at one pyramid level and returns each pixel's sweep coordinate s
(linear in 1/Z, -1 at z_min, +1 at z_max), validity and confidence; two implementations share that interface,
like RAFT-Stereo's correlation blocks:

* :class:`SweepSearch`: every hypothesis warps the other half onto the reference pixels with the exact
  per-pixel sweep (one ``grid_sample`` of D x H x W samples), cost, aggregation, winner.
* :class:`RectifiedSearch`: both halves row-rectified by vertical warps fitted to the exact sweep
  (:mod:`prismstereo.epipolar.row_rectify`); every hypothesis is a column shift (one gather builds the volume,
  :func:`~prismstereo.matching.sweep_cost.shift_cost`); the winning shift becomes s exactly
  (:func:`~prismstereo.epipolar.sweep_table.column_to_sweep`), resampled onto the unrectified pixels.

:class:`FineBand` then re-estimates every full-resolution pixel in a band of hypotheses around an estimate,
on the exact sweep (:mod:`prismstereo.epipolar.series`). :mod:`prismstereo.matching.build` builds a rig's
search.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo._graph import fill_invalid, tracing
from prismstereo.epipolar.row_rectify import RectifiedLevel
from prismstereo.epipolar.series import series_at, series_band
from prismstereo.epipolar.sweep_table import column_to_sweep
from prismstereo.errors import OptionError, ShapeError, check_number, check_shape
from prismstereo.matching.aggregate import (
    GUIDED_EPS,
    GUIDED_RADIUS,
    GUIDED_SUBSAMPLE,
    box_filter,
    box_std,
    guided_filter,
    sgm_aggregate,
)
from prismstereo.matching.cost import Warped, grey, sweep_cost, worst_cost
from prismstereo.matching.select import (
    left_right_check,
    soft_argmin_local,
    subpixel_refine,
    uniqueness,
    winner_take_all,
)
from prismstereo.matching.sweep_cost import sample_points, sample_slices, shift_cost
from prismstereo.matching.sweep_sampler import SweepSampler

__all__ = ["Extended", "FineBand", "LevelResult", "RectifiedSearch", "SearchOptions", "SweepSearch", "extend_estimate"]

# soft-argmin temperature per cost's units
_TEMPERATURE = {"census": 1.0, "sad": 0.02, "zncc": 0.05, "ad_gradient": 0.05}
# the cost of an entry of the rectified shift volume that is not a real sample, as a share of the worst cost (ZNCC:
# 1.5, between uncorrelated and anti-correlated): the worst cost made the shifts whose windows reach past the other
# half's edge lose to shorter ones there, a margin of about the aggregated window (the binned coarse level of the
# narrow-range pyramid with factor 4: coverage of setup 2's step scene 93.7 -> 95.1 %); measurements in
# docs/design.md (*How the model picks its defaults*, ``coarse_factor``)
_SHIFT_FILL = 0.75
_STRIP_VOXELS = 400_000  # fine band voxels per strip in torch eager (~1.6 MB per float32 volume: cache-sized)
_EXPORT_STRIP_VOXELS = 2_000_000  # per strip of an exported graph (the pyramid's bands: one piece; see FineBand)


@dataclasses.dataclass(frozen=True, kw_only=True)
class SearchOptions:
    """Matching options of a level (see :class:`~prismstereo.model.PrismStereo` for their meaning and
    defaults; validated there)."""

    cost: str = "zncc"
    window: int = 5
    census_threshold: float = 0.4 / 255
    box: int = 5
    aggregation: str = "sgm"
    directions: int = 4
    p1: float = 1.0
    p2: float = 8.0
    refinement: str | None = None
    min_uniqueness: float = 0.3
    band_edges: str = "reject"
    wide_box: int = 0
    weak_texture: float = 8.0 / 255


class LevelResult(NamedTuple):
    """A level's estimate, (B, 1, H, W) each at the level's (unrectified) resolution.

    Attributes:
        s: sweep coordinate in [-1, 1] (may leave it slightly before clamping).
        valid: bool.
        confidence: in [0, 1].
        match: (B, 2, H, W) full-sensor (u, v) of the match at s, when the level has it (:class:`FineBand`),
            else None.
    """

    s: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    match: torch.Tensor | None = None


def similarity(best: torch.Tensor, cost: str, channels: int, window: int) -> torch.Tensor:
    """Confidence in [0, 1] from the winner's (box-averaged) cost: the NCC for 'zncc', 1 - cost / worst
    otherwise.

    Example:
        >>> similarity(torch.tensor([0.2]), "zncc", 1, 5)
        tensor([0.8000])
    """
    worst = worst_cost(cost, channels, window)
    return (1.0 - best / (1.0 if cost == "zncc" else worst)).clamp(0.0, 1.0)


def _refine(options: SearchOptions, local: torch.Tensor, total: torch.Tensor, index: torch.Tensor | int, cost: str,
            final: bool, limit: float = 0.5) -> torch.Tensor:
    method = options.refinement if final and options.refinement is not None else None
    if method == "soft_argmin":
        if isinstance(index, int):  # one winner for all pixels
            index = torch.full_like(total[:, :1], index, dtype=torch.long)
        return soft_argmin_local(total, index, radius=2, temperature=_TEMPERATURE[cost])
    return subpixel_refine(local, index, method or ("parabola" if cost == "zncc" else "equiangular"), limit)


class _Search(nn.Module):
    """Cost volume -> box (+ SGM) -> winner, sub-pixel index, confidence, uniqueness: shared by the searches."""

    def __init__(self, options: SearchOptions) -> None:
        super().__init__()
        self.options = options

    def decide(self, volume: torch.Tensor, channels: int, final: bool, guide: torch.Tensor | None = None):
        """(index (B, 1, H, W) long, refined index, confidence, unique, aggregated volume).

        ``guide`` (B, 1, H, W), the level's grey reference in the volume's layout, steers the 'guided'
        aggregation (:func:`~prismstereo.matching.aggregate.guided_filter`); its confidence is the similarity of
        the filtered cost (a window's evidence spread over its region of similar grey), the others' that of the
        box-averaged cost."""
        o = self.options
        guided = o.aggregation == "guided"
        local = box_filter(volume, o.box)
        if o.aggregation == "sgm":
            total = sgm_aggregate(local, o.p1, o.p2, o.directions)
        elif guided:
            total = guided_filter(local, guide, GUIDED_RADIUS, GUIDED_EPS, GUIDED_SUBSAMPLE)
        else:
            total = local
        index, _ = winner_take_all(total.detach())
        scored = total if guided else local  # the cost the sub-pixel fit and the confidence read
        refined = _refine(o, scored, total, index, o.cost, final)
        confidence = similarity(scored.gather(1, index), o.cost, channels, o.window)
        if guided and not final:  # a placement: the band after it judges it (the filtered cost is flat in weak
            unique = torch.ones_like(index, dtype=torch.bool)  # texture, where the ratio test rejects right winners)
        else:
            unique = uniqueness(total.detach(), index, 1.0, nonnegative=True)[1] >= o.min_uniqueness  # costs >= 0
        return index, refined, confidence, unique, total


class SweepSearch(_Search):
    """The whole range at one level by the exact plane sweep: the other half sampled on every pixel's sweep
    (:class:`~prismstereo.matching.sweep_sampler.SweepSampler`, the sampling :class:`~prismstereo.nn.PrismCostVolume`
    uses too), cost, aggregation, winner.

    Args:
        options: matching options.
        sampler: the level's sampler (:func:`~prismstereo.matching.sweep_sampler.sweep_sampler`).

    Example:
        >>> from prismstereo.matching.sweep_sampler import SweepSampler
        >>> sampler = SweepSampler(torch.zeros(3, 8, 6, 2), 4, other_valid=torch.ones(8, 6, dtype=torch.bool))
        >>> SweepSearch(SearchOptions(), sampler)(torch.rand(1, 1, 8, 6), torch.rand(1, 1, 8, 6), final=True).s.shape
        torch.Size([1, 1, 8, 6])
    """

    def __init__(self, options: SearchOptions, sampler: SweepSampler) -> None:
        super().__init__(options)
        self.sampler = sampler
        self.num_hypotheses = sampler.num_hypotheses

    def forward(self, reference: torch.Tensor, other: torch.Tensor, final: bool) -> LevelResult:
        """Search the level images ``reference`` (B, C, H, W) and ``other`` (B, C, H_o, W_o)."""
        warped = self.sampler(other)
        o = self.options
        volume = sweep_cost(reference, warped, o.cost, o.window, o.census_threshold)
        index, refined, confidence, unique, _ = self.decide(volume, reference.shape[1], final, grey(reference))
        ok = warped.valid.gather(1, index) & unique
        return LevelResult(-1.0 + refined * (2.0 / (self.num_hypotheses - 1)), ok, confidence)


class RectifiedSearch(_Search):
    """The whole range at one level as a 1-D shift volume on the row-rectified halves.

    Both level images are rectified by one ``grid_sample`` each; shift k compares rectified column u with
    column u + k of the other; the volume stays transposed, (B, D, W, H), until the winner (see
    :func:`~prismstereo.matching.sweep_cost.shift_cost`) unless the aggregation is not symmetric in H and W
    (2-direction SGM scans rows only). The shift becomes the sweep coordinate exactly on each rectified
    pixel's own sweep and is resampled onto the unrectified level pixels (bilinear; validity nearest).

    Args:
        options: matching options.
        level: :func:`~prismstereo.epipolar.row_rectify.rectified_level` of this level.
        factor: the level's downsampling f.
        split: the other half's first full-sensor column.
        lr_threshold: optional left-right check (level px; see :class:`~prismstereo.model.PrismStereo`).

    Example:
        >>> from prismstereo.epipolar.row_rectify import fit_row_rectification, rectified_level
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 900.0))
        >>> level = rectified_level(fit_row_rectification(rig, fit), fit, 2, torch.ones(96, 64, dtype=torch.bool))
        >>> search = RectifiedSearch(SearchOptions(), level, 2, rig.reference_width)
        >>> search(torch.rand(1, 1, 48, 32), torch.rand(1, 1, 48, 32), final=False).s.shape
        torch.Size([1, 1, 48, 32])
    """

    def __init__(self, options: SearchOptions, level: RectifiedLevel, factor: int, split: int,
                 lr_threshold: float | None = None) -> None:
        super().__init__(options)
        self.factor, self.split, self.lr_threshold = factor, split, lr_threshold
        self.transposed = not (options.aggregation == "sgm" and options.directions == 2)
        for name in ("reference_grid", "other_grid", "shifts", "back_grid", "table"):
            self.register_buffer(name, getattr(level, name).float())
        self.register_buffer("index", level.index)
        valid = level.valid.transpose(-1, -2).contiguous() if self.transposed else level.valid
        self.register_buffer("valid", valid)
        if lr_threshold is not None:  # the other half's view of the volume: its entry (k, x) is (k, x - k)
            valid_t = level.valid.transpose(-1, -2)  # (D, W_l, H_r)
            d, w_l, _ = valid_t.shape
            ref_col = torch.arange(level.other_grid.shape[1]).view(1, -1) - level.shifts.long().view(-1, 1)
            inside = (ref_col >= 0) & (ref_col < w_l)
            ref_col = ref_col.clamp(0, w_l - 1)
            self.register_buffer("right_index", (torch.arange(d).view(-1, 1) * w_l + ref_col).reshape(-1))
            right_valid = valid_t.gather(1, ref_col.unsqueeze(-1).expand(-1, -1, valid_t.shape[2]))
            self.register_buffer("right_valid", right_valid & inside.unsqueeze(-1))  # (D, W_ol, H_r)

    @property
    def num_hypotheses(self) -> int:
        """The number of shifts."""
        return int(self.shifts.numel())

    def forward(self, reference: torch.Tensor, other: torch.Tensor, final: bool) -> LevelResult:
        """Search the level images ``reference`` (B, C, H, W) and ``other`` (B, C, H_o, W_o)."""
        b, o, t = reference.shape[0], self.options, self.transposed
        ref_r = sample_slices(reference, self.reference_grid.to(reference)[None, None], shared=True)[:, :, 0]
        oth_r = sample_slices(other, self.other_grid.to(other)[None, None], shared=True)[:, :, 0]
        # 'ad_gradient' saturates at its worst on mismatches (truncated): a fill below it would win there
        fill = (1.0 if o.cost == "ad_gradient" else _SHIFT_FILL) * worst_cost(o.cost, reference.shape[1], o.window)
        volume = shift_cost(ref_r, oth_r, self.index, self.valid.unsqueeze(0), o.cost, o.window,
                            o.census_threshold, transposed=t, fill=fill)
        guide = grey(ref_r).transpose(-1, -2) if t else grey(ref_r)
        index, refined, confidence, unique, total = self.decide(volume, reference.shape[1], final, guide)
        ok = self.valid.unsqueeze(0).expand(b, -1, -1, -1).gather(1, index) & unique
        if t:
            refined, ok, confidence = refined.transpose(-1, -2), ok.transpose(-1, -2), confidence.transpose(-1, -2)
        first = self.shifts[0].to(reference)
        if self.lr_threshold is not None:  # the other half's winners over the same aggregated volume
            vol = (total if t else total.transpose(-1, -2)).detach()  # (B, D, W_l, H_r)
            d, w_l, h_r = vol.shape[1:]
            right = vol.reshape(b, d * w_l, h_r).index_select(1, self.right_index).view(b, d, -1, h_r)
            # no winner at invalid entries: the largest finite value, so that the fill is bounded (total >= 0): a
            # Max in an exported graph instead of a Where, which onnxruntime runs on one thread (0.8 ms in a profile
            # of the narrow-range frame, 600-1450 mm; the frame time did not change measurably); winners unchanged
            right = fill_invalid(right, self.right_valid, torch.finfo(right.dtype).max, bounded=True)
            k_right = winner_take_all(right)[0].transpose(-1, -2).to(reference.dtype)  # (B, 1, H_r, W_ol)
            # disparity in left_right_check's convention (other column = reference column - d): d = -shift
            ok = ok & left_right_check(-(first + refined.detach()), -(first + k_right), self.lr_threshold)
        w_l, f = reference.shape[-1], self.factor
        u = (torch.arange(w_l, device=reference.device).to(reference.dtype) + 0.5) * f - 0.5
        column = u + self.split + (first + refined) * f  # full-sensor column of the match
        s = column_to_sweep(self.table.to(reference), column)
        grid = self.back_grid.to(reference).unsqueeze(0).expand(b, -1, -1, -1)
        s = F.grid_sample(s, grid, mode="bilinear", padding_mode="border", align_corners=False)
        confidence = F.grid_sample(confidence, grid, mode="bilinear", padding_mode="border", align_corners=False)
        ok = F.grid_sample(ok.to(reference.dtype), grid, mode="nearest", padding_mode="zeros", align_corners=False)
        return LevelResult(s, ok > 0.5, confidence)


class FineBand(nn.Module):
    """Full-resolution band of 2 R + 1 hypotheses (``step`` apart in s) around each pixel's estimate s0, on the
    exact sweep: cost, box, winner, sub-pixel refinement (no SGM: the coarse level already regularised).

    Where the reference window has little texture (grey standard deviation sigma over the cost window below
    ``options.weak_texture``) the box-averaged cost is blended with the cost averaged over ``options.wide_box``
    (when larger than the box): C = C_box + w (C_wide - C_box), w = max(0, 1 - sigma / weak_texture). A small
    window's minimum in weak texture or under defocus is mostly noise; a wider one keeps the sub-pixel fit
    stable there, and richly textured windows keep their small, sharp support.

    The band is centred on each pixel's own estimate, not rounded to the hypothesis grid: rounding made the
    parabola fits pixel-lock (quarter-res plane at 600 mm: 0.19 % -> 0.49 % mean error). A pixel whose best
    hypothesis is on the band's edge (its match lies beyond the band) is invalid with ``options.band_edges``
    'reject'; with 'clamp' its winner becomes the inner neighbour of that edge hypothesis, refined there (at
    most ``vertex_limit`` steps further out) and judged by that hypothesis' confidence (with R = 1 that is always the
    centre: taken by static slices, without a winner search or gathers). The band runs over horizontal
    strips whose cost and box filters see ``window // 2 + max(fine_box, wide_box) // 2`` rows beyond the strip,
    so the strips give the whole image's numbers (bitwise). Torch eager takes cache-sized strips (~400 k voxels);
    an exported graph takes bands of up to 2 M voxels in one piece and larger ones in strips unrolled into the
    graph (the batch axis stays dynamic); the timings behind both sizes: ``docs/design.md``, *Implementation
    measurements*.

    Args:
        options: matching options of the band (cost, window, census threshold, box = the band's box window,
            refinement).
        band: R.
        step: hypothesis spacing in s.
        split: the other half's first full-sensor column.
        with_match: return each pixel's match (False: ``match`` None, for a caller that moves s afterwards).
        vertex_limit: the sub-pixel fit's largest move from the winner, in steps (0.5: within half a step of a
            true minimum; 1.0: up to the band's outer sample, for a band placed on a prior that may lag the
            motion by a step, :class:`~prismstereo.depth.temporal.TemporalDepth`).

    Example:
        >>> from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients
        >>> from prismstereo.epipolar.series import sweep_series
        >>> from prismstereo.epipolar.sweep_table import tabulate_sweep, valid_interval
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 900.0))
        >>> uv = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(96.0), indexing="xy"), -1).double()
        >>> coefficients = sweep_coefficients(fit, uv).permute(2, 0, 1, 3)
        >>> series = sweep_series(coefficients).float()
        >>> interval = valid_interval(tabulate_sweep(coefficients).float(), torch.ones(96, 64, dtype=torch.bool), 64)
        >>> fine = FineBand(SearchOptions(box=7), 2, 0.05, 64)
        >>> res = fine(torch.rand(1, 1, 96, 64), torch.rand(1, 1, 96, 64), torch.zeros(1, 1, 96, 64),
        ...            torch.ones(1, 1, 96, 64, dtype=torch.bool), series, interval)
        >>> res.s.shape
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, options: SearchOptions, band: int, step: float, split: int, with_match: bool = True, *,
                 vertex_limit: float = 0.5) -> None:
        super().__init__()
        check_number(vertex_limit, "vertex_limit", 0.0, 1.0, open_low=True)
        self.options, self.band, self.step, self.split = options, band, step, split
        self.with_match, self.vertex_limit = with_match, float(vertex_limit)

    def forward(self, reference: torch.Tensor, other: torch.Tensor, s0: torch.Tensor, ok0: torch.Tensor,
                series: torch.Tensor, interval: torch.Tensor, texture: torch.Tensor | None = None) -> LevelResult:
        """The band around ``s0`` (B, 1, H, W) (detached, in [-1, 1]) with the estimate's validity ``ok0``;
        ``series`` (2, D + 1, H, W) the exact sweep (:func:`~prismstereo.epipolar.series.sweep_series`),
        ``interval`` (2, H, W) each pixel's valid s (:func:`~prismstereo.epipolar.sweep_table.valid_interval`);
        ``texture`` optionally (B, 1, H, W) the reference's grey :func:`~prismstereo.matching.aggregate.box_std`
        over the cost window (the wide box's weight; computed here when None)."""
        exporting = tracing()
        h = reference.shape[-2]
        halo = self.options.window // 2 + max(self.options.box, self.options.wide_box) // 2
        # per image when exporting: the graph's batch axis is dynamic, and a traced batch size in this
        # arithmetic made the strips' slices depend on it (a batch of 4 failed in onnxruntime)
        voxels = (2 * self.band + 1) * int(reference.shape[-1]) * (1 if exporting else int(reference.shape[0]))
        rows = max(16, (_EXPORT_STRIP_VOXELS if exporting else _STRIP_VOXELS) // voxels)
        if rows >= h:  # one piece: no slices (in an exported graph each Slice, and a Concat of one, is a copy)
            return self._rows(reference, other, s0, ok0, series, 0, interval, texture)
        strips = []
        for top in range(0, h, rows):
            lo, hi = max(0, top - halo), min(h, top + rows + halo)
            res = self._rows(reference[..., lo:hi, :], other, s0[..., lo:hi, :], ok0[..., lo:hi, :],
                             series, lo, interval[:, lo:hi], None if texture is None else texture[..., lo:hi, :])
            keep = slice(top - lo, top - lo + min(rows, h - top))
            strips.append([None if t is None else t[..., keep, :] for t in res])
        return LevelResult(*(None if ts[0] is None else torch.cat(ts, -2) for ts in zip(*strips, strict=True)))

    def _rows(self, reference: torch.Tensor, other: torch.Tensor, s0: torch.Tensor, ok0: torch.Tensor,
              series: torch.Tensor, top: int, interval: torch.Tensor,
              texture: torch.Tensor | None = None) -> LevelResult:
        """The band on rows ``top`` ... of the image (``series`` whole, ``interval`` of these rows)."""
        o, step = self.options, self.step
        offsets = torch.arange(-self.band, self.band + 1, device=reference.device).to(reference.dtype) * step
        # the band's positions s0 + t_j from each pixel's Taylor coefficients at s0 (exported as one MatMul: in
        # onnxruntime cheaper than Horner's rule over the (B, J, H, W) coordinates), in other-half pixels
        x, y = series_band(series, s0, offsets, top, origin=(self.split, 0.0))
        channels = reference.shape[1]
        if o.cost == "zncc":  # ZNCC compares grey windows: sample the grey image (linear)
            reference, other = grey(reference), grey(other)
        lo, hi = interval.to(reference).unbind(0)
        t = offsets.view(1, -1, 1, 1)  # s0 + t_j within the pixel's interval (beyond [-1, 1]: outside it)
        warped = Warped(sample_points(other, x, y), (t >= lo - s0) & (t <= hi - s0))
        volume = sweep_cost(reference, warped, o.cost, o.window, o.census_threshold)
        local = box_filter(volume, o.box)
        if o.wide_box > o.box:  # weak texture: the cost averaged over a wider box (see FineBand)
            if texture is None:
                texture = box_std(grey(reference), o.window)
            weight = (1.0 - texture.detach() / o.weak_texture).clamp(0.0, 1.0)  # a weight, not a path of gradients
            local = local + weight * (box_filter(volume, o.wide_box) - local)
        if o.band_edges == "clamp" and self.band == 1:  # the winner is always the centre: static slices
            j: torch.Tensor | int = 1
        else:
            j, _ = winner_take_all(local.detach())
            if o.band_edges == "clamp":  # a winner on the band's edge: refined from its inner neighbour instead
                j = j.clamp(1, 2 * self.band - 1)
        refined = _refine(o, local, local, j, o.cost, True, self.vertex_limit)
        if isinstance(j, int):
            frac, s_j, ok = refined - j, s0 + offsets[j], ok0 & warped.valid[:, j:j + 1]
        else:  # the winner's s and validity by arithmetic on (B, 1, H, W): the numbers of gathers from the band
            frac = refined - j.to(reference.dtype)
            s_j = s0 + (j - self.band).to(reference.dtype) * step
            ok = ok0 & (s_j >= lo) & (s_j <= hi) & (j > 0) & (j < 2 * self.band)
        s = s_j + frac * step
        # the match: the series at s (16 multiply-adds per pixel with setup 1's degree 4, cheaper in onnxruntime
        # than gathering the band's samples around s and interpolating between them, which was within 2e-4 px)
        match = torch.cat(series_at(series, s, top), 1) if self.with_match else None
        return LevelResult(s, ok, similarity(_pick(local, j), o.cost, channels, o.window), match)


def _pick(t: torch.Tensor, j: torch.Tensor | int) -> torch.Tensor:
    """(B, 1, H, W) entries of (B, J, H, W) ``t`` at each pixel's hypothesis ``j`` ((B, 1, H, W) long), or at one
    hypothesis for all (an int: a static slice, no gather in an exported graph)."""
    return t[:, j:j + 1] if isinstance(j, int) else t.gather(1, j)


class Extended(NamedTuple):
    """:func:`extend_estimate`'s result, (B, 1, H, W) each.

    Attributes:
        s: the estimate, extended to invalid pixels in reach of valid ones.
        reach: bool, where it is defined (valid, or a valid pixel within the radius).
    """

    s: torch.Tensor
    reach: torch.Tensor


def extend_estimate(s: torch.Tensor, valid: torch.Tensor, radius: int) -> Extended:
    """Give invalid pixels within ``radius`` pixels of a valid one the mean s of the valid pixels of their
    (2 radius + 1)^2 window; valid pixels, and those out of reach, keep theirs.

    A coarse level loses a margin of about its window at the edges of the common field of view (its windows
    leave the other half's image there) and elsewhere along invalid patches; the fine band, with its own
    smaller full-resolution windows and checks, can still match most of these pixels if it is placed near
    the right s. (:class:`~prismstereo.model.PrismStereo` accepts such a pixel only at a higher confidence.)

    Args:
        s: (B, 1, H, W) estimate; any value where invalid (NaN too: kept only where out of reach).
        valid: (B, 1, H, W) bool.
        radius: >= 0 pixels (0: unchanged).

    Example:
        >>> s = torch.tensor([[[[0.2, 0.4, 9.0, 9.0]]]]); ok = torch.tensor([[[[True, True, False, False]]]])
        >>> t, reach = extend_estimate(s, ok, 1)
        >>> [round(v, 3) for v in t[0, 0, 0].tolist()], reach[0, 0, 0].tolist()
        ([0.2, 0.4, 0.4, 9.0], [True, True, True, False])
    """
    check_shape(s, ["B", 1, "H", "W"], "s")
    if valid.shape != s.shape or valid.dtype != torch.bool:
        raise ShapeError(f"valid must be a bool tensor of s's shape {tuple(s.shape)}, got {valid.dtype} "
                         f"{tuple(valid.shape)}")
    if not isinstance(radius, int) or radius < 0:
        raise OptionError(f"radius must be an int >= 0, got {radius!r}")
    if radius == 0:
        return Extended(s, valid)
    k = 2 * radius + 1

    def window_mean(t: torch.Tensor) -> torch.Tensor:  # separable: 2 k instead of k^2 terms per pixel
        t = F.avg_pool2d(t, (k, 1), 1, (radius, 0), count_include_pad=False)
        return F.avg_pool2d(t, (1, k), 1, (0, radius), count_include_pad=False)

    total = window_mean(torch.where(valid, s, s.new_tensor(0.0)))
    share = window_mean(valid.to(s.dtype))  # same normalisation: the ratio is the mean
    mean = total / share.clamp_min(torch.finfo(s.dtype).tiny)
    reach = valid | (share > 0)
    return Extended(torch.where(valid | ~reach, s, mean), reach)
