"""Dense matching of a conventional rectified pair with the library's matching layers.

This is how the matcher is checked on real photographs (e.g. the Middlebury pairs): the same cost,
aggregation and selection layers the bi-prism model uses, on an already rectified left/right pair.
Convention: disparity d >= 0 with right column = left column - d (the usual rectified convention).

Besides the shared layers it has the pieces of cost-volume filtering (Rhemann et al. 2011) used by the
defaults of :class:`MatchOptions`: :func:`~prismstereo.matching.cost.ad_gradient_volume` (truncated colour +
gradient difference) and :func:`~prismstereo.matching.aggregate.guided_filter` (edge-aware aggregation of a
cost volume).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import torch

from prismstereo.errors import OptionError, ShapeError, check_int, check_odd, check_option, check_shape
from prismstereo.matching.aggregate import (
    GUIDED_EPS,
    GUIDED_RADIUS,
    GUIDED_SUBSAMPLE,
    box_filter,
    guided_filter,
    sgm_aggregate,
    sgm_aggregate_guided,
)
from prismstereo.matching.cost import (
    AD_THRESHOLD,
    COSTS,
    GRADIENT_THRESHOLD,
    GRADIENT_WEIGHT,
    ad_gradient_volume,
    cost_volume,
)
from prismstereo.matching.postprocess import fill_background, median_filter, weighted_median
from prismstereo.matching.select import (
    left_right_check,
    subpixel_refine,
    subpixel_refine_guarded,
    uniqueness,
    winner_take_all,
)

__all__ = ["MatchOptions", "MatchResult", "match_rectified", "right_view_volume"]

RectifiedCost = Literal["census", "sad", "zncc", "ad_gradient"]
RECTIFIED_COSTS: tuple[str, ...] = COSTS
Aggregation = Literal["box", "sgm", "guided"]
OutOfRange = Literal["worst", "replicate"]
SubpixelCost = Literal["local", "sad"]


@dataclasses.dataclass(frozen=True, kw_only=True)
class MatchOptions:
    """Options of :func:`match_rectified`.

    The defaults follow Rhemann et al.'s cost-volume filtering (2011): a truncated colour + horizontal
    gradient difference (:func:`ad_gradient_volume`), filtered by a colour guided filter of radius 13 (the
    fast form, coefficients at half resolution) in each view, winner-take-all with a sub-pixel fit on the
    untruncated colour difference, left-right check, 5x5 medians around a background fill of the rejected
    pixels, and last a colour-weighted median of radius 7. They were chosen on the two Middlebury pairs
    (``benchmarks/middlebury.py``, one setting for both; bad>1px with unfilled pixels counted as bad, against
    OpenCV StereoSGBM with the README's settings, target half of SGBM's: the current scores are in
    ``docs/benchmarks.md``, *The rectified matcher on the Middlebury pairs*). Each of these changes from the
    defaults, one at a time, scored worse on at least one pair and better on neither: ``cost='census'``;
    ``gradient_weight=0.89`` (Rhemann's); the right view's cost taken from the left's filtered volume instead of
    its own filter; ``lr_threshold=None``; ``fill=False``; ``median=1``; ``weighted_median=0``.
    ``guided_subsample=1`` and ``weighted_median_step=1`` give the same scores in more time. The sub-pixel fit on
    the truncated cost (``subpixel_cost='local'``, ``subpixel_window=3``) pulls estimates towards integers, which
    Tsukuba's integer ground truth rewards and Venus's sub-pixel one does not.

    A semi-global census matcher (census 7x7 with a 2-grey-level threshold, 8-direction SGM with P1 32 / P2 384
    and ``p2_edge`` 0.013, 5x5 medians; it scores worse on both pairs) is ``cost='census'``,
    ``aggregation='sgm'``, ``subpixel_cost='local'``, ``subpixel_window=3``, ``weighted_median=0``.

    Args:
        cost: 'ad_gradient' (default, :func:`ad_gradient_volume`), 'census', 'sad' or 'zncc'.
        window: census / ZNCC window (odd).
        census_threshold: census bits are set where a neighbour is darker than the centre by more than this
            (image units, >= 0; 0 is the classic census); a couple of grey levels keeps flat, noisy regions
            from matching on noise.
        grey: match the channel mean instead of every channel (a colour census triples the bits, so the
            penalties, and did worse on Middlebury; the 'ad_gradient' colour difference is the mean over
            channels either way, its gradient is always the grey one's); the adaptive P2, the guided filter and
            the weighted median still look at every channel.
        ad_threshold: truncation of the 'ad_gradient' colour difference (image units, > 0).
        gradient_threshold: truncation of its gradient difference (image units per px, > 0).
        gradient_weight: weight of the gradient term, in [0, 1] (the colour term has 1 - weight).
        box: box pre-aggregation window applied to the per-pixel cost (odd, 1 = none).
        aggregation: 'guided' (:func:`guided_filter` of the cost volume, guided by the left image), 'sgm'
            (scanline directions, see ``directions``) or 'box' (the pre-aggregation only).
        guided_radius: radius of the guided filter's box (>= 1; window 2 r + 1).
        guided_eps: its regularisation (> 0, squared image units): larger smooths across weaker edges.
        guided_subsample: compute the filter's coefficients on s x s block means (the fast guided filter, ~1/4
            of the work for 2; 1 = exact); the output keeps the full-resolution edges of the guide.
        directions: SGM scan directions, 2, 4 or 8.
        p1, p2: SGM penalties, in units of the (box-averaged) cost (the defaults suit the census, in bits).
        p2_edge: intensity step (image units) that halves P2 between neighbours (P2 / (1 + |dI| / p2_edge),
            at least P1: depth jumps are cheaper across edges); None for a constant P2.
        out_of_range: cost of hypotheses whose match falls outside the right image (the left border):
            'worst' (the cost's maximum) or 'replicate' (the cost of the largest in-range disparity, so the
            aggregation carries the disparity of the pixels to the right into the border).
        lr_threshold: left-right consistency tolerance (px), None to skip the check. With 'guided'
            aggregation the right view's volume gets its own guided filter (guided by the right image); with the
            others it is read from the left view's aggregated volume (:func:`right_view_volume`).
        uniqueness_ratio: best <= ratio * second best outside +-1, in (0, 1] (1 keeps every pixel).
        min_confidence: pixels below this confidence (1 - best / second) are invalid.
        subpixel_cost: cost of the sub-pixel fit where it has its own minimum at the winner
            (:func:`~prismstereo.matching.select.subpixel_refine_guarded`; the other pixels fit the aggregated
            cost): 'sad' (the untruncated mean absolute colour difference: V-shaped at the minimum, no pull
            towards integers) or 'local' (the matching cost before aggregation).
        subpixel_window: box window (odd) over which that cost is averaged first.
        median: window (odd, 1 = none) of the median filters
            (:func:`~prismstereo.matching.postprocess.median_filter`): one over the valid pixels after the
            checks (also with ``fill=False``), one over the valid and filled pixels after the fill.
        fill: give the invalid pixels the lower of the nearest valid disparities on their row
            (:func:`~prismstereo.matching.postprocess.fill_background`); they stay invalid and are flagged in
            :attr:`MatchResult.filled`.
        weighted_median: radius (0 = none) of the colour-weighted median
            (:func:`~prismstereo.matching.postprocess.weighted_median`, guided by the left image) applied last
            to the valid and filled pixels, over the valid and filled pixels: it moves the fill and the
            fattened borders of foreground objects to the disparity of the pixels of the same colour. Filled
            pixels that no right-view pixel claims (occluded, Mei et al. 2011) may only be lowered by it: they
            lie behind their neighbours.
        weighted_median_step: spacing (px, >= 1) of its taps: 2 takes every other row and column of the
            window (a quarter of the taps, the same scores on the Middlebury pairs).
        sigma_space: spatial scale (px, > 0) of the weighted median's weights exp(-|dx|^2 / sigma_space^2).
        sigma_colour: colour scale (image units, > 0) of its weights exp(-max_c |dI_c|^2 / sigma_colour^2).
    """

    cost: RectifiedCost = "ad_gradient"
    window: int = 7
    census_threshold: float = 2.0 / 255.0
    grey: bool = True
    ad_threshold: float = AD_THRESHOLD
    gradient_threshold: float = GRADIENT_THRESHOLD
    gradient_weight: float = GRADIENT_WEIGHT
    box: int = 1
    aggregation: Aggregation = "guided"
    guided_radius: int = GUIDED_RADIUS
    guided_eps: float = GUIDED_EPS
    guided_subsample: int = GUIDED_SUBSAMPLE
    directions: int = 8
    p1: float = 32.0
    p2: float = 384.0
    p2_edge: float | None = 0.013
    out_of_range: OutOfRange = "replicate"
    lr_threshold: float | None = 1.0
    uniqueness_ratio: float = 1.0
    min_confidence: float = 0.0
    subpixel_cost: SubpixelCost = "sad"
    subpixel_window: int = 9
    median: int = 5
    fill: bool = True
    weighted_median: int = 7
    weighted_median_step: int = 2
    sigma_space: float = 7.0
    sigma_colour: float = 0.1

    def __post_init__(self) -> None:
        check_option(self.cost, RECTIFIED_COSTS, "cost")
        check_option(self.aggregation, ("box", "sgm", "guided"), "aggregation")
        check_option(self.out_of_range, ("worst", "replicate"), "out_of_range")
        check_option(self.subpixel_cost, ("local", "sad"), "subpixel_cost")
        for name in ("window", "box", "subpixel_window", "median"):
            check_odd(getattr(self, name), name)
        for name, low in (("guided_radius", 1), ("guided_subsample", 1), ("weighted_median", 0),
                          ("weighted_median_step", 1)):
            check_int(getattr(self, name), name, low)
        if not 0 <= self.p1 <= self.p2:
            raise OptionError(f"need 0 <= p1 <= p2, got {self.p1}, {self.p2}")
        if not self.census_threshold >= 0:
            raise OptionError(f"census_threshold must be >= 0, got {self.census_threshold!r}")
        if self.p2_edge is not None and not self.p2_edge > 0:
            raise OptionError(f"p2_edge must be > 0 or None, got {self.p2_edge!r}")
        for name in ("ad_threshold", "gradient_threshold", "guided_eps", "sigma_space", "sigma_colour"):
            if not getattr(self, name) > 0:
                raise OptionError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not 0 <= self.gradient_weight <= 1:
            raise OptionError(f"gradient_weight must be in [0, 1], got {self.gradient_weight!r}")


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
    """Disparity of a rectified pair: cost volume -> box -> guided filter or SGM -> WTA + sub-pixel -> checks
    -> median -> background fill -> median -> colour-weighted median (see :class:`MatchOptions`).

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
    if options.cost == "ad_gradient":
        volume = ad_gradient_volume(left, right, offsets, options.ad_threshold, options.gradient_threshold,
                                    options.gradient_weight)
    else:
        volume = cost_volume(ref, other, offsets, options.cost, options.window, options.census_threshold)
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
    elif options.aggregation == "guided":
        cost = guided_filter(cost, left, options.guided_radius, options.guided_eps, options.guided_subsample)
    method = "parabola" if options.cost == "zncc" else "equiangular"
    index, _ = winner_take_all(cost)
    # sub-pixel from a lightly aggregated local cost where it agrees with the aggregated winner: SGM's P1
    # flattens the cost curve next to its minimum and locks fits on it to integers (0.2-0.3 px error on a
    # 6.4 px shift), and so do the truncations of 'ad_gradient' (0.15-0.2 px); where the local cost disagrees
    # (flat, or its own minimum elsewhere) the fit on the aggregated cost is safer
    fit = cost_volume(left, right, offsets, "sad", 1).cost if options.subpixel_cost == "sad" else local
    disparity = subpixel_refine_guarded(box_filter(fit, options.subpixel_window), index, cost, method)
    unique, confidence = uniqueness(cost, index, options.uniqueness_ratio)
    in_range = volume.valid.expand(cost.shape).gather(1, index)
    valid = unique & in_range & (confidence >= options.min_confidence)
    occluded = torch.zeros_like(valid)
    if options.lr_threshold is not None:
        if options.aggregation == "guided":  # the right view's own filter, guided by the right image
            right_cost = guided_filter(_right_view_local(local, options.out_of_range), right, options.guided_radius,
                                       options.guided_eps, options.guided_subsample)
        else:
            right_cost = right_view_volume(cost)
        r_index, _ = winner_take_all(right_cost)
        r_disp = subpixel_refine(torch.nan_to_num(right_cost, posinf=1e30), r_index, method)
        valid = valid & left_right_check(disparity, r_disp, options.lr_threshold)
        occluded = ~valid & _occluded(r_disp, num_disparities, options.lr_threshold)
    disparity = median_filter(disparity, options.median, valid)
    filled = torch.zeros_like(valid)
    if options.fill:
        disparity, filled = fill_background(disparity, valid)
        disparity = median_filter(disparity, options.median, valid | filled)
    if options.weighted_median > 0:
        smoothed = weighted_median(disparity, left, valid | filled, options.weighted_median, options.sigma_space,
                                   options.sigma_colour, options.weighted_median_step)
        # occluded pixels lie behind the surface next to them: the median may lower their fill, not raise it
        disparity = torch.where(filled & occluded, torch.minimum(smoothed, disparity), smoothed)
    return MatchResult(disparity, valid, torch.where(valid, confidence, torch.zeros_like(confidence)), filled)


def _right_view_local(local: torch.Tensor, out_of_range: str) -> torch.Tensor:
    """The right view's cost (:func:`right_view_volume`) with finite out-of-range hypotheses (u + d >= W):
    the cost of the last in-range one ('replicate') or the volume's maximum ('worst')."""
    right = right_view_volume(local)
    if out_of_range == "replicate":
        return _replicate_out_of_range(right, torch.isfinite(right[:1, :, :1]))
    return torch.where(torch.isfinite(right), right, local.amax())


def _occluded(r_disp: torch.Tensor, num_disparities: int, threshold: float) -> torch.Tensor:
    """(B, 1, H, W) bool: left pixels u with no hypothesis d whose right pixel u - d has a disparity within
    ``threshold`` of d (Mei et al. 2011: no right pixel claims them, so they are occluded in the right view)."""
    w = r_disp.shape[-1]
    u = torch.arange(w, device=r_disp.device)
    claimed = torch.zeros_like(r_disp, dtype=torch.bool)
    for d in range(num_disparities):
        x = u - d
        back = r_disp.index_select(-1, x.clamp_min(0))
        claimed |= ((back - d).abs() <= threshold) & (x >= 0)
    return ~claimed


def _replicate_out_of_range(cost: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Out-of-range hypotheses (``valid`` (1, D, 1, W) False) take the cost of the last in-range one."""
    d = cost.shape[1]
    hyp = torch.arange(d, device=cost.device).view(1, d, 1, 1)
    last = torch.where(valid, hyp, torch.full_like(hyp, -1)).amax(dim=1, keepdim=True).clamp_min(0)
    edge = cost.gather(1, last.expand(cost.shape[0], 1, cost.shape[2], -1))
    return torch.where(valid, cost, edge)
