"""Matching costs on shift-based cost volumes: SAD, ZNCC and census (Hamming).

A cost volume compares each reference pixel (v, u) with the other image at column u + offset_i for D
hypotheses (fractional offsets interpolate linearly between columns). For a conventional rectified pair
with disparity d (right column = u - d) the offsets are -d; for the bi-prism's shift-band form
(:mod:`prismstereo.epipolar.grids`) they are the band shifts. Slices are built by slicing, never by one
``grid_sample`` per hypothesis.

Costs (lower is better), all (B, D, H, W):

* ``'sad'``: mean over channels of |I_ref - I_other| per pixel (aggregate with a box afterwards).
* ``'census'``: Hamming distance between census codes (``window`` x ``window`` neighbourhood, one bit per
  neighbour and channel: darker than the centre), per pixel, in [0, bits]. Integer offsets (a rectified
  pair's disparities) compare bit-packed codes (:func:`census_codes`, :func:`census_volume`): the same
  values, ~20x faster than one float channel per bit.
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

__all__ = ["Cost", "COSTS", "CostVolume", "census_transform", "census_codes", "shifted", "cost_volume",
           "census_volume"]

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
    return _census_bits(image, window, 0.0).to(image.dtype)


def _census_bits(image: torch.Tensor, window: int, threshold: float) -> torch.Tensor:
    """(B, C * (window^2 - 1), H, W) bool: neighbour < centre - threshold (borders replicate the edge)."""
    r = window // 2
    padded = F.pad(image, (r, r, r, r), mode="replicate")
    h, w = image.shape[-2:]
    centre = image - threshold
    return torch.cat([padded[..., dy:dy + h, dx:dx + w] < centre
                      for dy in range(window) for dx in range(window) if (dy, dx) != (r, r)], dim=1)


def census_codes(image: torch.Tensor, window: int = 5, threshold: float = 0.0) -> torch.Tensor:
    """Bit-packed census codes: the bits of :func:`census_transform`, eight to a byte.

    A bit is set where the neighbour is darker than the centre by more than ``threshold`` (0: the classic
    census, identical bits to :func:`census_transform`). A small threshold (a few grey levels) keeps the
    bits of flat, noisy regions at 0 in both images instead of flipping at random with the noise.

    Args:
        image: (B, C, H, W), floating point.
        window: odd window size (>= 3).
        threshold: >= 0, in image units (2 / 255 is two grey levels of an 8-bit image in [0, 1]).

    Returns:
        (B, ceil(C * (window^2 - 1) / 8), H, W) uint8 codes; :func:`census_volume` compares them.

    Raises:
        ShapeError: ``image`` is not (B, C, H, W). OptionError: bad window or negative threshold.

    Example:
        >>> census_codes(torch.rand(1, 1, 6, 7), 5).shape  # 24 bits: 3 bytes
        torch.Size([1, 3, 6, 7])
    """
    check_shape(image, ["B", "C", "H", "W"], "image")
    _check_window(window)
    if window < 3:
        raise OptionError(f"census window must be >= 3, got {window}")
    if not threshold >= 0:
        raise OptionError(f"census threshold must be >= 0, got {threshold}")
    bits = _census_bits(image, window, threshold)
    b, k, h, w = bits.shape
    bits = F.pad(bits.to(torch.uint8), (0, 0, 0, 0, 0, -k % 8)).view(b, -1, 8, h, w)
    weights = torch.tensor([1, 2, 4, 8, 16, 32, 64, 128], dtype=torch.uint8, device=image.device)
    return (bits * weights.view(1, 1, 8, 1, 1)).sum(2).to(torch.uint8)


def _popcount(codes: torch.Tensor) -> torch.Tensor:
    """Set bits per byte of a uint8 tensor (SWAR: shifts, masks and adds, no lookup)."""
    x = codes - ((codes >> 1) & 0x55)
    x = (x & 0x33) + ((x >> 2) & 0x33)
    return (x + (x >> 4)) & 0x0F


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
    if cost == "census" and bool((offsets == offsets.round()).all()):
        return census_volume(reference, other, offsets, window)
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


def census_volume(
    reference: torch.Tensor, other: torch.Tensor, offsets: torch.Tensor, window: int = 5, threshold: float = 0.0
) -> CostVolume:
    """Census cost volume at integer column offsets from bit-packed codes (XOR and popcount per byte).

    With ``threshold`` 0 the values equal :func:`cost_volume`'s ``'census'`` cost (which calls this for
    integer offsets); see :func:`census_codes` for the threshold.

    Args:
        reference: (B, C, H, W) reference image, floating point.
        other: (B, C, H, W_o) the other image, row-aligned with the reference.
        offsets: (D,) integer-valued column offsets (any dtype), e.g. ``-torch.arange(D)`` for disparities.
        window: census window (odd, >= 3).
        threshold: census threshold (>= 0, image units).

    Returns:
        CostVolume: cost (B, D, H, W) Hamming distances in [0, C * (window^2 - 1)], dtype of ``reference``
        (out-of-range samples get the maximum), valid (1, D, 1, W).

    Raises:
        ShapeError: bad shapes. OptionError: fractional offsets, bad window or threshold.

    Example:
        >>> left = torch.rand(1, 1, 12, 20, generator=torch.Generator().manual_seed(0))
        >>> right = torch.roll(left, -3, dims=-1)
        >>> vol = census_volume(left, right, -torch.arange(6), 5)
        >>> int(vol.cost[0, :, 6, 10].argmin()), float(vol.cost[0, 3, 6, 10])
        (3, 0.0)
    """
    check_shape(reference, ["B", "C", "H", "W"], "reference")
    check_shape(other, ["B", "C", "H", "W"], "other")
    check_shape(offsets, ["D"], "offsets")
    if reference.shape[:3] != other.shape[:3]:
        raise ShapeError(f"reference {tuple(reference.shape)} and other {tuple(other.shape)} must share B, C, H")
    if not bool((offsets == offsets.round()).all()):
        raise OptionError("census_volume needs integer offsets (use cost_volume for fractional ones)")
    ref_codes = census_codes(reference, window, threshold)
    other_codes = census_codes(other, window, threshold)
    bits = float(reference.shape[1] * (window * window - 1))
    width, w_o = reference.shape[-1], other.shape[-1]
    slices, valid = [], []
    for off in offsets.round().long().tolist():
        x = torch.arange(width, device=reference.device) + off
        ok = (x >= 0) & (x <= w_o - 1)
        view = other_codes.index_select(-1, x.clamp(0, w_o - 1))
        hamming = _popcount(torch.bitwise_xor(ref_codes, view)).sum(1).to(reference.dtype)
        slices.append(torch.where(ok, hamming, torch.full_like(hamming, bits)))
        valid.append(ok)
    return CostVolume(torch.stack(slices, dim=1), torch.stack(valid).view(1, len(valid), 1, width))


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
