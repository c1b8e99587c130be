"""Choosing a hypothesis per pixel: winner-take-all, sub-pixel refinement, local soft-argmin, checks.

All functions take a cost volume (B, D, H, W) (lower is better) and return per-pixel maps (B, 1, H, W)
in *hypothesis index* units (fractional after refinement); :mod:`prismstereo.depth.convert` turns indices
into depth.

* Sub-pixel: ``'equiangular'`` (the V fit, for L1-type costs such as SAD and census) or ``'parabola'``
  (for SSD-like costs such as ZNCC); a parabola on SAD pulls estimates toward integers (pixel locking).
* :func:`subpixel_refine_guarded`: the fit on a local cost where it agrees with the (aggregated) winner,
  else on a fallback cost: SGM's P1 flattens the aggregated curve and locks fits on it to integers.
* :func:`soft_argmin_local`: a differentiable estimate from a softmax over the 2 r + 1 hypotheses around
  the winner (a full-range soft-argmin is biased by multi-modal costs).
* :func:`uniqueness` and :func:`left_right_check` reject ambiguous and occluded pixels.
"""

from __future__ import annotations

from typing import Literal

import torch

from prismstereo.errors import OptionError, ShapeError, check_number, check_option, check_shape

__all__ = [
    "Subpixel",
    "refine",
    "winner_take_all",
    "subpixel_refine",
    "subpixel_refine_guarded",
    "soft_argmin_local",
    "uniqueness",
    "left_right_check",
]

Subpixel = Literal["equiangular", "parabola"]
Refinement = Literal["equiangular", "parabola", "soft_argmin"]

# soft-argmin temperature per cost's units
_TEMPERATURE = {"census": 1.0, "sad": 0.02, "zncc": 0.05, "ad_gradient": 0.05}


def winner_take_all(cost: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Index (B, 1, H, W) long and value (B, 1, H, W) of the lowest cost over D.

    Example:
        >>> idx, best = winner_take_all(torch.tensor([3.0, 1.0, 2.0]).view(1, 3, 1, 1))
        >>> int(idx), float(best)
        (1, 1.0)
    """
    check_shape(cost, ["B", "D", "H", "W"], "cost")
    best, index = cost.min(dim=1, keepdim=True)
    return index, best


def _neighbours(cost: torch.Tensor, index: torch.Tensor | int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    d = cost.shape[1]
    if isinstance(index, int):  # one winner for every pixel: static slices
        return tuple(cost[:, i:i + 1] for i in (max(index - 1, 0), index, min(index + 1, d - 1)))
    c0 = cost.gather(1, index)
    cm = cost.gather(1, (index - 1).clamp(0, d - 1))
    cp = cost.gather(1, (index + 1).clamp(0, d - 1))
    return cm, c0, cp


def subpixel_refine(cost: torch.Tensor, index: torch.Tensor | int, method: Subpixel = "equiangular",
                    limit: float = 0.5) -> torch.Tensor:
    """Refine integer winners to fractional indices by fitting the costs at i-1, i, i+1.

    parabola: delta = (c- - c+) / (2 (c- - 2 c0 + c+)); equiangular: delta = (c- - c+) / (2 max(c- - c0,
    c+ - c0)). delta is clamped to [-limit, limit]; winners at the first or last hypothesis stay integer.
    ``limit`` 0.5 (default) keeps a true minimum's fit within half a step of it; 1.0 lets a fit around a
    hypothesis that is not the minimum (a band's clamped edge winner) reach the outer sample (for a parabolic
    cost with its minimum on that sample the fit gives it exactly).

    Args:
        cost: (B, D, H, W).
        index: (B, 1, H, W) long winners (:func:`winner_take_all`), or one int, the winner of every pixel (the
            three costs are then static slices: no gathers in an exported graph; the same values).
        method: 'equiangular' or 'parabola'.
        limit: the largest |delta|, in (0, 1].

    Returns:
        (B, 1, H, W) fractional index, dtype of ``cost``.

    Raises:
        OptionError: unknown method, an int index outside [0, D), or a limit outside (0, 1].

    Example:
        >>> c = torch.tensor([2.0, 0.0, 1.0]).view(1, 3, 1, 1)
        >>> float(subpixel_refine(c, torch.ones(1, 1, 1, 1, dtype=torch.long))), float(subpixel_refine(c, 1))
        (1.25, 1.25)
    """
    check_option(method, ("equiangular", "parabola"), "method")
    check_number(limit, "limit", 0.0, 1.0, open_low=True)
    d = cost.shape[1]
    if isinstance(index, int) and not 0 <= index < d:
        raise OptionError(f"index must be in [0, {d}) for a cost of {d} hypotheses, got {index}")
    cm, c0, cp = _neighbours(cost, index)
    den = cm - 2 * c0 + cp if method == "parabola" else torch.maximum(cm - c0, cp - c0)
    delta = (cm - cp) / (2 * den).clamp_min(1e-12)
    if isinstance(index, int):
        return delta.clamp(-limit, limit) + index if 0 < index < d - 1 else torch.full_like(delta, float(index))
    # winners at the first or last hypothesis stay integer: the delta times the mask (finite costs give a finite
    # delta; onnxruntime runs a Where on one thread, the product on all of them)
    inner = ((index > 0) & (index < d - 1)).to(cost.dtype)
    return index.to(cost.dtype) + delta.clamp(-limit, limit) * inner


def subpixel_refine_guarded(
    cost: torch.Tensor,
    index: torch.Tensor,
    fallback: torch.Tensor | None = None,
    method: Subpixel = "equiangular",
) -> torch.Tensor:
    """:func:`subpixel_refine` on ``cost`` where it has a strict local minimum at the winner, else on
    ``fallback`` (or no refinement).

    Meant for winners chosen on an aggregated cost (SGM): the fit on a lightly aggregated local cost is
    accurate (no pixel locking) where that cost agrees with the winner; where it does not (its own minimum
    is elsewhere, or it is flat), clamping its fit to +-0.5 would push the estimate away, so the fit on the
    aggregated cost (``fallback``) is used there.

    Args:
        cost: (B, D, H, W) local cost.
        index: (B, 1, H, W) long winners.
        fallback: (B, D, H, W) cost for the other pixels (e.g. the aggregated one); None keeps them integer.
        method: 'equiangular' or 'parabola'.

    Returns:
        (B, 1, H, W) fractional index, dtype of ``cost``.

    Raises:
        ShapeError: bad shapes. OptionError: unknown method.

    Example:
        >>> local = torch.tensor([2.0, 0.0, 1.0, 3.0]).view(1, 4, 1, 1)
        >>> flat = torch.tensor([2.0, 0.0, 0.0, 3.0]).view(1, 4, 1, 1)
        >>> one = torch.ones(1, 1, 1, 1, dtype=torch.long)
        >>> float(subpixel_refine_guarded(local, one)), float(subpixel_refine_guarded(flat, one))
        (1.25, 1.0)
    """
    check_shape(cost, ["B", "D", "H", "W"], "cost")
    check_shape(index, ["B", 1, "H", "W"], "index")
    check_option(method, ("equiangular", "parabola"), "method")
    if fallback is not None and fallback.shape != cost.shape:
        raise ShapeError(f"fallback {tuple(fallback.shape)} must have the cost's shape {tuple(cost.shape)}")
    cm, c0, cp = _neighbours(cost, index)
    agrees = (cm > c0) & (cp > c0)
    other = index.to(cost.dtype) if fallback is None else subpixel_refine(fallback, index, method)
    return torch.where(agrees, subpixel_refine(cost, index, method), other)


def soft_argmin_local(
    cost: torch.Tensor, index: torch.Tensor | None = None, radius: int = 2, temperature: float = 1.0
) -> torch.Tensor:
    """Differentiable index: softmax(-cost / temperature) expectation over winner +- radius.

    The softmax is written out (min, exp, sum, divide), which exports to fast ONNX.

    Args:
        cost: (B, D, H, W).
        index: (B, 1, H, W) winners; default :func:`winner_take_all` (no gradient flows through it).
        radius: half width of the window (>= 1).
        temperature: softmax temperature in cost units (> 0).

    Returns:
        (B, 1, H, W) fractional index, differentiable w.r.t. ``cost``.

    Example:
        >>> c = torch.tensor([4.0, 1.0, 1.0, 4.0]).view(1, 4, 1, 1)
        >>> round(float(soft_argmin_local(c, radius=1, temperature=0.5)), 2)
        1.5
    """
    check_shape(cost, ["B", "D", "H", "W"], "cost")
    if radius < 1 or temperature <= 0:
        raise OptionError(f"need radius >= 1 and temperature > 0, got {radius}, {temperature}")
    if index is None:
        index = winner_take_all(cost.detach())[0]
    d = cost.shape[1]
    offsets = torch.arange(-radius, radius + 1, device=cost.device).view(1, -1, 1, 1)
    taps = (index + offsets).clamp(0, d - 1)  # (B, 2r+1, H, W)
    local = cost.gather(1, taps)
    inside = (index + offsets >= 0) & (index + offsets <= d - 1)
    logits = torch.where(inside, -local / temperature, local.new_tensor(-1e9))
    logits = logits - logits.amax(dim=1, keepdim=True).detach()
    weights = torch.exp(logits)
    weights = weights / weights.sum(dim=1, keepdim=True)
    return (weights * taps.to(cost.dtype)).sum(dim=1, keepdim=True)


def uniqueness(cost: torch.Tensor, index: torch.Tensor, ratio: float = 0.9,
               nonnegative: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Uniqueness test: the best cost must be below ``ratio`` times the best cost outside winner +- 1.

    ``nonnegative``: the caller guarantees cost >= 0 (e.g. any cost of this package, aggregated or not): the
    hypotheses near the winner are then masked by a Max with the largest float instead of a Where (which
    onnxruntime runs on one thread); the same results.

    Returns:
        (unique (B, 1, H, W) bool, confidence (B, 1, H, W) in [0, 1] = 1 - best / second best).

    Example:
        >>> c = torch.tensor([1.0, 0.2, 1.0, 0.3]).view(1, 4, 1, 1)
        >>> unique, conf = uniqueness(c, torch.ones(1, 1, 1, 1, dtype=torch.long), 0.9)
        >>> bool(unique), round(float(conf), 3)
        (True, 0.333)
    """
    if not 0 < ratio <= 1:
        raise OptionError(f"ratio must be in (0, 1], got {ratio}")
    d = cost.shape[1]
    hyp = torch.arange(d, device=cost.device).view(1, d, 1, 1)
    # two comparisons with (B, 1, H, W) bounds: |hyp - index| <= 1 would make two int64 volumes
    near = (hyp >= index - 1) & (hyp <= index + 1)
    best = cost.gather(1, index)
    if nonnegative:  # cost >= 0: max(cost, big near the winner) is the fill
        big = torch.finfo(cost.dtype).max
        second = torch.maximum(cost, near.to(cost.dtype) * big).amin(dim=1, keepdim=True)
        second = torch.where(second >= big, best, second)  # no hypothesis beyond winner +- 1 (a plane)
    else:  # a scalar fill: onnxruntime's Where against a full tensor of inf reads a whole volume more
        second = torch.where(near, cost.new_tensor(float("inf")), cost).amin(dim=1, keepdim=True)
        second = torch.where(torch.isinf(second), best, second)
    confidence = (1 - best / second.clamp_min(1e-12)).clamp(0, 1)
    return best <= ratio * second, confidence


def left_right_check(
    disparity_left: torch.Tensor, disparity_right: torch.Tensor, threshold: float = 1.0
) -> torch.Tensor:
    """Left-right consistency of a rectified pair (disparity d: right column = left column - d).

    A left pixel passes when the right disparity at u - d(u) (linear interpolation) agrees with d(u) to
    ``threshold`` px; pixels whose match falls outside the right image fail.

    Args:
        disparity_left: (B, 1, H, W) left-view disparity.
        disparity_right: (B, 1, H, W_r) right-view disparity (of the right image's pixels).
        threshold: tolerance (px).

    Returns:
        (B, 1, H, W) bool.

    Example:
        >>> dl = torch.full((1, 1, 1, 6), 2.0); dr = torch.full((1, 1, 1, 6), 2.0)
        >>> left_right_check(dl, dr)
        tensor([[[[False, False,  True,  True,  True,  True]]]])
    """
    check_shape(disparity_left, ["B", 1, "H", "W"], "disparity_left")
    check_shape(disparity_right, ["B", 1, "H", "W"], "disparity_right")
    w, w_r = disparity_left.shape[-1], disparity_right.shape[-1]
    x = torch.arange(w, dtype=disparity_left.dtype, device=disparity_left.device) - disparity_left
    inside = (x >= 0) & (x <= w_r - 1)
    x0 = torch.floor(x).clamp(0, w_r - 1).long()
    x1 = (x0 + 1).clamp(max=w_r - 1)
    a = (x - x0).clamp(0, 1)
    back = (1 - a) * disparity_right.gather(-1, x0) + a * disparity_right.gather(-1, x1)
    return inside & ((back - disparity_left).abs() <= threshold)


def refine(local: torch.Tensor, total: torch.Tensor, index: torch.Tensor | int, method: Refinement, cost: str,
           limit: float = 0.5) -> torch.Tensor:
    """The sub-pixel index of each pixel's winner ``index``: the fit ``method`` ('equiangular', 'parabola',
    :func:`subpixel_refine`) on ``local``, or 'soft_argmin' (:func:`soft_argmin_local`, radius 2, a temperature
    in the units of ``cost``) over ``total``.

    Args:
        local: (B, D, H, W) the cost the fits read.
        total: (B, D, H, W) the cost the soft-argmin reads (the aggregated one).
        index: (B, 1, H, W) long winners, or one int for every pixel.
        method: 'equiangular', 'parabola' or 'soft_argmin'.
        cost: the cost's name (:data:`~prismstereo.matching.cost.COSTS`), for the soft-argmin's temperature.
        limit: the fits' largest move from the winner (hypothesis steps).

    Returns:
        (B, 1, H, W) fractional index.

    Example:
        >>> c = torch.tensor([4.0, 1.0, 2.0]).view(1, 3, 1, 1)
        >>> round(float(refine(c, c, 1, "equiangular", "sad")), 3)
        1.333
    """
    check_option(method, ("equiangular", "parabola", "soft_argmin"), "refinement")
    if method == "soft_argmin":
        if isinstance(index, int):  # one winner for all pixels
            index = torch.full_like(total[:, :1], index, dtype=torch.long)
        return soft_argmin_local(total, index, radius=2, temperature=_TEMPERATURE[cost])
    return subpixel_refine(local, index, method, limit)
