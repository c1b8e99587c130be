"""Dense matching of a conventional rectified pair with the library's matching layers.

This is how the matcher is checked on real photographs (e.g. the Middlebury pairs): the same cost,
aggregation and selection layers the bi-prism model uses, on an already rectified left/right pair.
Convention: disparity d >= 0 with right column = left column - d (the usual rectified convention).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import torch

from prismstereo.errors import OptionError, ShapeError, check_option, check_shape
from prismstereo.matching.aggregate import box_filter, sgm_aggregate, sgm_aggregate_guided
from prismstereo.matching.cost import COSTS, Cost, census_volume, cost_volume
from prismstereo.matching.postprocess import fill_background, median_filter
from prismstereo.matching.select import (
    left_right_check,
    subpixel_refine,
    subpixel_refine_guarded,
    uniqueness,
    winner_take_all,
)

__all__ = ["MatchOptions", "MatchResult", "match_rectified", "right_view_volume"]

Aggregation = Literal["box", "sgm"]
OutOfRange = Literal["worst", "replicate"]


@dataclasses.dataclass(frozen=True, kw_only=True)
class MatchOptions:
    """Options of :func:`match_rectified`.

    The defaults (grey census 7x7 with a 2-grey-level threshold, no box, 8-direction SGM with P1 32 / P2 384
    in census bits and P2 lowered across intensity edges, out-of-range hypotheses replicating the last
    in-range cost, left-right check, 5x5 median, background fill of the rejected pixels, sub-pixel fit on a
    3x3 box of the census cost) were chosen on the two Middlebury pairs (``benchmarks/middlebury.py``, one
    setting for both): bad>1px with unfilled pixels counted as bad 5.4 % (Tsukuba) and 2.1 % (Venus), against
    7.1 % and 9.7 % for OpenCV StereoSGBM with the README's settings (target 0.8x: 5.7 % and 7.8 %); among the
    valid (not filled) pixels, 95 % of each image, 4.1 % and 1.8 % are bad. Biggest single contributions:
    the adaptive P2, the fill and the median (each ~4 points on Tsukuba), the census threshold (~1).

    Args:
        cost: 'census' (default), 'sad' or 'zncc'.
        window: census / ZNCC window (odd).
        census_threshold: census bits are set where a neighbour is darker than the centre by more than this
            (image units, >= 0; 0 is the classic census); a couple of grey levels keeps flat, noisy regions
            from matching on noise.
        grey: match the channel mean instead of every channel (a colour census triples the bits, so the
            penalties, and did worse on Middlebury); the adaptive P2 still looks at every channel.
        box: box pre-aggregation window applied to the per-pixel cost (odd, 1 = none).
        aggregation: 'sgm' (scanline directions, see ``directions``) or 'box' (the pre-aggregation only).
        directions: SGM scan directions, 2, 4 or 8.
        p1, p2: SGM penalties, in units of the (box-averaged) cost.
        p2_edge: intensity step (image units) that halves P2 between neighbours (P2 / (1 + |dI| / p2_edge),
            at least P1: depth jumps are cheaper across edges); None for a constant P2.
        out_of_range: cost of hypotheses whose match falls outside the right image (the left border):
            'worst' (the cost's maximum) or 'replicate' (the cost of the largest in-range disparity, so the
            smoothness term carries the disparity of the pixels to the right into the border).
        lr_threshold: left-right consistency tolerance (px), None to skip the check.
        uniqueness_ratio: best <= ratio * second best outside +-1, in (0, 1] (1 keeps every pixel).
        min_confidence: pixels below this confidence (1 - best / second) are invalid.
        subpixel_window: box window (odd) of the local cost the sub-pixel fit uses where that cost has its
            own minimum at the winner (:func:`~prismstereo.matching.select.subpixel_refine_guarded`; the
            other pixels fit the aggregated cost).
        median: window (odd, 1 = none) of the median filters
            (:func:`~prismstereo.matching.postprocess.median_filter`): one over the valid pixels after the
            checks (also with ``fill=False``), one over the valid and filled pixels after the fill.
        fill: give the invalid pixels the lower of the nearest valid disparities on their row
            (:func:`~prismstereo.matching.postprocess.fill_background`); they stay invalid and are flagged in
            :attr:`MatchResult.filled`.
    """

    cost: Cost = "census"
    window: int = 7
    census_threshold: float = 2.0 / 255.0
    grey: bool = True
    box: int = 1
    aggregation: Aggregation = "sgm"
    directions: int = 8
    p1: float = 32.0
    p2: float = 384.0
    p2_edge: float | None = 0.013
    out_of_range: OutOfRange = "replicate"
    lr_threshold: float | None = 1.0
    uniqueness_ratio: float = 1.0
    min_confidence: float = 0.0
    subpixel_window: int = 3
    median: int = 5
    fill: bool = True

    def __post_init__(self) -> None:
        check_option(self.cost, COSTS, "cost")
        check_option(self.aggregation, ("box", "sgm"), "aggregation")
        check_option(self.out_of_range, ("worst", "replicate"), "out_of_range")
        for name in ("window", "box", "subpixel_window", "median"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1 or value % 2 == 0:
                raise OptionError(f"{name} must be a positive odd int, got {value!r}")
        if not 0 <= self.p1 <= self.p2:
            raise OptionError(f"need 0 <= p1 <= p2, got {self.p1}, {self.p2}")
        if not self.census_threshold >= 0:
            raise OptionError(f"census_threshold must be >= 0, got {self.census_threshold!r}")
        if self.p2_edge is not None and not self.p2_edge > 0:
            raise OptionError(f"p2_edge must be > 0 or None, got {self.p2_edge!r}")


class MatchResult(NamedTuple):
    """Disparity of the left view.

    Attributes:
        disparity: (B, 1, H, W) sub-pixel disparity (px); meaningless where neither valid nor filled.
        valid: (B, 1, H, W) bool: passed the range, uniqueness, confidence and left-right checks.
        confidence: (B, 1, H, W) in [0, 1] (0 where invalid).
        filled: (B, 1, H, W) bool: invalid pixels whose disparity comes from the background fill (all False
            with ``fill=False``); ``valid | filled`` is the dense map.
    """

    disparity: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    filled: torch.Tensor


def right_view_volume(volume: torch.Tensor) -> torch.Tensor:
    """The right view's volume from the left's: C_R(u, d) = C_L(u + d, d), +inf where u + d is outside.

    Example:
        >>> right_view_volume(torch.arange(8.0).view(1, 2, 1, 4))[0, 1, 0]
        tensor([5., 6., 7., inf])
    """
    w = volume.shape[-1]
    slices = []
    for d in range(volume.shape[1]):
        s = volume[:, d]
        shifted = torch.cat([s[..., d:], torch.full_like(s[..., :d], float("inf"))], dim=-1)
        slices.append(shifted[..., :w])
    return torch.stack(slices, dim=1)


def match_rectified(
    left: torch.Tensor, right: torch.Tensor, num_disparities: int, options: MatchOptions | None = None
) -> MatchResult:
    """Disparity of a rectified pair: cost volume -> box -> SGM -> WTA + sub-pixel -> checks -> median ->
    background fill -> median (see :class:`MatchOptions`).

    Args:
        left: (B, C, H, W) left image in [0, 1].
        right: (B, C, H, W) right image.
        num_disparities: D, disparities 0..D-1 are searched.
        options: :class:`MatchOptions`.

    Returns:
        MatchResult.

    Example:
        >>> left = torch.rand(1, 1, 32, 48); right = torch.roll(left, -4, dims=-1)
        >>> res = match_rectified(left, right, 8)
        >>> res.disparity.shape
        torch.Size([1, 1, 32, 48])
        >>> bool((res.valid | res.filled).all())  # dense: rejected pixels are filled
        True
    """
    options = options or MatchOptions()
    check_shape(left, ["B", "C", "H", "W"], "left")
    check_shape(right, ["B", "C", "H", "W"], "right")
    if left.shape != right.shape:
        raise ShapeError(f"left {tuple(left.shape)} and right {tuple(right.shape)} must have the same shape")
    if not isinstance(num_disparities, int) or not 2 <= num_disparities < left.shape[-1]:
        raise OptionError(f"num_disparities must be an int in [2, W), got {num_disparities!r}")
    ref, other = (left.mean(1, keepdim=True), right.mean(1, keepdim=True)) if options.grey else (left, right)
    offsets = -torch.arange(num_disparities, dtype=left.dtype, device=left.device)
    if options.cost == "census":
        volume = census_volume(ref, other, offsets, options.window, options.census_threshold)
    else:
        volume = cost_volume(ref, other, offsets, options.cost, options.window)
    cost = volume.cost
    if options.out_of_range == "replicate":
        cost = _replicate_out_of_range(cost, volume.valid)
    if options.cost != "zncc":
        cost = box_filter(cost, options.box)
    local = cost
    if options.aggregation == "sgm":
        if options.p2_edge is None:
            cost = sgm_aggregate(cost, options.p1, options.p2, options.directions)
        else:
            cost = sgm_aggregate_guided(cost, left, options.p1, options.p2, options.p2_edge, options.directions)
    method = "parabola" if options.cost == "zncc" else "equiangular"
    index, _ = winner_take_all(cost)
    # sub-pixel from a lightly aggregated local cost where it agrees with the (SGM) winner: SGM's P1
    # flattens the cost curve next to its minimum and locks fits on it to integers (0.2-0.3 px error on
    # a 6.4 px shift); where the local cost disagrees (flat, or its own minimum elsewhere) the fit on the
    # aggregated cost is safer
    disparity = subpixel_refine_guarded(box_filter(local, options.subpixel_window), index, cost, method)
    unique, confidence = uniqueness(cost, index, options.uniqueness_ratio)
    in_range = volume.valid.expand(cost.shape).gather(1, index)
    valid = unique & in_range & (confidence >= options.min_confidence)
    if options.lr_threshold is not None:
        right_cost = right_view_volume(cost)
        r_index, _ = winner_take_all(right_cost)
        r_disp = subpixel_refine(torch.nan_to_num(right_cost, posinf=1e30), r_index, method)
        valid = valid & left_right_check(disparity, r_disp, options.lr_threshold)
    disparity = median_filter(disparity, options.median, valid)
    filled = torch.zeros_like(valid)
    if options.fill:
        disparity, filled = fill_background(disparity, valid)
        disparity = median_filter(disparity, options.median, valid | filled)
    return MatchResult(disparity, valid, torch.where(valid, confidence, torch.zeros_like(confidence)), filled)


def _replicate_out_of_range(cost: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Out-of-range hypotheses (``valid`` (1, D, 1, W) False) take the cost of the last in-range one."""
    d = cost.shape[1]
    hyp = torch.arange(d, device=cost.device).view(1, d, 1, 1)
    last = torch.where(valid, hyp, torch.full_like(hyp, -1)).amax(dim=1, keepdim=True).clamp_min(0)
    edge = cost.gather(1, last.expand(cost.shape[0], 1, cost.shape[2], -1))
    return torch.where(valid, cost, edge)
