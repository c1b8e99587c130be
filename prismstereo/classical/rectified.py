"""Dense matching of a conventional rectified pair on the depth model's matching code (``prismstereo match``).

This is how the matcher is checked on real photographs (the Middlebury pairs, ``benchmarks/middlebury.py``).
Convention: disparity d >= 0 with right column = left column - d (the usual rectified convention).

Shared with the depth model, with the options of its config groups (:attr:`MatchOptions.config`): the shift volume
(:func:`~prismstereo.matching.sweep_cost.shift_cost`, hypothesis d compares left column u with right column u - d)
and its decision (:func:`~prismstereo.matching.search.decide`: box, then SGM or the guided filter of the volume
(Rhemann et al. 2011's cost-volume filtering), winner-take-all, sub-pixel fit, confidence, uniqueness). The
matcher's own steps (:class:`MatchOptions`' other fields): the grey images as the matched images, the cost of
hypotheses whose match falls outside the other image, and the post-processing: a sub-pixel fit on the untruncated
colour difference, the left-right check against the right view's own decision, medians, the background fill of
the rejected pixels and a colour-weighted median.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, NamedTuple

import torch

from prismstereo.classical.config import StereoConfig, ValidityConfig
from prismstereo.conventions import to_grey
from prismstereo.errors import (
    OptionError,
    ShapeError,
    check_int,
    check_number,
    check_odd,
    check_option,
    check_shape,
)
from prismstereo.matching.aggregate import box_filter
from prismstereo.matching.options import AggregationConfig, CostConfig
from prismstereo.matching.postprocess import fill_background, median_filter, weighted_median
from prismstereo.matching.search import decide
from prismstereo.matching.select import left_right_check, subpixel_refine_guarded
from prismstereo.matching.sweep_cost import shift_cost

__all__ = ["MATCH_CONFIG", "SHARED_OPTIONS", "MatchOptions", "MatchResult", "match_rectified"]

OutOfRange = Literal["worst", "replicate"]
SubpixelCost = Literal["local", "sad"]

MATCH_CONFIG = StereoConfig(
    cost=CostConfig(cost="ad_gradient", window=7, census_threshold=2.0 / 255.0),
    aggregation=AggregationConfig(aggregation="guided", box=1, directions=8, p1=32.0, p2=384.0, p2_edge=0.013),
    validity=ValidityConfig(min_confidence=0.0, min_uniqueness=0.0),
)
"""The matcher's defaults of the shared options (:attr:`MatchOptions.config`): the 'ad_gradient' cost filtered by
the guided filter (chosen on the Middlebury pairs); for the census (``window``, ``census_threshold``) and SGM (8
directions, penalties in census bits, a P2 halved across edges) when they are chosen; no uniqueness or confidence
threshold (the left-right check rejects what the matcher rejects)."""

SHARED_OPTIONS: tuple[str, ...] = (
    "cost", "window", "census_threshold", "aggregation", "box", "directions", "p1", "p2", "p2_edge", "guided_radius",
    "guided_eps", "guided_subsample", "refinement", "min_uniqueness", "min_confidence",
)
"""The options of :attr:`MatchOptions.config` the matcher reads (the others are the depth model's later stages)."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class MatchOptions:
    """Options of :func:`match_rectified`: the shared part in ``config``, the matcher's own steps as fields.

    ``config`` holds the options of the steps shared with the depth model (:data:`SHARED_OPTIONS`), read by
    :func:`~prismstereo.matching.sweep_cost.shift_cost` and :func:`~prismstereo.matching.search.decide`: the cost
    (``cost``, ``window``, ``census_threshold``), the aggregation (``aggregation``, ``box``, ``directions``, ``p1``,
    ``p2``, ``p2_edge``, ``guided_radius``, ``guided_eps``, ``guided_subsample``), the shared sub-pixel fit
    (``refinement``, used with ``subpixel_cost=None``) and the decision's thresholds (``min_uniqueness``: 1 - best /
    second best aggregated cost outside winner +- 1; ``min_confidence``: the winner's similarity). The rest of the
    config (the search, the fine band, smoothing, the dense output, occlusion) is the depth model's and not read.
    :meth:`with_options` changes either kind by its flat name.

    The defaults follow Rhemann et al.'s cost-volume filtering (2011): a truncated colour + horizontal gradient
    difference filtered by a colour guided filter (the fast form, coefficients at half resolution) in each view,
    winner-take-all with a sub-pixel fit on the untruncated colour difference, left-right check, medians around a
    background fill of the rejected pixels, and last a colour-weighted median; one setting for both Middlebury
    pairs (``benchmarks/middlebury.py``). The previous defaults, census 7 x 7 + 8-direction SGM with an edge-aware
    P2 + medians, are ``with_options(cost='census', aggregation='sgm', subpixel_cost='local', subpixel_window=3,
    weighted_median=0)``. Current scores: ``docs/benchmarks.md``, *The rectified matcher on the Middlebury pairs*.

    Attributes:
        config: the shared options (default :data:`MATCH_CONFIG`).
        grey: the census and SAD compare the grey images (:func:`~prismstereo.conventions.to_grey`) instead of every
            channel (a colour census triples the bits, so the penalties, and did worse on Middlebury; ZNCC compares
            grey windows and 'ad_gradient' the mean colour difference either way); the guided filter, the edge-aware
            P2 and the weighted median see every channel.
        out_of_range: cost of hypotheses whose match falls outside the other image (the left view's left border,
            the right view's right border): 'worst' (the cost's worst value, as the shift volume fills it) or
            'replicate' (the cost of the largest in-range disparity, so the aggregation carries the disparity of the
            pixels inside into the border).
        subpixel_cost: where this cost (box-averaged over ``subpixel_window``) has its own minimum at the shared
            decision's winner, the fit on it replaces the one on the aggregated cost
            (:func:`~prismstereo.matching.select.subpixel_refine_guarded`): 'sad' (the untruncated mean absolute
            colour difference: V-shaped at the minimum, no pull towards integers, which the truncations of
            'ad_gradient' and SGM's P1 cause) or 'local' (the matching cost before aggregation); None keeps the
            shared decision's fit (``refinement``).
        subpixel_window: box window (odd) of that cost.
        lr_threshold: left-right consistency tolerance (px), None to skip the check. The right view gets its own
            shift volume and decision (the same options, its aggregation guided by the right image).
        median: window (odd, 1 = none) of the median filters
            (:func:`~prismstereo.matching.postprocess.median_filter`): one over the valid pixels after the checks
            (also with ``fill=False``), one over the valid and filled pixels after the fill.
        fill: give the invalid pixels the lower of the nearest valid disparities on their row
            (:func:`~prismstereo.matching.postprocess.fill_background`); they stay invalid and are flagged in
            :attr:`MatchResult.filled`.
        weighted_median: radius (0 = none) of the colour-weighted median
            (:func:`~prismstereo.matching.postprocess.weighted_median`, guided by the left image) applied last to
            the valid and filled pixels, over the valid and filled pixels: it moves the fill and the fattened
            borders of foreground objects to the disparity of the pixels of the same colour. Filled pixels that no
            right-view pixel claims (occluded, Mei et al. 2011) may only be lowered by it: they lie behind their
            neighbours.
        weighted_median_step: spacing (px, >= 1) of its taps: 2 takes every other row and column of the window.
        sigma_space: spatial scale (px, > 0) of the weighted median's weights exp(-|dx|^2 / sigma_space^2).
        sigma_colour: colour scale (image units, > 0) of its weights exp(-max_c |dI_c|^2 / sigma_colour^2).

    Example:
        >>> options = MatchOptions().with_options(cost="census", aggregation="sgm", fill=False)
        >>> options.config.cost.cost, options.config.aggregation.p2_edge, options.fill
        ('census', 0.013, False)
    """

    config: StereoConfig = MATCH_CONFIG
    grey: bool = True
    out_of_range: OutOfRange = "replicate"
    subpixel_cost: SubpixelCost | None = "sad"
    subpixel_window: int = 9
    lr_threshold: float | None = 1.0
    median: int = 5
    fill: bool = True
    weighted_median: int = 7
    weighted_median_step: int = 2
    sigma_space: float = 7.0
    sigma_colour: float = 0.1

    def __post_init__(self) -> None:
        if not isinstance(self.config, StereoConfig):
            raise OptionError(f"config must be a StereoConfig, got {type(self.config).__name__}")
        for name in ("grey", "fill"):
            if not isinstance(getattr(self, name), bool):
                raise OptionError(f"{name} must be a bool, got {getattr(self, name)!r}")
        check_option(self.out_of_range, ("worst", "replicate"), "out_of_range")
        if self.subpixel_cost is not None:
            check_option(self.subpixel_cost, ("local", "sad"), "subpixel_cost")
        for name in ("subpixel_window", "median"):
            check_odd(getattr(self, name), name)
        check_number(self.lr_threshold, "lr_threshold", 0.0, float("inf"), "a finite number > 0", none=True,
                     open_low=True)
        check_int(self.weighted_median, "weighted_median", 0)
        check_int(self.weighted_median_step, "weighted_median_step", 1)
        for name in ("sigma_space", "sigma_colour"):
            check_number(getattr(self, name), name, 0.0, float("inf"), "a finite number > 0", open_low=True)

    def with_options(self, **options: Any) -> MatchOptions:
        """A copy with some options changed by their flat names: the shared ones (:data:`SHARED_OPTIONS`) in
        ``config``, the others in the fields of their name.

        Raises:
            OptionError: a name that is neither, or a bad value.

        Example:
            >>> MatchOptions().with_options(aggregation="box", box=5, median=1).config.aggregation.box
            5
        """
        own = {f.name for f in dataclasses.fields(self)} - {"config"}
        unknown = sorted(set(options) - own - set(SHARED_OPTIONS))
        if unknown:
            raise OptionError(f"unknown matcher option(s) {', '.join(map(repr, unknown))}; valid: "
                              f"{', '.join(sorted(own | set(SHARED_OPTIONS)))}")
        shared = {k: v for k, v in options.items() if k not in own}
        config = self.config.with_options(**shared) if shared else self.config
        return dataclasses.replace(self, config=config, **{k: v for k, v in options.items() if k in own})


class MatchResult(NamedTuple):
    """Disparity of the left view.

    Attributes:
        disparity: (B, 1, H, W) sub-pixel disparity (px); meaningless where neither valid nor filled.
        valid: (B, 1, H, W) bool: passed the range, uniqueness, confidence and left-right checks.
        confidence: (B, 1, H, W) in [0, 1], the shared decision's confidence (the winner's similarity,
            :func:`~prismstereo.matching.search.similarity`); 0 where invalid.
        filled: (B, 1, H, W) bool: invalid pixels whose disparity comes from the background fill (all False
            with ``fill=False``); ``valid | filled`` is the dense map.
    """

    disparity: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor
    filled: torch.Tensor


def match_rectified(
    left: torch.Tensor, right: torch.Tensor, num_disparities: int, options: MatchOptions | None = None
) -> MatchResult:
    """Disparity of a rectified pair: the depth model's shift volume and decision, then the matcher's own
    post-processing (see the module and :class:`MatchOptions`).

    Shared (``options.config``): :func:`~prismstereo.matching.sweep_cost.shift_cost` with column
    ``index[d, u] = u - d`` (clamped to the image; a real sample where u - d >= 0), then
    :func:`~prismstereo.matching.search.decide` (a final search, guided by ``left``). The matcher's own: the cost of
    the hypotheses outside the right image (``out_of_range``), then the sub-pixel fit (``subpixel_cost``), the
    left-right check against the right view's own volume and decision (``lr_threshold``), median -> background fill
    -> median -> colour-weighted median.

    Args:
        left: (B, C, H, W) left image in [0, 1].
        right: (B, C, H, W) right image.
        num_disparities: D, disparities 0..D-1 are searched.
        options: :class:`MatchOptions`.

    Returns:
        MatchResult.

    Raises:
        ShapeError: bad or different shapes. OptionError: ``num_disparities`` not an int in [2, W).

    Example:
        >>> left = torch.rand(1, 1, 32, 48); right = torch.roll(left, -4, dims=-1)
        >>> res = match_rectified(left, right, 8)
        >>> res.disparity.shape
        torch.Size([1, 1, 32, 48])
        >>> bool((res.valid | res.filled).all())  # dense: rejected pixels are filled
        True
    """
    options = options or MatchOptions()
    _check_pair(left, right, num_disparities)
    config = options.config
    b, _, h, w = left.shape
    matched = options.grey and config.cost.cost in ("census", "sad")
    ref, other = (to_grey(left, dim=1), to_grey(right, dim=1)) if matched else (left, right)
    index, in_image = _shifts(num_disparities, h, w, -1, left.device)  # left column u: right column u - d
    volume = _volume(ref, other, index, in_image, options)
    decision = decide(volume, config.decision_options(), ref.shape[1], final=True, guide=left)
    disparity = decision.refined
    if options.subpixel_cost is not None:
        # SGM's P1 flattens the aggregated cost next to its minimum and locks fits on it to integers, and so do the
        # truncations of 'ad_gradient': where a lightly aggregated cost agrees with the winner it gives the fit
        # instead; where it disagrees (flat, or its own minimum elsewhere) the fit on the aggregated cost stays
        if options.subpixel_cost == "sad":
            fit = shift_cost(left, right, index, in_image, "sad", 1)
        else:
            fit = box_filter(volume, config.aggregation.box)
        method = "parabola" if config.cost.cost == "zncc" else "equiangular"
        disparity = subpixel_refine_guarded(box_filter(fit, options.subpixel_window), decision.index, decision.total,
                                            method)
    inside = in_image.expand(b, -1, -1, -1).gather(1, decision.index)
    valid = decision.unique & inside & (decision.confidence >= config.validity.min_confidence)
    occluded = torch.zeros_like(valid)
    if options.lr_threshold is not None:  # the right view's own volume and decision, guided by the right image
        index_r, in_image_r = _shifts(num_disparities, h, w, 1, left.device)  # right column x: left column x + d
        right_volume = _volume(other, ref, index_r, in_image_r, options)
        right_disparity = decide(right_volume, config.decision_options(), ref.shape[1], final=True, guide=right).refined
        valid = valid & left_right_check(disparity, right_disparity, options.lr_threshold)
        occluded = ~valid & _occluded(right_disparity, num_disparities, options.lr_threshold)
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
    confidence = torch.where(valid, decision.confidence, torch.zeros_like(decision.confidence))
    return MatchResult(disparity, valid, confidence, filled)


def _check_pair(left: torch.Tensor, right: torch.Tensor, num_disparities: int) -> None:
    """:func:`match_rectified`'s input checks."""
    check_shape(left, ["B", "C", "H", "W"], "left")
    check_shape(right, ["B", "C", "H", "W"], "right")
    if left.shape != right.shape:
        raise ShapeError(f"left {tuple(left.shape)} and right {tuple(right.shape)} must have the same shape")
    if isinstance(num_disparities, bool) or not isinstance(num_disparities, int) or not (
            2 <= num_disparities < left.shape[-1]):
        raise OptionError(f"num_disparities must be an int in [2, W), got {num_disparities!r}")


def _shifts(num: int, h: int, w: int, sign: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Columns of the other image, (D, W) long u + sign d clamped to [0, W), and the real samples, (1, D, H, W) bool
    (an expanded view)."""
    column = torch.arange(w, device=device) + sign * torch.arange(num, device=device).view(-1, 1)
    inside = (column >= 0) & (column < w)
    return column.clamp(0, w - 1), inside.view(1, num, 1, w).expand(1, num, h, w)


def _volume(reference: torch.Tensor, other: torch.Tensor, index: torch.Tensor, inside: torch.Tensor,
            options: MatchOptions) -> torch.Tensor:
    """The shared shift volume (worst cost outside ``other``), then the matcher's out-of-range step: with
    'replicate' the hypotheses outside take the cost of the last one inside (the largest in-range disparity)."""
    cost = options.config.cost
    volume = shift_cost(reference, other, index, inside, cost.cost, cost.window, cost.census_threshold)
    if options.out_of_range == "worst":
        return volume
    d = volume.shape[1]
    hyp = torch.arange(d, device=volume.device).view(1, d, 1, 1)
    last = torch.where(inside[..., :1, :], hyp, torch.full_like(hyp, -1)).amax(dim=1, keepdim=True).clamp_min(0)
    edge = volume.gather(1, last.expand(volume.shape[0], 1, volume.shape[2], -1))
    return torch.where(inside, volume, edge)


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
