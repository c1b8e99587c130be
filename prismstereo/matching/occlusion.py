"""Occlusion test of a depth map by a z-buffer in the other half-image.

Every reference pixel with a depth claims the other-half pixel its match falls on. Where several claim the same
pixel, only the nearest point can be seen there: the others are occluded in the other view, so their matches
are wrong (they matched the occluder's texture). :class:`~prismstereo.classical.model.PrismStereo` applies this to its
final depth (``occlusion_tolerance``, ``occluder_confidence``).
"""

from __future__ import annotations

import torch

from prismstereo.errors import OptionError, ShapeError, check_shape
from prismstereo.runtime import flat_index, scatter_min

__all__ = ["zbuffer_visible"]


def zbuffer_visible(
    match: torch.Tensor,
    depth: torch.Tensor,
    valid: torch.Tensor,
    split: int,
    other_width: int,
    tolerance: float = 0.0,
    occluders: torch.Tensor | None = None,
) -> torch.Tensor:
    """Which valid pixels are not hidden in the other half by a nearer point claiming the same pixel.

    Each pixel's match is rounded to an other-half pixel; a pixel is visible when no occluder (a pixel of
    ``occluders``, default ``valid``) whose depth is below ``depth (1 - tolerance)`` claims the same pixel.
    Invalid pixels never occlude; their own result is meaningless (combine it with ``valid``).

    Args:
        match: (B, 2, H, W_ref) full-sensor (u, v) of each reference pixel's match.
        depth: (B, 1, H, W_ref) depth Z (mm); any value where not valid.
        valid: (B, 1, H, W_ref) bool, the pixels tested.
        split: the other half's first full-sensor column.
        other_width: the other half's width (columns); matches outside it are clamped to its edge.
        tolerance: relative depth margin (>= 0): points within it of the nearest do not hide each other.
        occluders: optional (B, 1, H, W_ref) bool, the pixels allowed to hide others (e.g. confident ones).

    Returns:
        (B, 1, H, W_ref) bool.

    Raises:
        ShapeError: mismatched shapes. OptionError: negative tolerance or non-positive width.

    Example:
        >>> match = torch.tensor([[[[70.2, 70.4]], [[3.0, 3.1]]]])  # both land on other-half pixel (6, 3)
        >>> depth = torch.tensor([[[[500.0, 520.0]]]]); ok = torch.ones(1, 1, 1, 2, dtype=torch.bool)
        >>> zbuffer_visible(match, depth, ok, split=64, other_width=64)[0, 0, 0].tolist()
        [True, False]
        >>> zbuffer_visible(match, depth, ok, split=64, other_width=64, tolerance=0.05)[0, 0, 0].tolist()
        [True, True]
    """
    check_shape(match, ["B", 2, "H", "W"], "match")
    check_shape(depth, ["B", 1, "H", "W"], "depth")
    for name, mask in (("valid", valid), ("occluders", occluders)):
        if mask is not None and (mask.shape != depth.shape or mask.dtype != torch.bool):
            raise ShapeError(f"{name} must be a bool tensor of depth's shape {tuple(depth.shape)}, got {mask.dtype} "
                             f"{tuple(mask.shape)}")
    if match.shape[0] != depth.shape[0] or match.shape[-2:] != depth.shape[-2:]:
        raise ShapeError(f"match {tuple(match.shape)} does not match depth {tuple(depth.shape)}")
    if not tolerance >= 0:
        raise OptionError(f"tolerance must be >= 0, got {tolerance}")
    if not isinstance(other_width, int) or other_width < 1:
        raise OptionError(f"other_width must be a positive int, got {other_width!r}")
    b, _, h, w_ref = depth.shape
    n = h * other_width
    x = torch.round(match[:, 0] - split).clamp(0, other_width - 1)  # rounded and clamped in floating point
    y = torch.round(match[:, 1]).clamp(0, h - 1)
    target = flat_index(y, x, other_width, n).view(b, -1)
    far = depth.new_tensor(float("inf"))  # a scalar fill: no full tensor of it per call in an exported graph
    z = torch.where(valid, depth, far).view(b, -1)
    occ = z if occluders is None else torch.where(occluders, depth, far).view(b, -1)
    zbuf = torch.full((b, n), float("inf"), dtype=z.dtype, device=z.device)
    zbuf = scatter_min(zbuf, target, occ)
    return (z * (1 - tolerance) <= zbuf.gather(1, target)).view(b, 1, h, w_ref)
