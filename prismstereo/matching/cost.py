"""Matching costs on shift-based cost volumes: SAD, ZNCC and census (Hamming).

A cost volume compares each reference pixel (v, u) with the other image at column u + offset_i for D
hypotheses (fractional offsets interpolate linearly between columns). For a conventional rectified pair
with disparity d (right column = u - d) the offsets are -d; for the bi-prism's shift-band form
(:mod:`prismstereo.epipolar.grids`) they are the band shifts. Slices are built by slicing, never by one
``grid_sample`` per hypothesis.

Costs (lower is better), all (B, D, H, W):

* ``'sad'``: mean over channels of |I_ref - I_other| per pixel (aggregate with a box afterwards).
* ``'census'``: Hamming distance between census codes (``window`` x ``window`` neighbourhood, one bit per
  neighbour and channel: darker than the centre), per pixel, in [0, bits].
* ``'zncc'``: 1 - zero-normalised cross-correlation over a ``window`` x ``window`` window, in [0, 2].

Out-of-range samples get the cost's worst value and ``valid`` False.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.errors import OptionError, ShapeError, check_option, check_shape
from prismstereo.matching.aggregate import box_filter

__all__ = ["Cost", "COSTS", "CostVolume", "census_transform", "shifted", "cost_volume"]

Cost = Literal["sad", "zncc", "census"]
COSTS: tuple[str, ...] = ("sad", "zncc", "census")


class CostVolume(NamedTuple):
    """A cost volume.

    Attributes:
        cost: (B, D, H, W) matching cost, lower is better.
        valid: (1, D, 1, W) bool: the hypothesis' sample lies inside the other image.
    """

    cost: torch.Tensor
    valid: torch.Tensor


def _check_window(window: int) -> None:
    if not isinstance(window, int) or window < 1 or window % 2 == 0:
        raise OptionError(f"window must be a positive odd int, got {window!r}")


def census_transform(image: torch.Tensor, window: int = 5) -> torch.Tensor:
    """Census bits: for every neighbour of a ``window`` x ``window`` window and every channel, 1 where the
    neighbour is darker than the centre. Borders replicate the edge.

    Args:
        image: (B, C, H, W).
        window: odd window size (>= 3).

    Returns:
        (B, C * (window^2 - 1), H, W) float tensor of 0/1 bits.

    Example:
        >>> census_transform(torch.rand(1, 1, 6, 7), 3).shape
        torch.Size([1, 8, 6, 7])
    """
    check_shape(image, ["B", "C", "H", "W"], "image")
    _check_window(window)
    if window < 3:
        raise OptionError(f"census window must be >= 3, got {window}")
    r = window // 2
    padded = F.pad(image, (r, r, r, r), mode="replicate")
    h, w = image.shape[-2:]
    bits = [
        (padded[..., dy:dy + h, dx:dx + w] < image).to(image.dtype)
        for dy in range(window) for dx in range(window) if (dy, dx) != (r, r)
    ]
    return torch.cat(bits, dim=1)


def shifted(other: torch.Tensor, offset: float, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Columns u + offset (u = 0..width-1) of ``other`` (B, C, H, W_o), linearly interpolated.

    Returns:
        (view (B, C, H, width), valid (width,) bool: 0 <= u + offset <= W_o - 1).

    Example:
        >>> view, ok = shifted(torch.arange(5.0).view(1, 1, 1, 5), 1.5, 4)
        >>> view.flatten(), ok
        (tensor([1.5000, 2.5000, 3.5000, 0.0000]), tensor([ True,  True,  True, False]))
    """
    w_o = other.shape[-1]
    base = math.floor(offset)
    frac = offset - base
    x = torch.arange(width, device=other.device) + base
    valid = (x >= 0) & ((x + (1 if frac > 0 else 0)) <= w_o - 1)
    i0 = x.clamp(0, w_o - 1)
    out = other.index_select(-1, i0)
    if frac > 0:
        out = (1 - frac) * out + frac * other.index_select(-1, (x + 1).clamp(0, w_o - 1))
    return out * valid.to(other.dtype), valid


def cost_volume(
    reference: torch.Tensor,
    other: torch.Tensor,
    offsets: torch.Tensor,
    cost: Cost = "census",
    window: int = 5,
) -> CostVolume:
    """Compare reference pixels with the other image at columns u + offset_i.

    Args:
        reference: (B, C, H, W) reference image in [0, 1].
        other: (B, C, H, W_o) the other image, row-aligned with the reference.
        offsets: (D,) column offsets (px, fractional allowed).
        cost: 'sad', 'zncc' or 'census'.
        window: census / ZNCC window (odd).

    Returns:
        CostVolume with cost (B, D, H, W).

    Raises:
        OptionError: unknown cost or bad window. ShapeError: mismatching batch, channels or rows.

    Example:
        >>> ref = torch.rand(1, 1, 20, 30); other = torch.roll(ref, -3, dims=-1)
        >>> vol = cost_volume(ref, other, -torch.arange(6.0), "sad")
        >>> vol.cost.shape
        torch.Size([1, 6, 20, 30])
    """
    check_option(cost, COSTS, "cost")
    check_shape(reference, ["B", "C", "H", "W"], "reference")
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(offsets, ["D"], "offsets")
    _check_window(window)
    if reference.shape[:3] != other.shape[:3]:
        raise ShapeError(f"reference {tuple(reference.shape)} and other {tuple(other.shape)} must share B, C, H")
    width = reference.shape[-1]
    valid = []
    if cost == "census":
        ref_bits, other_bits = census_transform(reference, window), census_transform(other, window)
        slices = []
        for off in offsets.tolist():
            view, ok = shifted(other_bits, off, width)
            worst = torch.full_like(view[:, 0], ref_bits.shape[1])
            slices.append(torch.where(ok, (ref_bits - view).abs().sum(1), worst))
            valid.append(ok)
        volume = torch.stack(slices, dim=1)
    elif cost == "sad":
        slices = []
        for off in offsets.tolist():
            view, ok = shifted(other, off, width)
            slices.append(torch.where(ok, (reference - view).abs().mean(1), torch.ones_like(view[:, 0])))
            valid.append(ok)
        volume = torch.stack(slices, dim=1)
    else:
        volume, valid = _zncc(reference, other, offsets, window)
    mask = torch.stack(valid).view(1, len(valid), 1, width)
    return CostVolume(volume, mask)


def _zncc(reference: torch.Tensor, other: torch.Tensor, offsets: torch.Tensor, window: int):
    """1 - ZNCC over the window; products are box-filtered over the whole volume at once."""
    width = reference.shape[-1]
    gray_r, gray_o = reference.mean(1, keepdim=True), other.mean(1, keepdim=True)
    mean_r = box_filter(gray_r, window)
    var_r = (box_filter(gray_r * gray_r, window) - mean_r * mean_r).clamp_min(0)
    mean_o = box_filter(gray_o, window)
    var_o = (box_filter(gray_o * gray_o, window) - mean_o * mean_o).clamp_min(0)
    stats_o = torch.cat([gray_o, mean_o, var_o], dim=1)  # one shifted view per offset serves all three
    prods, m_o, v_o, valid = [], [], [], []
    for off in offsets.tolist():
        view, ok = shifted(stats_o, off, width)
        prods.append(gray_r[:, 0] * view[:, 0])
        m_o.append(view[:, 1])
        v_o.append(view[:, 2])
        valid.append(ok)
    cross = box_filter(torch.stack(prods, 1), window)
    mo, vo = torch.stack(m_o, 1), torch.stack(v_o, 1)
    ncc = (cross - mean_r * mo) / torch.sqrt(var_r * vo + 1e-12)
    ok = torch.stack(valid).view(1, len(valid), 1, width)
    return torch.where(ok, 1.0 - ncc.clamp(-1, 1), torch.full_like(ncc, 2.0)), valid
