"""Matching costs of a reference image against views of the other image: SAD, ZNCC and census (Hamming).

A *view* is the other image resampled onto the reference pixels for one hypothesis; :class:`Warped` holds the
views of all D hypotheses and their validity. The depth model builds them by a plane-sweep warp
(:func:`~prismstereo.matching.sweep_cost.warp_slices`) or a gather of columns
(:func:`~prismstereo.matching.sweep_cost.shift_cost`, which the rectified-pair matcher ``prismstereo match`` uses
too); every cost is computed here, once, by :func:`sweep_cost` (or from its parts).

Costs (lower is better), all (B, D, H, W):

* ``'sad'``: mean over channels of |I_ref - I_view| per pixel (aggregate with a box afterwards);
  differentiable w.r.t. both images.
* ``'census'``: Hamming distance between the census bits (:func:`census_transform`: ``window`` x ``window``,
  one bit per neighbour and channel, set where the neighbour is darker than the centre by more than a
  threshold) of the reference and of each view, in [0, bits].
* ``'zncc'``: 1 - zero-normalised cross-correlation of the grey windows, in [0, 2], each window's variance
  floored at ~ the variance of 8-bit read noise (:func:`ncc_cost`); differentiable.
* ``'ad_gradient'``: Rhemann et al.'s (2011) truncated colour + gradient difference per pixel
  (:func:`ad_gradient_cost` of the mean absolute colour difference and of the difference of the horizontal
  gradients of the grey images, :func:`~prismstereo.conventions.to_grey`), in [0, 1]; the gradient term ignores
  brightness offsets between the views, the truncations limit the weight of occluded and mismatched pixels. No window:
  meant for an edge-aware aggregation (:func:`~prismstereo.matching.aggregate.guided_filter`).

Views that are not valid get the cost's worst value (:func:`worst_cost`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Literal, NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.conventions import to_grey
from prismstereo.errors import OptionError, ShapeError, check_odd, check_option, check_shape
from prismstereo.matching.aggregate import box_filter
from prismstereo.runtime import fill_invalid

__all__ = ["Cost", "COSTS", "Warped", "ad_gradient_cost", "census_transform", "ncc_cost", "reference_moments",
           "sweep_cost", "window_moments", "worst_cost", "zncc_cost"]

Cost = Literal["sad", "zncc", "census", "ad_gradient"]
COSTS: tuple[str, ...] = ("sad", "zncc", "census", "ad_gradient")
# 'ad_gradient' truncations and weight (chosen on Middlebury with the rectified matcher): ad_gradient_cost's defaults
AD_THRESHOLD, GRADIENT_THRESHOLD, GRADIENT_WEIGHT = 7.0 / 255.0, 2.0 / 255.0, 0.95

_VAR_FLOOR = 1e-5  # (0.8 / 255)^2: below the variance of 8-bit read noise of 1 level


class Warped(NamedTuple):
    """Views of the other image at every hypothesis.

    Attributes:
        image: (B, C, D, H, W) samples.
        valid: (B, D, H, W) bool (or broadcastable to it): the sample is real (for a plane-sweep warp: every
            bilinear tap lies inside the other half on a pixel that sees through the prism).
    """

    image: torch.Tensor
    valid: torch.Tensor


def _darker(padded: torch.Tensor, centre: torch.Tensor, window: int) -> Iterator[torch.Tensor]:
    """Census bits of ``centre`` (..., H, W) against each neighbour of the replicate-padded ``padded``
    (..., H + 2 r, W + 2 r), in raster order without the centre: bool, neighbour < centre."""
    r = window // 2
    h, w = centre.shape[-2:]
    for dy in range(window):
        for dx in range(window):
            if (dy, dx) != (r, r):
                yield padded[..., dy:dy + h, dx:dx + w] < centre


def census_transform(image: torch.Tensor, window: int = 5, threshold: float = 0.0) -> torch.Tensor:
    """Census bits: for every neighbour of a ``window`` x ``window`` window and every channel, 1 where the
    neighbour is darker than the centre by more than ``threshold``. Borders replicate the edge.

    A small threshold (a few grey levels) keeps the bits of flat, noisy regions at 0 in both images instead of
    flipping at random with the noise; 0 is the classic census.

    Args:
        image: (B, C, H, W).
        window: odd window size (>= 3).
        threshold: >= 0, in image units (2 / 255 is two grey levels of an 8-bit image in [0, 1]).

    Returns:
        (B, C * (window^2 - 1), H, W) tensor of 0/1 bits, dtype of ``image``.

    Raises:
        ShapeError: ``image`` is not (B, C, H, W). OptionError: bad window or negative threshold.

    Example:
        >>> census_transform(torch.rand(1, 1, 6, 7), 3).shape
        torch.Size([1, 8, 6, 7])
    """
    check_shape(image, ["B", "C", "H", "W"], "image")
    check_odd(window, "window")
    if window < 3:
        raise OptionError(f"census window must be >= 3, got {window}")
    if not threshold >= 0:
        raise OptionError(f"census threshold must be >= 0, got {threshold}")
    r = window // 2
    padded = F.pad(image, (r, r, r, r), mode="replicate")
    return torch.cat(list(_darker(padded, image - threshold, window)), dim=1).to(image.dtype)


def worst_cost(cost: Cost, channels: int, window: int) -> float:
    """The largest value of a cost: the fill for invalid samples.

    Example:
        >>> worst_cost("census", 1, 5)
        24.0
    """
    check_option(cost, COSTS, "cost")
    return {"sad": 1.0, "zncc": 2.0, "census": float(channels * (window * window - 1)), "ad_gradient": 1.0}[cost]


def census_cost(reference: torch.Tensor, views: torch.Tensor, window: int, threshold: float) -> torch.Tensor:
    """Hamming distance (B, D, H, W) between the census bits of ``reference`` (B, C, H, W) and of each view
    (B, C, D, H, W), counted neighbour by neighbour (no (B, C * bits, D, H, W) tensor of bits)."""
    r = window // 2
    centre_r = reference.unsqueeze(2) - threshold  # (B, C, 1, H, W)
    centre_v = views - threshold
    pad_ref = F.pad(reference, (r, r, r, r), mode="replicate").unsqueeze(2)
    pad_v = F.pad(views, (r, r, r, r, 0, 0), mode="replicate")
    count = None
    for bits_r, bits_v in zip(_darker(pad_ref, centre_r, window), _darker(pad_v, centre_v, window), strict=True):
        differ = torch.logical_xor(bits_r, bits_v).to(views.dtype)
        count = differ if count is None else count + differ
    return count.sum(1) if count.shape[1] > 1 else count.squeeze(1)  # over channels once, at the end


def window_moments(x: torch.Tensor, window: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Window mean and variance (clamped at 0) of every plane of (B, K, H, W), each (B, K, H, W).

    Example:
        >>> mean, var = window_moments(torch.arange(25.0).view(1, 1, 5, 5), 3)
        >>> float(mean[0, 0, 2, 2]), round(float(var[0, 0, 2, 2]), 2)  # 6, 7, 8, 11, ..., 18
        (12.0, 17.33)
    """
    if x.shape[1] == 1:  # one plane: x and x^2 in one box (onnxruntime pools a channel on one thread: 2 for 1)
        mean, square = box_filter(torch.cat([x, x * x], 1), window).split(1, 1)
    else:
        mean, square = box_filter(x, window), box_filter(x * x, window)
    return mean, (square - mean * mean).clamp_min(0)


def ncc_cost(cross: torch.Tensor, var_r: torch.Tensor, var_v: torch.Tensor) -> torch.Tensor:
    """1 - NCC in [0, 2] from the window covariance and the two variances, each variance floored at ~ the
    variance of 8-bit noise: windows without texture (e.g. the black pixels outside the prism's view) get
    NCC ~ 0 instead of a ratio of rounding errors (torch and onnxruntime differed by 0.02 without).

    Example:
        >>> ncc_cost(torch.tensor([1.0, 0.0]), torch.tensor([1.0, 0.0]), torch.tensor([1.0, 0.0]))
        tensor([1.0014e-05, 1.0000e+00])
    """
    ncc = cross / torch.sqrt((var_r + _VAR_FLOOR) * (var_v + _VAR_FLOOR))
    return 1.0 - ncc.clamp(-1, 1)


def reference_moments(reference: torch.Tensor, window: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Window mean and variance, (B, 1, H, W) each, of the grey ``reference`` (B, C, H, W) centred on 0.5: what
    :func:`zncc_cost` takes of the reference, and (the variance's root) the texture measure of the fine band's wide
    box and of the calibrated confidence, from one box filter. Centred because ZNCC is offset-invariant and
    E[x^2] - E[x]^2 cancels far less in float32 about 0 (torch and onnxruntime then agree to ~1e-6 on low-contrast
    windows).

    Example:
        >>> mean, var = reference_moments(torch.full((1, 1, 4, 4), 0.75), 3)
        >>> float(mean[0, 0, 1, 1]), float(var[0, 0, 1, 1])
        (0.25, 0.0)
    """
    return window_moments(to_grey(reference, dim=1) - 0.5, window)


def zncc_cost(reference: torch.Tensor, views: torch.Tensor, window: int,
              moments: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
    """1 - ZNCC (B, D, H, W) of the grey ``reference`` (B, C, H, W) against each grey view (B, C, D, H, W);
    ``moments``: the reference's :func:`reference_moments` when the caller has them (computed here otherwise).

    Example:
        >>> ref = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> cost = zncc_cost(ref, torch.stack([ref, 1.0 - ref], 2), 5)
        >>> cost.shape, bool(cost[0, 0].max() < 0.01), bool(cost[0, 1].min() > 1.99)
        (torch.Size([1, 2, 8, 8]), True, True)
    """
    # both centred on 0.5, as reference_moments
    ref = to_grey(reference, dim=1) - 0.5  # (B, 1, H, W)
    view = to_grey(views, dim=1).squeeze(1) - 0.5  # (B, D, H, W)
    mean_r, var_r = window_moments(ref, window) if moments is None else moments
    mean_v, var_v = window_moments(view, window)
    cross = box_filter(view * ref, window) - mean_v * mean_r
    return ncc_cost(cross, var_r, var_v)


def sweep_cost(
    reference: torch.Tensor, warped: Warped, cost: Cost = "census", window: int = 5, census_threshold: float = 0.0,
    moments: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """Per-pixel matching cost of the reference against each view.

    Args:
        reference: (B, C, H, W) reference in [0, 1].
        warped: the views, image (B, C, D, H, W) (e.g.
            :func:`~prismstereo.matching.sweep_cost.warp_slices` of the other half).
        cost: 'sad', 'zncc', 'census' or 'ad_gradient' (its gradients along W of each view).
        window: census / ZNCC window (odd; census >= 3).
        census_threshold: a census bit is set where the neighbour is darker than the centre by more than this
            (>= 0). A threshold that is not a multiple of 1/255 keeps 8-bit ties (equal neighbours) from
            flipping bits on rounding differences between runtimes (torch vs onnxruntime).
        moments: 'zncc': the reference's :func:`reference_moments` (B, 1, H, W) each, when the caller has them.

    Returns:
        (B, D, H, W) cost, the worst value (:func:`worst_cost`) where the view is not valid.

    Raises:
        OptionError: unknown cost, bad window or negative threshold. ShapeError: reference and views disagree.

    Example:
        >>> ref = torch.rand(1, 1, 12, 16)
        >>> slices = Warped(ref.unsqueeze(2).repeat(1, 1, 3, 1, 1), torch.ones(1, 3, 12, 16, dtype=torch.bool))
        >>> float(sweep_cost(ref, slices, "census").abs().max())
        0.0
    """
    check_option(cost, COSTS, "cost")
    check_shape(reference, ["B", "C", "H", "W"], "reference")
    check_shape(warped.image, ["B", "C", "D", "H", "W"], "warped.image")
    check_odd(window, "window", 3 if cost == "census" else 1)
    if warped.image.shape[:2] != reference.shape[:2] or warped.image.shape[-2:] != reference.shape[-2:]:
        raise ShapeError(f"reference {tuple(reference.shape)} does not match slices {tuple(warped.image.shape)}")
    if not census_threshold >= 0:
        raise OptionError(f"census_threshold must be >= 0, got {census_threshold}")
    if cost == "census":
        volume = census_cost(reference, warped.image, window, census_threshold)
    elif cost in ("sad", "ad_gradient"):
        volume = (reference.unsqueeze(2) - warped.image).abs().mean(1)
        if cost == "ad_gradient":  # SAD, truncated and mixed with the views' gradient difference
            gd = (_x_gradient(reference).unsqueeze(2) - _x_gradient(warped.image)).abs()[:, 0]
            volume = ad_gradient_cost(volume, gd)
    else:
        volume = zncc_cost(reference, warped.image, window, moments)
    # ZNCC (1 - a clamped NCC), census counts and 'ad_gradient' lie in [0, worst]; SAD only for images in [0, 1]
    return fill_invalid(volume, warped.valid, worst_cost(cost, reference.shape[1], window), bounded=cost != "sad")


def _x_gradient(image: torch.Tensor) -> torch.Tensor:
    """(B, 1, ..., W) central difference along W of the grey image (channels on axis 1; edges replicated:
    one-sided halves)."""
    grey = to_grey(image, dim=1)
    grey = torch.cat([grey[..., :1], grey, grey[..., -1:]], -1)
    return 0.5 * (grey[..., 2:] - grey[..., :-2])


def ad_gradient_cost(
    colour_difference: torch.Tensor,
    gradient_difference: torch.Tensor,
    ad_threshold: float = AD_THRESHOLD,
    gradient_threshold: float = GRADIENT_THRESHOLD,
    gradient_weight: float = GRADIENT_WEIGHT,
) -> torch.Tensor:
    """Rhemann et al.'s (2011) truncated mix of a colour and a gradient difference, in [0, 1]:
    ((1 - a) min(AD, t_ad) + a min(GD, t_g)) / ((1 - a) t_ad + a t_g).

    Args:
        colour_difference: (...) mean absolute colour difference, >= 0.
        gradient_difference: (...) absolute difference of the horizontal gradients (same shape).
        ad_threshold, gradient_threshold: the truncations t_ad, t_g (image units, > 0).
        gradient_weight: a, in [0, 1].

    Returns:
        (...) cost in [0, 1].

    Example:
        >>> ad_gradient_cost(torch.tensor([0.0, 1.0]), torch.tensor([0.0, 1.0])).tolist()  # equal; both saturated
        [0.0, 1.0]
    """
    scale = 1.0 / ((1 - gradient_weight) * ad_threshold + gradient_weight * gradient_threshold)
    mix = ((1 - gradient_weight) * colour_difference.clamp_max(ad_threshold)
           + gradient_weight * gradient_difference.clamp_max(gradient_threshold))
    return (mix * scale).clamp_max(1.0)  # the scale's rounding left saturated costs at 1 + 1e-7
