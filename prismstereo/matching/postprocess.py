"""Disparity post-processing: masked and colour-weighted median filtering, background filling of rejected
pixels.

Both work on (B, 1, H, W) disparity maps with a (B, 1, H, W) bool mask of the pixels to trust, are
vectorised (no loop over pixels) and keep the input dtype.

* :func:`median_filter`: the median of the trusted disparities in a window; removes isolated outliers
  (single wrong winners, speckles smaller than half the window) and smooths the sub-pixel noise.
* :func:`fill_background`: a rejected pixel takes the lower (farther) of the nearest trusted disparities
  to its left and right on the same row. Pixels rejected by the left-right check are mostly occluded
  background next to a foreground object, so the lower neighbour is the better guess (the usual
  Middlebury-style occlusion fill); the left image border, whose matches fall outside the right image,
  takes the nearest disparity to its right.
* :func:`robust_mean`: the confidence-weighted mean of the values within a window that agree with the
  window's weighted mean; cheap (four box filters) and in the exported graph. It averages the sub-pixel noise
  of weak texture and defocus over the surface while depth steps (values further apart than the tolerance)
  stay sharp, and it fills pixels whose own value disagrees with a confident neighbourhood.
* :func:`weighted_median`: the median of the trusted disparities in a window, each weighted by its
  closeness in position and colour to the centre pixel (a bilateral weight guided by the image): pixels
  take the disparity of the nearby pixels of their own colour, which puts the fill of occluded regions and
  the fattened borders of foreground objects (pixels of the background given the foreground's disparity by
  a window-based cost) back on the right surface.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.errors import OptionError, ShapeError, check_int, check_odd, check_shape
from prismstereo.matching.aggregate import box_filter

__all__ = ["RobustMean", "median_filter", "fill_background", "robust_mean", "weighted_median"]


class RobustMean(NamedTuple):
    """:func:`robust_mean`'s result, (B, 1, H, W) each.

    Attributes:
        values: the filtered values.
        agreement: m_w(a) / m_w(w) in [0, 1], the share of the window's weight that agrees with its mean.
        support: m_w(w), the window's mean weight.
    """

    values: torch.Tensor
    agreement: torch.Tensor
    support: torch.Tensor


def _check_mask(disparity: torch.Tensor, valid: torch.Tensor | None) -> torch.Tensor:
    check_shape(disparity, ["B", 1, "H", "W"], "disparity")
    if valid is None:
        return torch.ones_like(disparity, dtype=torch.bool)
    check_shape(valid, ["B", 1, "H", "W"], "valid")
    if valid.shape != disparity.shape or valid.dtype != torch.bool:
        raise ShapeError(f"valid must be a bool tensor of shape {tuple(disparity.shape)}, got {valid.dtype} "
                         f"{tuple(valid.shape)}")
    return valid


def median_filter(disparity: torch.Tensor, window: int = 5, valid: torch.Tensor | None = None) -> torch.Tensor:
    """Median of the valid disparities in a ``window`` x ``window`` window around every valid pixel.

    Invalid pixels neither contribute nor change; windows are cut at the image border. With an even
    number of valid values the lower of the two middle ones is taken (like :func:`torch.median`).

    Args:
        disparity: (B, 1, H, W).
        valid: (B, 1, H, W) bool, None for all pixels.
        window: odd window size (1 returns the input).

    Returns:
        (B, 1, H, W) filtered disparity, dtype of ``disparity``.

    Raises:
        ShapeError: bad shapes or a non-bool mask. OptionError: ``window`` not a positive odd int.

    Example:
        >>> d = torch.full((1, 1, 5, 5), 3.0); d[0, 0, 2, 2] = 9.0
        >>> float(median_filter(d, 3)[0, 0, 2, 2])
        3.0
    """
    mask = _check_mask(disparity, valid)
    check_odd(window, "window")
    if window == 1:
        return disparity
    r = window // 2
    h, w = disparity.shape[-2:]
    values = F.pad(torch.where(mask, disparity, torch.full_like(disparity, float("inf"))), (r, r, r, r),
                   value=float("inf"))
    inside = F.pad(mask, (r, r, r, r), value=False)
    taps = torch.cat([values[..., dy:dy + h, dx:dx + w] for dy in range(window) for dx in range(window)], 1)
    count = torch.stack([inside[..., dy:dy + h, dx:dx + w] for dy in range(window) for dx in range(window)],
                        0).sum(0)  # (B, 1, H, W)
    ordered = taps.sort(dim=1).values  # invalid taps (+inf) sort last
    median = ordered.gather(1, ((count - 1) // 2).clamp_min(0))
    return torch.where(mask & (count > 0), median, disparity)


def fill_background(disparity: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Fill invalid pixels with the lower of the nearest valid disparities to their left and right (same
    row); a pixel with a valid neighbour on one side only takes that one.

    Args:
        disparity: (B, 1, H, W).
        valid: (B, 1, H, W) bool, the pixels to keep.

    Returns:
        (disparity with the fill, filled (B, 1, H, W) bool: the invalid pixels that got a value; rows
        without any valid pixel stay unfilled).

    Raises:
        ShapeError: bad shapes or a non-bool mask.

    Example:
        >>> d = torch.tensor([[5.0, 0.0, 0.0, 9.0, 0.0]]).view(1, 1, 1, 5)
        >>> ok = torch.tensor([[True, False, False, True, False]]).view(1, 1, 1, 5)
        >>> filled, new = fill_background(d, ok)
        >>> filled.flatten().tolist(), new.flatten().tolist()
        ([5.0, 5.0, 5.0, 9.0, 9.0], [False, True, True, False, True])
    """
    if valid is None:
        raise ShapeError("valid must be a bool tensor, got None")
    valid = _check_mask(disparity, valid)
    w = disparity.shape[-1]
    column = torch.arange(w, device=disparity.device).expand_as(disparity)
    # nearest valid column at or left of each pixel (-1: none), and at or right of it (w: none)
    left = torch.where(valid, column, torch.full_like(column, -1)).cummax(-1).values
    right = torch.where(valid, column, torch.full_like(column, w)).flip(-1).cummin(-1).values.flip(-1)
    inf = torch.full_like(disparity, float("inf"))
    from_left = torch.where(left >= 0, disparity.gather(-1, left.clamp_min(0)), inf)
    from_right = torch.where(right < w, disparity.gather(-1, right.clamp_max(w - 1)), inf)
    fill = torch.minimum(from_left, from_right)
    filled = ~valid & ((left >= 0) | (right < w))
    return torch.where(filled, fill, disparity), filled


def robust_mean(values: torch.Tensor, weight: torch.Tensor, window: int, tolerance: float,
                min_weight: float = 0.02, keep: float = 0.5) -> RobustMean:
    """Confidence-weighted mean of the values that agree with their window, in two passes of box filters.

    With m_w the ``window`` x ``window`` box mean (:func:`~prismstereo.matching.aggregate.box_filter`):

        mean(p)    = m_w(w x)(p) / m_w(w)(p)                                   (weighted mean)
        a(q)       = w(q) [|x(q) - mean(q)| < tolerance]                       (q agrees with its own window)
        robust(p)  = m_w(a x)(p) / m_w(a)(p)

    and the output is robust(p), except that a pixel keeps x(p) where m_w(a)(p) <= ``min_weight`` (no agreeing
    support) or where it is confident (w(p) >= ``keep``) but disagrees with robust(p) by ``tolerance`` or more.
    Values on the other side of a depth step (further than ``tolerance`` from their window's mean) drop out
    of the second pass, so a step moves by at most the width of the band where both sides mix, and confident
    structures narrower than the window (a thin rod in front of a wall) keep their own values. On a plane the
    mean of a centred window is unbiased (x linear in the pixel coordinates; the sweep coordinate of a plane
    is nearly so), so sub-pixel noise averages out. Gradients reach ``values`` (the weights and the agreement
    test are constants of the pass). Used by :class:`~prismstereo.classical.model.PrismStereo` (``smoothing``) on the
    sweep coordinate with the confidence as weight.

    Args:
        values: (B, 1, H, W) e.g. sweep coordinates or disparities.
        weight: (B, 1, H, W) >= 0, e.g. a confidence (0: the pixel does not contribute).
        window: box window (odd int >= 3).
        tolerance: agreement tolerance in the units of ``values`` (> 0).
        min_weight: the second pass's mean weight below which a pixel keeps its own value.
        keep: the weight from which a pixel that disagrees with its neighbourhood keeps its own value.

    Returns:
        :class:`RobustMean` (values, agreement, support), (B, 1, H, W) each in the dtype of ``values``; the
        agreement and the support describe the evidence around each pixel (features of the confidence of
        :class:`~prismstereo.classical.model.PrismStereo`).

    Raises:
        ShapeError: bad shapes. OptionError: bad window or tolerance.

    Example:
        >>> x = torch.zeros(1, 1, 9, 9); x[..., 4:] = 10.0; x[0, 0, 2, 1] = 3.0  # a step and one outlier
        >>> weight = torch.ones_like(x); weight[0, 0, 2, 1] = 0.2  # the outlier is not confident
        >>> out = robust_mean(x, weight, 5, 1.0).values
        >>> [round(v, 4) for v in out[0, 0, 2].tolist()]
        [0.0, 0.0, 0.0, 0.0, 10.0, 10.0, 10.0, 10.0, 10.0]
    """
    check_shape(values, ["B", 1, "H", "W"], "values")
    if weight.shape != values.shape:
        raise ShapeError(f"weight {tuple(weight.shape)} must have the shape of values {tuple(values.shape)}")
    check_odd(window, "window", 3)
    if not (isinstance(tolerance, (int, float)) and 0 < tolerance < math.inf):
        raise OptionError(f"tolerance must be a finite number > 0, got {tolerance!r}")
    w = weight.detach().to(values.dtype).clamp_min(0.0)
    num, support = box_filter(torch.cat([w * values, w], 1), window).split(1, 1)
    mean = num / support.clamp_min(1e-12)
    agree = w * ((values.detach() - mean.detach()).abs() < tolerance).to(values.dtype)
    num, den = box_filter(torch.cat([agree * values, agree], 1), window).split(1, 1)
    robust = num / den.clamp_min(1e-12)
    own = (den <= min_weight) | ((w >= keep) & ((values.detach() - robust.detach()).abs() >= tolerance))
    return RobustMean(torch.where(own, values, robust), den / support.clamp_min(1e-12), support)


def weighted_median(
    disparity: torch.Tensor,
    guide: torch.Tensor,
    valid: torch.Tensor | None = None,
    radius: int = 9,
    sigma_space: float = 9.0,
    sigma_colour: float = 0.1,
    step: int = 1,
) -> torch.Tensor:
    """Colour-weighted median of the valid disparities in a (2 r + 1)^2 window around every valid pixel.

    Tap q of pixel p weighs exp(-|q - p|^2 / sigma_space^2 - max_c (guide_c(q) - guide_c(p))^2 /
    sigma_colour^2) (0 for invalid taps and taps outside the image); the output is the tap value at which
    the cumulative weight of the sorted taps reaches half the total (the lower one on a tie), so values are
    taken from the input, sub-pixel ones included. With ``step`` > 1 only the taps at multiples of ``step``
    from the centre are used (a sparser window, ~1 / step^2 of the work). Invalid pixels do not change;
    neither do pixels whose taps all weigh 0.

    Exact (the taps are sorted, no histogram of bins); vectorised over chunks of pixels (at most ~2^22 taps
    at a time), memory O(chunk).

    Args:
        disparity: (B, 1, H, W).
        guide: (B or 1, C, H, W) guide image (e.g. the left image in [0, 1]).
        valid: (B, 1, H, W) bool, the pixels to use and to filter; None for all.
        radius: window radius r (int >= 1).
        sigma_space: spatial scale (px, > 0).
        sigma_colour: colour scale (guide units, > 0).
        step: tap spacing (int >= 1).

    Returns:
        (B, 1, H, W) filtered disparity, dtype of ``disparity``.

    Raises:
        ShapeError: bad shapes or a non-bool mask. OptionError: bad radius, step or scales.

    Example:
        >>> guide = torch.zeros(1, 1, 5, 6); guide[..., 3:] = 1.0  # two colour regions
        >>> d = torch.where(guide > 0, 8.0, 2.0); d[0, 0, 2, 2] = 8.0  # a fattened foreground pixel
        >>> weighted_median(d, guide, radius=2)[0, 0, 2].tolist()
        [2.0, 2.0, 2.0, 8.0, 8.0, 8.0]
    """
    mask = _check_mask(disparity, valid)
    _check_weighted_median(disparity, guide, radius, step, sigma_space, sigma_colour)
    b, _, h, w = disparity.shape
    r = radius
    hp, wp = h + 2 * r, w + 2 * r
    guide = (guide.to(disparity.dtype) / sigma_colour).expand(b, -1, -1, -1)
    channels = guide.shape[1]
    values = F.pad(disparity, (r, r, r, r)).reshape(-1)
    inside = F.pad(mask, (r, r, r, r), value=False).reshape(-1)
    colours = F.pad(guide, (r, r, r, r), mode="replicate").permute(1, 0, 2, 3).reshape(channels, -1)
    steps = range(-(r // step) * step, r + 1, step)  # multiples of step within the radius
    taps = [(dy, dx) for dy in steps for dx in steps]
    offsets = torch.tensor([dy * wp + dx for dy, dx in taps], device=disparity.device)
    spatial = torch.tensor([-(dy * dy + dx * dx) / sigma_space**2 for dy, dx in taps], dtype=disparity.dtype,
                           device=disparity.device)
    pixels = mask.reshape(-1).nonzero().squeeze(1)  # flat (b, y, x) indices of the pixels to filter
    bi, yx = pixels // (h * w), pixels % (h * w)
    centres = bi * (hp * wp) + (yx // w + r) * wp + (yx % w + r)
    out = disparity.reshape(-1).clone()
    chunk = max(1, (1 << 22) // len(taps))
    for start in range(0, len(pixels), chunk):
        median, total = _weighted_medians(values, inside, colours, centres[start:start + chunk], offsets, spatial)
        keep = pixels[start:start + chunk]
        out[keep] = torch.where(total > 0, median, out[keep])
    return out.view(b, 1, h, w)


def _check_weighted_median(disparity: torch.Tensor, guide: torch.Tensor, radius: int, step: int, sigma_space: float,
                           sigma_colour: float) -> None:
    """:func:`weighted_median`'s checks of the guide and the options (the disparity and mask checked already)."""
    check_shape(guide, ["B", "C", "H", "W"], "guide")
    b, _, h, w = disparity.shape
    if guide.shape[-2:] != (h, w) or guide.shape[0] not in (1, b):
        raise ShapeError(f"guide {tuple(guide.shape)} must match the disparity {tuple(disparity.shape)} in H, W "
                         "and batch")
    for name, value in (("radius", radius), ("step", step)):
        check_int(value, name, 1)
    if not (sigma_space > 0 and sigma_colour > 0):
        raise OptionError(f"sigma_space and sigma_colour must be > 0, got {sigma_space}, {sigma_colour}")


def _weighted_medians(values: torch.Tensor, inside: torch.Tensor, colours: torch.Tensor, centre: torch.Tensor,
                      offsets: torch.Tensor, spatial: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The weighted medians (N,) of the taps ``offsets`` (T,) around the flat padded indices ``centre`` (N,), and
    each pixel's total weight (N,) (0: every tap weighs 0). ``values``, ``inside`` and ``colours`` (C, P) are the
    padded disparities, mask and guide / sigma_colour; ``spatial`` (T,) the taps' -|q - p|^2 / sigma_space^2."""
    index = centre[:, None] + offsets  # (N, T)
    distance = (colours[:, index] - colours[:, centre].unsqueeze(-1)).abs_().amax(0)
    weight = (spatial - distance.square_()).exp_().mul_(inside[index])
    ordered, order = values[index].sort(dim=1)
    cumulative = weight.gather(1, order).cumsum_(1)
    total = cumulative[:, -1:]
    k = (cumulative < 0.5 * total).sum(1, keepdim=True).clamp_max(offsets.shape[0] - 1)
    return ordered.gather(1, k).squeeze(1), total.squeeze(1)
