"""Depth previews people can read: a colour map of inverse depth with a colour bar in mm, pixels without a depth
hatched in grey, for the CLI's preview images and ``--preview-video`` frames (the depth files themselves are
:mod:`prismstereo.io`'s)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from prismstereo.io import ImageIOError, _depth_array, _imwrite

if TYPE_CHECKING:  # maps of tensors or numpy arrays alike: the preview needs no torch
    import torch

__all__ = ["INVALID_GREY", "depth_preview", "write_depth_preview"]

INVALID_GREY = (96, 160)
"""The preview's hatching of pixels without a depth: diagonal stripes of these two grey levels (no colormap colour)."""


def depth_preview(
    depth: torch.Tensor,
    valid: torch.Tensor | None = None,
    cmap: str = "turbo",
    percentiles: tuple[float, float] = (2.0, 98.0),
    limits_mm: tuple[float, float] | None = None,
    colorbar: bool = True,
) -> np.ndarray:
    """An 8-bit picture of a depth map (H, W): a matplotlib colormap of inverse depth (near warm, far cool with
    ``turbo``) stretched between the given percentiles of the valid depths, or between fixed ``limits_mm``
    (z_min, z_max: the same colours in every frame of a video); pixels without a depth hatched in grey
    (:data:`INVALID_GREY`, unlike any colour of the map); with ``colorbar``, a scale on the right: the colours from
    near (top) to far (bottom) with depths in mm.

    Returns:
        (H, W + bar, 3) uint8 BGR array (OpenCV's order, for ``cv2.imwrite`` / ``cv2.VideoWriter``); bar 0 without
        ``colorbar``.

    Raises:
        ImageIOError: on an unknown colormap.

    Example:
        >>> depth_preview(torch.full((4, 5), 500.0), limits_mm=(400.0, 700.0), colorbar=False).shape
        (4, 5, 3)
        >>> depth_preview(torch.full((96, 64), 500.0), limits_mm=(400.0, 700.0)).shape[1] > 64
        True
    """
    import matplotlib

    try:
        colormap = matplotlib.colormaps[cmap]
    except KeyError as exc:
        raise ImageIOError(f"unknown matplotlib colormap {cmap!r}") from exc
    d = _depth_array(depth, valid)
    ok = np.isfinite(d) & (d > 0)
    inv = np.zeros(d.shape)
    inv[ok] = 1.0 / d[ok]
    if limits_mm is not None:
        lo, hi = 1.0 / limits_mm[1], 1.0 / limits_mm[0]
    else:
        lo, hi = np.percentile(inv[ok], percentiles) if ok.any() else (1.0 / 1000.0, 1.0 / 100.0)
    hi = max(hi, lo * (1 + 1e-9))
    t = np.clip((inv - lo) / (hi - lo), 0.0, 1.0)
    rgb = colormap(t)[..., :3]
    rows, cols = np.indices(d.shape)
    stripes = np.where((rows + cols) // 4 % 2 == 0, INVALID_GREY[0], INVALID_GREY[1]) / 255.0
    rgb[~ok] = stripes[~ok, None]
    picture = (rgb[..., ::-1] * 255).round().astype(np.uint8)
    if colorbar:
        picture = np.concatenate([picture, _colorbar(d.shape[0], lo, hi, colormap)], 1)
    return np.ascontiguousarray(picture)


def _colorbar(height: int, lo: float, hi: float, colormap) -> np.ndarray:
    """(height, width, 3) uint8 BGR: a strip of the colormap from inverse depth ``hi`` (near, top) to ``lo`` (far,
    bottom), labelled in mm at round depths."""
    scale = max(0.3, height / 700.0)  # OpenCV's font scale: readable from 96 px to full sensors
    thick = max(1, round(scale * 1.5))
    (text_w, text_h), _ = cv2.getTextSize("0000 mm", cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    strip = max(6, round(12 * scale / 0.4))
    bar = np.full((height, strip + text_w + 3 * strip // 2, 3), 255, np.uint8)
    inv = np.linspace(hi, lo, height)
    bar[:, strip // 2:strip // 2 + strip] = (colormap((inv - lo) / (hi - lo))[:, None, :3][..., ::-1] * 255).round()
    labels, last = max(2, min(6, height // (3 * text_h))), -height
    for f in np.linspace(0.0, 1.0, labels):  # evenly spaced on the bar, each depth rounded to 2 significant digits
        exact = 1.0 / (hi - f * (hi - lo))
        unit = 10.0 ** (int(np.floor(np.log10(exact))) - 1)
        for z in (round(exact / unit) * unit, np.floor(exact / unit) * unit, np.ceil(exact / unit) * unit):
            y = int(round((hi - 1.0 / z) / (hi - lo) * (height - 1)))  # rounded, else towards the bar's inside
            if 0 <= y < height:
                break
        if not 0 <= y < height or y - last < text_h + 2:
            continue
        last, y_text = y, min(max(y + text_h // 2, text_h), height - 2)
        cv2.line(bar, (strip // 2 + strip, y), (strip * 2 - strip // 4, y), (0, 0, 0), 1)
        cv2.putText(bar, f"{z:g} mm", (strip * 2, y_text), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick,
                    cv2.LINE_AA)
    return bar


def write_depth_preview(
    path: str | Path,
    depth: torch.Tensor,
    valid: torch.Tensor | None = None,
    cmap: str = "turbo",
    percentiles: tuple[float, float] = (2.0, 98.0),
    colorbar: bool = True,
) -> None:
    """Write :func:`depth_preview` of a depth map (H, W) as an 8-bit RGB image (with its colour bar in mm).

    Raises:
        ImageIOError: on an unknown colormap or a failed write.

    Example:
        >>> write_depth_preview("depth_preview.png", 400 + 100 * torch.rand(96, 64))  # doctest: +SKIP
    """
    _imwrite(Path(path), depth_preview(depth, valid, cmap, percentiles, colorbar=colorbar))
