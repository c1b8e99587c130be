"""Disparity post-processing: masked median filtering and background filling of rejected pixels.

Both work on (B, 1, H, W) disparity maps with a (B, 1, H, W) bool mask of the pixels to trust, are
vectorised (no loop over pixels) and keep the input dtype.

* :func:`median_filter`: the median of the trusted disparities in a window; removes isolated outliers
  (single wrong winners, speckles smaller than half the window) and smooths the sub-pixel noise.
* :func:`fill_background`: a rejected pixel takes the lower (farther) of the nearest trusted disparities
  to its left and right on the same row. Pixels rejected by the left-right check are mostly occluded
  background next to a foreground object, so the lower neighbour is the better guess (the usual
  Middlebury-style occlusion fill); the left image border, whose matches fall outside the right image,
  takes the nearest disparity to its right.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from prismstereo.errors import OptionError, ShapeError, check_shape

__all__ = ["median_filter", "fill_background"]


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
    if not isinstance(window, int) or window < 1 or window % 2 == 0:
        raise OptionError(f"window must be a positive odd int, got {window!r}")
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
