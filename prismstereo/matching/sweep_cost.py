"""Views of the other half-image for the depth model's cost volumes, and the rectified levels' shift volume.

A plane sweep warps the other half to the reference pixels once per hypothesis (one ``grid_sample`` call for
all of them, :func:`warp_slices`): for a fronto-parallel depth plane the warped slice is the other half as seen
from the reference view, so window costs (census, ZNCC) compare like with like; for a coarse-to-fine band around
a smooth prior surface each slice is the warp by a surface parallel to that prior (a slanted support window).
:func:`sample_points` samples at per-pixel positions (the fine bands), :func:`shift_cost` builds a rectified
level's volume by column gathers. The costs themselves are :mod:`prismstereo.matching.cost`'s
(:func:`~prismstereo.matching.cost.sweep_cost`); samples outside the other half or on its pixels that see
nothing through the prism get the worst cost.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from prismstereo.conventions import to_grey
from prismstereo.errors import OptionError, ShapeError, check_odd, check_option, check_shape
from prismstereo.matching.aggregate import box_filter
from prismstereo.matching.cost import (
    COSTS,
    Cost,
    Warped,
    _x_gradient,
    ad_gradient_cost,
    ncc_cost,
    sweep_cost,
    window_moments,
    worst_cost,
    zncc_cost,
)
from prismstereo.runtime import fill_invalid, sample_bilinear, sample_grid

__all__ = ["sample_points", "sample_slices", "shift_cost", "warp_slices"]


def sample_slices(other: torch.Tensor, grid: torch.Tensor, shared: bool | None = None) -> torch.Tensor:
    """Sample ``other`` at a plane-sweep grid with one bilinear ``grid_sample`` call (border padding,
    :func:`~prismstereo.runtime.sample_grid`).

    Args:
        other: (B, C, H_o, W_o) the other half-image.
        grid: (B or 1, D, H, W, 2) sample positions normalised for ``grid_sample`` (align_corners=False:
            -1 and +1 are the outer edges of the first and last pixel).
        shared: the grid (batch 1) serves every image: the images are stacked in the channel axis of one
            ``grid_sample`` call instead of copying the grid per image. None: when the grid's batch is 1. Pass
            it explicitly in code that is traced for ONNX export (a traced batch of 1 would fix the choice).

    Returns:
        (B, C, D, H, W) samples.

    Raises:
        ShapeError: bad shapes, or a shared grid with batch > 1.

    Example:
        >>> sample_slices(torch.rand(2, 3, 10, 12), torch.zeros(1, 4, 10, 8, 2)).shape
        torch.Size([2, 3, 4, 10, 8])
    """
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(grid, ["B", "D", "H", "W", 2], "grid")
    b = other.shape[0]
    h_o, w_o = other.shape[-2:]
    g = grid.to(other.dtype)
    if g.shape[0] not in (1, b):
        raise ShapeError(f"grid batch {g.shape[0]} must be 1 or the image batch {b}")
    _, d, h, w, _ = g.shape
    if shared is None:
        shared = g.shape[0] == 1
    # border padding: windows reaching past the edge see replicated pixels instead of black, which keeps
    # matches near the other half's edges (whether the sample itself is real is decided by the caller)
    if shared:  # one grid for the batch: the images go to the channel axis (no copy of the grid per image)
        if g.shape[0] != 1:
            raise ShapeError(f"a shared grid must have batch 1, got {g.shape[0]}")
        return sample_grid(other.reshape(1, -1, h_o, w_o), g.reshape(1, d * h, w, 2)).view(b, -1, d, h, w)
    if g.shape[0] != b:  # (an Expand is a copy in onnxruntime: only when the grid really has batch 1)
        g = g.expand(b, -1, -1, -1, -1)
    return sample_grid(other, g.reshape(b, d * h, w, 2)).view(b, -1, d, h, w)


def sample_points(image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``image`` at per-image pixel positions (pixel centres at integers; positions outside
    are clamped to the image, which is ``grid_sample``'s border padding).

    Torch eager calls ``grid_sample``; an ONNX export gathers each position's four taps and blends them
    (:func:`~prismstereo.runtime.sample_bilinear`: onnxruntime's GridSample kernel is single-threaded
    and slow). The two forms agree to float rounding; both are differentiable w.r.t. the image and the
    positions.

    Args:
        image: (B, C, H, W).
        x, y: (B, D, H', W') column and row of each sample (the same shape).

    Returns:
        (B, C, D, H', W') samples.

    Raises:
        ShapeError: bad shapes.

    Example:
        >>> image = torch.arange(12.0).view(1, 1, 3, 4)
        >>> out = sample_points(image, torch.tensor([[[[0.5, 9.0]]]]), torch.tensor([[[[1.0, 0.0]]]]))
        >>> [round(v, 4) for v in out.flatten().tolist()]  # (0.5, 1) between 4 and 5; (9, 0) clamped to (3, 0)
        [4.5, 3.0]
    """
    check_shape(image, ["B", "C", "H", "W"], "image")
    check_shape(x, ["B", "D", "H", "W"], "x")
    if y.shape != x.shape or x.shape[0] != image.shape[0]:
        raise ShapeError(f"x {tuple(x.shape)} and y {tuple(y.shape)} must match, with the image's batch "
                         f"{image.shape[0]}")
    return sample_bilinear(image, x.to(image.dtype), y.to(image.dtype))


def warp_slices(
    other: torch.Tensor, grid: torch.Tensor, other_valid: torch.Tensor | None = None, shared: bool | None = None
) -> Warped:
    """Sample ``other`` at a plane-sweep grid (:func:`sample_slices`) and flag the real samples.

    A sample is valid when it lies between the first and last pixel centres of ``other`` (all bilinear taps
    inside, 1e-3 px slack) and, with ``other_valid``, every tap with non-zero weight is a pixel that sees
    through the prism (the mask is sampled as an extra channel of the same call).

    Args:
        other: (B, C, H_o, W_o) the other half-image.
        grid: (B or 1, D, H, W, 2) normalised sample positions (see :func:`sample_slices`).
        other_valid: optional (H_o, W_o) bool, pixels of the other half that see through the prism.
        shared: see :func:`sample_slices`.

    Returns:
        Warped.

    Example:
        >>> w = warp_slices(torch.rand(2, 1, 10, 12), torch.zeros(1, 3, 10, 8, 2))
        >>> w.image.shape, w.valid.shape
        (torch.Size([2, 1, 3, 10, 8]), torch.Size([2, 3, 10, 8]))
    """
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(grid, ["B", "D", "H", "W", 2], "grid")
    b, c = other.shape[:2]
    h_o, w_o = other.shape[-2:]
    g = grid.to(other.dtype)
    x, y = ((g[..., 0] + 1) * w_o - 1) / 2, ((g[..., 1] + 1) * h_o - 1) / 2  # pixel coordinates
    eps = 1e-3  # px: a centre exactly on the last pixel must not fall out by rounding
    inside = (x >= -eps) & (x <= w_o - 1 + eps) & (y >= -eps) & (y <= h_o - 1 + eps)
    stacked = other if other_valid is None else torch.cat([other, other_valid.to(other).expand(b, 1, -1, -1)], 1)
    sampled = sample_slices(stacked, g, shared)
    valid = inside if other_valid is None else inside & (sampled[:, c] > 0.999)
    return Warped(sampled[:, :c], valid.expand(b, -1, -1, -1))


def shift_cost(
    reference: torch.Tensor,
    other: torch.Tensor,
    index: torch.Tensor,
    valid: torch.Tensor,
    cost: Cost = "census",
    window: int = 5,
    census_threshold: float = 0.0,
    transposed: bool = False,
    fill: float | None = None,
) -> torch.Tensor:
    """Cost volume of a rectified pair by column shifts: hypothesis d compares reference column u with
    column ``index[d, u]`` of ``other`` on the same row (one gather builds the slices).

    Same costs and values as :func:`sweep_cost` on the gathered slices, except that ZNCC takes the window
    moments of ``other`` once from the image and gathers them (a box of a shifted image is the shifted box):
    one box filter over the volume instead of three. The window // 2 columns at each side of the reference,
    whose windows are cut by its edge, are computed from the gathered slices as :func:`sweep_cost` does;
    ``other``'s moments see its edge columns replicated, as the clamped gather (and ``grid_sample``'s border
    padding) does.

    The work happens on the transposed images (columns as rows): gathering whole rows of H values is a plain
    copy, where gathering single columns into a (D, H, W) layout is an element-wise gather plus a transpose in
    onnxruntime. ``transposed=True`` returns that (B, D, W, H) layout as it is: box filters,
    semi-global aggregation over 2, 4 or 8 directions and the winner search are symmetric in H and W, so a
    caller can stay transposed until it has a per-pixel result.

    Args:
        reference: (B, C, H, W) rectified reference in [0, 1].
        other: (B, C, H, W_o) rectified other image.
        index: (D, W) long, columns of ``other`` (in [0, W_o)).
        valid: (B or 1, D, H, W) bool, real samples ((B or 1, D, W, H) with ``transposed``).
        cost: 'sad', 'zncc', 'census' or 'ad_gradient' (its horizontal gradients taken before the gather).
        window: census / ZNCC window (odd).
        census_threshold: see :func:`sweep_cost`.
        transposed: return (B, D, W, H).
        fill: the cost of entries that are not valid (>= 0); None: the worst cost (:func:`worst_cost`).

    Returns:
        (B, D, H, W) cost (or (B, D, W, H)), ``fill`` where not valid.

    Raises:
        OptionError / ShapeError: as :func:`sweep_cost`; an index or mask of the wrong shape.

    Example:
        >>> ref = torch.rand(1, 1, 8, 12); other = torch.roll(ref, 2, dims=-1)
        >>> index = (torch.arange(12) + torch.arange(4).view(-1, 1)).clamp(max=11)
        >>> vol = shift_cost(ref, other, index, torch.ones(1, 4, 8, 12, dtype=torch.bool), "sad")
        >>> int(vol[..., :10].mean((0, 2, 3)).argmin())
        2
    """
    valid_t = _transposed_valid(reference, other, index, valid, cost, transposed)
    ref_t, other_t = reference.transpose(-1, -2), other.transpose(-1, -2)  # (B, C, W, H): columns as rows
    if fill is not None and not (isinstance(fill, (int, float)) and fill >= 0):
        raise OptionError(f"fill must be a number >= 0 or None, got {fill!r}")
    # image_t[:, :, index] gathers the slices: (B, C, W_o, H) -> (B, C, D, W, H)
    if cost == "ad_gradient":  # its gradients along W, taken on the images before the gather
        grad_r, grad_o = (_x_gradient(x).transpose(-1, -2) for x in (reference, other))
        colour = (ref_t.unsqueeze(2) - other_t[:, :, index]).abs().mean(1)  # (B, D, W, H)
        volume = ad_gradient_cost(colour, (grad_r.unsqueeze(2) - grad_o[:, :, index]).abs()[:, 0])
        value = worst_cost(cost, 1, window) if fill is None else float(fill)
        volume = fill_invalid(volume, valid_t, value, bounded=value >= worst_cost(cost, 1, window))
    elif cost != "zncc":
        volume = sweep_cost(ref_t, Warped(other_t[:, :, index], valid_t), cost, window, census_threshold)
        if fill is not None:  # sweep_cost filled the worst cost
            volume = fill_invalid(volume, valid_t, float(fill))
    else:
        volume = _zncc_shift(ref_t, other_t, index, valid_t, window, fill)
    return volume if transposed else volume.transpose(-1, -2)


def _transposed_valid(reference: torch.Tensor, other: torch.Tensor, index: torch.Tensor, valid: torch.Tensor,
                      cost: Cost, transposed: bool) -> torch.Tensor:
    """:func:`shift_cost`'s checks of its inputs; its mask as (B, D, W, H)."""
    check_option(cost, COSTS, "cost")
    check_shape(reference, ["B", "C", "H", "W"], "reference")
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(index, ["D", "W"], "index")
    b, _, h, w = reference.shape
    if index.shape[1] != w or other.shape[:3] != reference.shape[:3]:
        raise ShapeError(f"reference {tuple(reference.shape)}, other {tuple(other.shape)} and index "
                         f"{tuple(index.shape)} disagree")
    d = index.shape[0]
    expected = (d, w, h) if transposed else (d, h, w)
    if valid.dim() != 4 or tuple(valid.shape[1:]) != expected or valid.shape[0] not in (1, b):
        raise ShapeError(f"valid must be (B or 1, {', '.join(map(str, expected))}), got {tuple(valid.shape)}")
    return (valid if transposed else valid.transpose(-1, -2)).expand(b, -1, -1, -1)


def _zncc_shift(ref_t: torch.Tensor, other_t: torch.Tensor, index: torch.Tensor, valid_t: torch.Tensor, window: int,
                fill: float | None) -> torch.Tensor:
    """:func:`shift_cost`'s ZNCC on the transposed (B, C, W, H) images: ``other``'s window moments taken once and
    gathered, the edge columns from the gathered slices as :func:`sweep_cost` computes them. Returns (B, D, W, H)."""
    check_odd(window, "window")
    w = ref_t.shape[-2]
    r = window // 2
    ref = to_grey(ref_t, dim=1) - 0.5
    oth = to_grey(other_t, dim=1) - 0.5
    mean_r, var_r = window_moments(ref, window)
    # the gather clamps columns, i.e. replicates the edge columns: so do the moments' windows
    mean_o, var_o = (m[..., r:r + oth.shape[-2], :] for m in window_moments(F.pad(oth, (0, 0, r, r), mode="replicate"),
                                                                       window))
    # three gathers of (B, W_o, H) images: one of the stacked three costs onnxruntime a Split (a copy) of the
    # (B, 3, D, W, H) result, and dropping a channel axis after the gather is another copy
    wrp, mean_w, var_w = (x[:, 0][:, index] for x in (oth, mean_o, var_o))  # each (B, D, W, H)
    cross = box_filter(wrp * ref, window) - mean_w * mean_r
    volume = ncc_cost(cross, var_r, var_w)
    if r and w > 2 * r:  # edge columns: truncated windows on both sides, as sweep_cost computes them
        left = zncc_cost(ref_t[..., :2 * r, :], wrp[..., :2 * r, :].unsqueeze(1) + 0.5, window)[..., :r, :]
        right = zncc_cost(ref_t[..., -2 * r:, :], wrp[..., -2 * r:, :].unsqueeze(1) + 0.5, window)[..., -r:, :]
        volume = torch.cat([left, volume[..., r:w - r, :], right], -2)
    worst = worst_cost("zncc", 1, window)
    value = worst if fill is None else float(fill)  # ZNCC lies in [0, worst]: a fill >= worst is max(volume, fill)
    return fill_invalid(volume, valid_t, value, bounded=value >= worst)
