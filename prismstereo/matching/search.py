"""The coarse searches: the whole depth range at one level, as swappable modules.

A *search* covers the whole depth range at one pyramid level and returns each pixel's sweep coordinate s
(linear in 1/Z, -1 at z_min, +1 at z_max), validity and confidence; two implementations share that interface,
like RAFT-Stereo's correlation blocks, and one decision (:func:`decide`: aggregation, winner, sub-pixel fit,
confidence, uniqueness):

* :class:`SweepSearch`: every hypothesis warps the other half onto the reference pixels with the exact
  per-pixel sweep (one ``grid_sample`` of D x H x W samples), cost, aggregation, winner.
* :class:`RectifiedSearch`: both halves row-rectified by vertical warps fitted to the exact sweep
  (:mod:`prismstereo.epipolar.row_rectify`); every hypothesis is a column shift (one gather builds the volume,
  :func:`~prismstereo.matching.sweep_cost.shift_cost`); the winning shift becomes s exactly
  (:func:`~prismstereo.epipolar.sweep_table.column_to_sweep`), resampled onto the unrectified pixels.

:func:`~prismstereo.classical.search.build_search` builds a rig's search from a level's resolved options; the fine
band that follows a search is :mod:`prismstereo.matching.band`'s.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.conventions import to_grey
from prismstereo.epipolar.row_rectify import RectifiedLevel
from prismstereo.epipolar.sweep_table import column_to_sweep
from prismstereo.errors import OptionError
from prismstereo.matching.aggregate import box_filter, guided_filter, sgm_aggregate, sgm_aggregate_guided
from prismstereo.matching.cost import sweep_cost, worst_cost
from prismstereo.matching.options import DecisionOptions
from prismstereo.matching.select import left_right_check, refine, uniqueness, winner_take_all
from prismstereo.matching.sweep_cost import sample_slices, shift_cost
from prismstereo.matching.sweep_sampler import SweepSampler
from prismstereo.runtime import fill_invalid, sample_grid

__all__ = ["Decision", "LevelResult", "RectifiedSearch", "SweepSearch", "decide", "similarity"]

# the cost of an entry of the rectified shift volume that is not a real sample, as a share of the worst cost (ZNCC:
# 1.5, between uncorrelated and anti-correlated): the worst cost made the shifts whose windows reach past the other
# half's edge lose to shorter ones there, a margin of about the aggregated window
_SHIFT_FILL = 0.75


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


class Decision(NamedTuple):
    """:func:`decide`'s result, (B, 1, H, W) per pixel.

    Attributes:
        index: long, the winning hypothesis.
        refined: its sub-pixel index.
        confidence: in [0, 1], the winner's similarity (:func:`similarity`).
        unique: bool, the winner passed the uniqueness test (``min_uniqueness``).
        total: (B, D, H, W) the aggregated cost.
    """

    index: torch.Tensor
    refined: torch.Tensor
    confidence: torch.Tensor
    unique: torch.Tensor
    total: torch.Tensor


def decide(volume: torch.Tensor, options: DecisionOptions, channels: int, final: bool,
           guide: torch.Tensor | None = None) -> Decision:
    """A cost volume's winners: box (``box``), then semi-global (``'sgm'``: ``directions``, ``p1``, ``p2``, ``p2_edge``)
    or guided (``'guided'``: ``guided_radius``, ``guided_eps``, ``guided_subsample``) aggregation or none,
    winner-take-all, sub-pixel refinement (``refinement`` for a ``final`` search, the fit matching the cost otherwise),
    confidence and uniqueness (``min_uniqueness``).

    The one decision of the depth model's searches and of the rectified-pair matcher
    (:func:`~prismstereo.classical.rectified.match_rectified`).

    Args:
        volume: (B, D, H, W) cost of ``options.cost.cost``, lower is better.
        options: the cost, aggregation, final fit and uniqueness (a level's:
            :meth:`~prismstereo.classical.config.StereoConfig.decision_options`).
        channels: the images' channels (the worst census cost counts bits per channel).
        final: the search's estimate is the level's (a single level), not a placement of a band.
        guide: (B or 1, C, H, W) the reference image in the volume's layout (the depth model's searches pass the
            level's grey reference, the matcher its colour left image), which steers the 'guided' aggregation
            (:func:`~prismstereo.matching.aggregate.guided_filter`) and, with ``p2_edge``, SGM's jump penalty
            (:func:`~prismstereo.matching.aggregate.sgm_aggregate_guided`); needed by those two only.

    Returns:
        Decision. The 'guided' aggregation's confidence is the similarity of the filtered cost (a window's evidence
        spread over its region of similar grey), the others' that of the box-averaged cost.

    Raises:
        OptionError: the guided filter or an edge-aware P2 without a guide.

    Example:
        >>> from prismstereo.matching.options import AggregationConfig, CostConfig
        >>> volume = torch.rand(1, 8, 12, 16)
        >>> decide(volume, DecisionOptions(CostConfig(), AggregationConfig()), 1, final=False).refined.shape
        torch.Size([1, 1, 12, 16])
    """
    cost, aggregation = options.cost.cost, options.aggregation
    guided = aggregation.aggregation == "guided"
    local = box_filter(volume, aggregation.box)
    edges = aggregation.aggregation == "sgm" and aggregation.p2_edge is not None
    if (guided or edges) and guide is None:
        raise OptionError(f"the {'guided filter' if guided else 'edge-aware P2 (p2_edge)'} needs a guide image")
    if edges:
        total = sgm_aggregate_guided(local, guide, aggregation.p1, aggregation.p2, aggregation.p2_edge,
                                     aggregation.directions)
    elif aggregation.aggregation == "sgm":
        total = sgm_aggregate(local, aggregation.p1, aggregation.p2, aggregation.directions)
    elif guided:
        total = guided_filter(local, guide, aggregation.guided_radius, aggregation.guided_eps,
                              aggregation.guided_subsample)
    else:
        total = local
    index, _ = winner_take_all(total.detach())
    scored = total if guided else local  # the cost the sub-pixel fit and the confidence read
    method = options.refinement if final and options.refinement else (
        "parabola" if cost == "zncc" else "equiangular")
    refined = refine(scored, total, index, method, cost)
    confidence = similarity(scored.gather(1, index), cost, channels, options.cost.window)
    if guided and not final:  # a placement: the band after it judges it (the filtered cost is flat in weak
        unique = torch.ones_like(index, dtype=torch.bool)  # texture, where the ratio test rejects right winners)
    else:  # costs >= 0
        unique = uniqueness(total.detach(), index, 1.0, nonnegative=True)[1] >= options.min_uniqueness
    return Decision(index, refined, confidence, unique, total)


class SweepSearch(nn.Module):
    """The whole range at one level by the exact plane sweep: the other half sampled on every pixel's sweep
    (:class:`~prismstereo.matching.sweep_sampler.SweepSampler`, the sampling :class:`~prismstereo.nn.PrismCostVolume`
    uses too), cost, aggregation, winner.

    Args:
        options: what the search decides with (:func:`decide`).
        sampler: the level's sampler (:func:`~prismstereo.matching.sweep_sampler.sweep_sampler`).

    Example:
        >>> from prismstereo.matching.options import AggregationConfig, CostConfig
        >>> from prismstereo.matching.sweep_sampler import SweepSampler
        >>> sampler = SweepSampler(torch.zeros(3, 8, 6, 2), 4, other_valid=torch.ones(8, 6, dtype=torch.bool))
        >>> search = SweepSearch(DecisionOptions(CostConfig(), AggregationConfig()), sampler)
        >>> search(torch.rand(1, 1, 8, 6), torch.rand(1, 1, 8, 6), final=False).s.shape
        torch.Size([1, 1, 8, 6])
    """

    def __init__(self, options: DecisionOptions, sampler: SweepSampler) -> None:
        super().__init__()
        self.options, self.sampler = options, sampler
        self.num_hypotheses = sampler.num_hypotheses

    def forward(self, reference: torch.Tensor, other: torch.Tensor, final: bool) -> LevelResult:
        """Search the level images ``reference`` (B, C, H, W) and ``other`` (B, C, H_o, W_o)."""
        warped = self.sampler(other)
        cost = self.options.cost
        volume = sweep_cost(reference, warped, cost.cost, cost.window, cost.census_threshold)
        index, refined, confidence, unique, _ = decide(volume, self.options, reference.shape[1], final,
                                                       to_grey(reference, dim=1))
        ok = warped.valid.gather(1, index) & unique
        return LevelResult(-1.0 + refined * (2.0 / (self.num_hypotheses - 1)), ok, confidence)


class RectifiedSearch(nn.Module):
    """The whole range at one level as a 1-D shift volume on the row-rectified halves.

    Both level images are rectified by one ``grid_sample`` each; shift k compares rectified column u with
    column u + k of the other; the volume stays transposed, (B, D, W, H), until the winner (see
    :func:`~prismstereo.matching.sweep_cost.shift_cost`) unless the aggregation is not symmetric in H and W
    (2-direction SGM scans rows only). The shift becomes the sweep coordinate exactly on each rectified
    pixel's own sweep and is resampled onto the unrectified level pixels (bilinear; validity nearest).

    Args:
        options: what the search decides with (:func:`decide`).
        level: :func:`~prismstereo.epipolar.row_rectify.rectified_level` of this level.
        factor: the level's downsampling f.
        split: the other half's first full-sensor column.
        lr_threshold: the left-right check: the other half's winners must agree with the reference's to this many
            level pixels; None: no check.

    Example:
        >>> from prismstereo.epipolar.row_rectify import fit_row_rectification, rectified_level
        >>> from prismstereo.epipolar.sweep import fit_sweep
        >>> rig = thesis_setup1().downscaled(8); fit = fit_sweep(rig, (400.0, 900.0))
        >>> level = rectified_level(fit_row_rectification(rig, fit), fit, 2, torch.ones(96, 64, dtype=torch.bool))
        >>> from prismstereo.matching.options import AggregationConfig, CostConfig
        >>> search = RectifiedSearch(DecisionOptions(CostConfig(), AggregationConfig()), level, 2, rig.reference_width)
        >>> search(torch.rand(1, 1, 48, 32), torch.rand(1, 1, 48, 32), final=False).s.shape
        torch.Size([1, 1, 48, 32])
    """

    def __init__(self, options: DecisionOptions, level: RectifiedLevel, factor: int, split: int,
                 lr_threshold: float | None = None) -> None:
        super().__init__()
        self.options, self.factor, self.split = options, factor, split
        self.lr_threshold = lr_threshold
        aggregation = options.aggregation
        self.transposed = not (aggregation.aggregation == "sgm" and aggregation.directions == 2)
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
        b, cost, t = reference.shape[0], self.options.cost, self.transposed
        ref_r = sample_slices(reference, self.reference_grid.to(reference)[None, None], shared=True)[:, :, 0]
        oth_r = sample_slices(other, self.other_grid.to(other)[None, None], shared=True)[:, :, 0]
        # 'ad_gradient' saturates at its worst on mismatches (truncated): a fill below it would win there
        fill = (1.0 if cost.cost == "ad_gradient" else _SHIFT_FILL) * worst_cost(cost.cost, reference.shape[1],
                                                                               cost.window)
        volume = shift_cost(ref_r, oth_r, self.index, self.valid.unsqueeze(0), cost.cost, cost.window,
                            cost.census_threshold, transposed=t, fill=fill)
        guide = to_grey(ref_r, dim=1).transpose(-1, -2) if t else to_grey(ref_r, dim=1)
        index, refined, confidence, unique, total = decide(volume, self.options, reference.shape[1], final, guide)
        ok = self.valid.unsqueeze(0).expand(b, -1, -1, -1).gather(1, index) & unique
        if t:
            refined, ok, confidence = refined.transpose(-1, -2), ok.transpose(-1, -2), confidence.transpose(-1, -2)
        first = self.shifts[0].to(reference)
        if self.lr_threshold is not None:  # the other half's winners over the same aggregated volume
            vol = (total if t else total.transpose(-1, -2)).detach()  # (B, D, W_l, H_r)
            d, w_l, h_r = vol.shape[1:]
            right = vol.reshape(b, d * w_l, h_r).index_select(1, self.right_index).view(b, d, -1, h_r)
            # no winner at invalid entries: the largest finite value, so that the fill is bounded (total >= 0): a
            # Max in an exported graph instead of a Where, which onnxruntime runs on one thread; winners unchanged
            right = fill_invalid(right, self.right_valid, torch.finfo(right.dtype).max, bounded=True)
            k_right = winner_take_all(right)[0].transpose(-1, -2).to(reference.dtype)  # (B, 1, H_r, W_ol)
            # disparity in left_right_check's convention (other column = reference column - d): d = -shift
            ok = ok & left_right_check(-(first + refined.detach()), -(first + k_right), self.lr_threshold)
        w_l, f = reference.shape[-1], self.factor
        u = (torch.arange(w_l, device=reference.device).to(reference.dtype) + 0.5) * f - 0.5
        column = u + self.split + (first + refined) * f  # full-sensor column of the match
        s = column_to_sweep(self.table.to(reference), column)
        grid = self.back_grid.to(reference).unsqueeze(0).expand(b, -1, -1, -1)
        s, confidence = sample_grid(s, grid), sample_grid(confidence, grid)
        # validity: the nearest rectified pixel's (no blend of valid and invalid ones), none beyond the level
        ok = F.grid_sample(ok.to(reference.dtype), grid, mode="nearest", padding_mode="zeros", align_corners=False)
        return LevelResult(s, ok > 0.5, confidence)
