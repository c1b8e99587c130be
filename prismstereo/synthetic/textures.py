"""Surface textures for the synthetic renderer: what a surface looks like at a point.

A texture maps surface coordinates (s, t) in mm (each surface defines its own, see
:mod:`prismstereo.synthetic.scenes`) to intensities in [0, 1], one value per channel. Textures are
deterministic functions: the renderer's antialiasing comes from supersampling, not from the textures.

* :class:`NoiseTexture`: band-limited procedural noise (seeded), several octaves; its feature size can be
  chosen from the depth it will be seen at (:func:`feature_size_for_depth`) so any depth stays matchable.
* :class:`ImageTexture`: a photograph (bilinear sampling) stretched over a rectangle of the surface.
* :class:`CheckerTexture`, :class:`CircleGridTexture`: calibration targets with a white border.
"""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import torch
import torch.nn.functional as F

from prismstereo.errors import PrismStereoError, check_shape
from prismstereo.geometry.rig import BiPrismRig

__all__ = [
    "Texture",
    "SceneError",
    "NoiseTexture",
    "ImageTexture",
    "CheckerTexture",
    "CircleGridTexture",
    "ConstantTexture",
    "feature_size_for_depth",
]


class SceneError(PrismStereoError, ValueError):
    """An invalid scene or texture (bad sizes, surfaces behind the prism, empty images...)."""


@runtime_checkable
class Texture(Protocol):
    """Anything with ``channels`` and ``sample(coords (N, 2) mm) -> (N, channels)`` in [0, 1]."""

    channels: int

    def sample(self, coords: torch.Tensor) -> torch.Tensor:  # pragma: no cover - protocol
        ...


def feature_size_for_depth(rig: BiPrismRig, depth_mm: float, pixels: float = 3.0) -> float:
    """Texture feature size (mm) that appears ``pixels`` px wide at ``depth_mm`` through the rig.

    s = pixels * Z * pixel_size / f (pinhole magnification; the prism changes it by < 1 %).

    Example:
        >>> round(feature_size_for_depth(thesis_setup1(), 525.0), 4)
        0.2929
    """
    if depth_mm <= 0 or pixels <= 0:
        raise SceneError(f"depth_mm and pixels must be positive, got {depth_mm}, {pixels}")
    return pixels * depth_mm * rig.pixel_size_mm / rig.focal_length_mm


class ConstantTexture:
    """A uniform colour.

    Example:
        >>> ConstantTexture(0.5).sample(torch.zeros(4, 2)).shape
        torch.Size([4, 1])
    """

    def __init__(self, value: float | tuple[float, ...] = 0.5) -> None:
        values = (value,) if isinstance(value, (int, float)) else tuple(value)
        if not values or not all(0.0 <= v <= 1.0 for v in values):
            raise SceneError(f"constant texture values must be in [0, 1], got {value!r}")
        self.values = values
        self.channels = len(values)

    def sample(self, coords: torch.Tensor) -> torch.Tensor:
        return torch.tensor(self.values, dtype=coords.dtype, device=coords.device).expand(coords.shape[0], -1)


class NoiseTexture:
    """Seeded band-limited noise: a sum of octaves of smoothed random lattices, sampled bicubically.

    Octave k has lattice cell ``feature_mm * 2**k`` and weight ``0.5**k``; each lattice is white noise
    smoothed by a Gaussian of one cell and tiled with period ``lattice * cell``. Values are
    0.5 + contrast * (normalised sum), clamped to [0, 1].

    Args:
        feature_mm: finest feature (lattice cell) size in mm; see :func:`feature_size_for_depth`.
        seed: random seed (same seed, same texture).
        channels: 1 (grey) or 3 (independent RGB channels).
        octaves: number of octaves (>= 1).
        contrast: standard deviation of the intensity around 0.5.
        lattice: lattice size (period in cells).

    Example:
        >>> tex = NoiseTexture(0.3, seed=1)
        >>> tex.sample(torch.rand(5, 2)).shape
        torch.Size([5, 1])
    """

    def __init__(
        self, feature_mm: float, seed: int = 0, channels: int = 1, octaves: int = 3, contrast: float = 0.18,
        lattice: int = 512,
    ) -> None:
        if not feature_mm > 0 or not math.isfinite(feature_mm):
            raise SceneError(f"feature_mm must be positive, got {feature_mm}")
        if channels not in (1, 3):
            raise SceneError(f"channels must be 1 or 3, got {channels}")
        if octaves < 1 or lattice < 8 or not 0 < contrast <= 0.5:
            raise SceneError(
                f"need octaves >= 1, lattice >= 8, contrast in (0, 0.5]; got {octaves}, {lattice}, {contrast}"
            )
        self.feature_mm, self.seed, self.channels = float(feature_mm), int(seed), channels
        self.octaves, self.contrast, self.lattice = octaves, float(contrast), lattice
        gen = torch.Generator().manual_seed(self.seed)
        kernel = torch.exp(-0.5 * torch.arange(-3, 4, dtype=torch.float64).square())
        kernel = (kernel / kernel.sum()).to(torch.float32)
        grids = []
        for _ in range(octaves):
            g = torch.randn(1, channels, lattice, lattice, generator=gen)
            g = F.pad(g, (3, 3, 3, 3), mode="circular")
            g = F.conv2d(g, kernel.view(1, 1, 1, 7).expand(channels, 1, 1, 7), groups=channels)
            g = F.conv2d(g, kernel.view(1, 1, 7, 1).expand(channels, 1, 7, 1), groups=channels)
            g = g / g.std()
            grids.append(F.pad(g, (2, 2, 2, 2), mode="circular"))  # margin for bicubic taps across the seam
        self._grids = grids
        self._norm = math.sqrt(sum(0.25**k for k in range(octaves)))

    def sample(self, coords: torch.Tensor) -> torch.Tensor:
        check_shape(coords, ["N", 2], "coords")
        total = torch.zeros(coords.shape[0], self.channels, dtype=torch.float32, device=coords.device)
        for k, grid in enumerate(self._grids):
            cell = self.feature_mm * 2**k
            # lattice coordinates, wrapped to [0, L), then into the padded grid's normalised frame
            q = torch.remainder(coords.to(torch.float64) / cell, self.lattice) + 2.0
            size = self.lattice + 4
            norm = (2.0 * q + 1.0) / size - 1.0  # align_corners=False: texel i's centre is at i
            out = F.grid_sample(grid.to(coords.device), norm.to(torch.float32).view(1, 1, -1, 2), mode="bicubic",
                                align_corners=False)
            total += 0.5**k * out.view(self.channels, -1).T
        return (0.5 + self.contrast * total / self._norm).clamp(0.0, 1.0).to(coords.dtype)


class ImageTexture:
    """A picture stretched over the rectangle [0, width_mm] x [0, height_mm] of surface coordinates.

    Image pixel (i, j) (row, column) has its centre at s = (j + 0.5) * width_mm / w,
    t = (i + 0.5) * height_mm / h; sampling is bilinear, with the border colour repeated outside.

    Args:
        image: (C, h, w) or (h, w) float tensor in [0, 1] (C = 1 or 3).
        width_mm: physical width of the picture.
        height_mm: physical height, default keeps square texels.

    Example:
        >>> tex = ImageTexture(torch.rand(3, 20, 30), width_mm=60.0)
        >>> tex.sample(torch.tensor([[30.0, 20.0]])).shape
        torch.Size([1, 3])
    """

    def __init__(self, image: torch.Tensor, width_mm: float, height_mm: float | None = None) -> None:
        if not isinstance(image, torch.Tensor) or image.dim() not in (2, 3):
            raise SceneError("image must be a (C, h, w) or (h, w) tensor")
        if image.dim() == 2:
            image = image[None]
        if image.shape[0] not in (1, 3) or image.numel() == 0:
            raise SceneError(f"image must be non-empty with 1 or 3 channels, got shape {tuple(image.shape)}")
        if not torch.is_floating_point(image) or image.min() < 0 or image.max() > 1:
            raise SceneError("image must be a floating-point tensor with values in [0, 1]")
        h, w = image.shape[1:]
        if height_mm is None:
            height_mm = width_mm * h / w
        if not (width_mm > 0 and height_mm > 0):
            raise SceneError(f"texture size must be positive, got {width_mm} x {height_mm} mm")
        self.image = image.to(torch.float32)
        self.channels = image.shape[0]
        self.width_mm, self.height_mm = float(width_mm), float(height_mm)

    def sample(self, coords: torch.Tensor) -> torch.Tensor:
        check_shape(coords, ["N", 2], "coords")
        norm = torch.stack([2.0 * coords[:, 0] / self.width_mm - 1.0, 2.0 * coords[:, 1] / self.height_mm - 1.0], -1)
        out = F.grid_sample(self.image[None].to(coords.device), norm.to(torch.float32).view(1, 1, -1, 2),
                            mode="bilinear", padding_mode="border", align_corners=False)
        return out.view(self.channels, -1).T.to(coords.dtype)


class CheckerTexture:
    """A checkerboard of ``rows`` x ``cols`` squares starting black at (0, 0), on a white board.

    The squares cover [0, cols * square_mm] x [0, rows * square_mm]; everything else is white (the
    board's margin, its size set by the surface's extent). Inner corners are at multiples of square_mm.

    Example:
        >>> CheckerTexture(rows=7, cols=10, square_mm=20.0).sample(torch.tensor([[5.0, 5.0], [25.0, 5.0]]))
        tensor([[0.],
                [1.]])
    """

    def __init__(self, rows: int, cols: int, square_mm: float, dark: float = 0.0, light: float = 1.0) -> None:
        if rows < 2 or cols < 2 or not square_mm > 0:
            raise SceneError(f"a checkerboard needs rows, cols >= 2 and square_mm > 0; got {rows}, {cols}, {square_mm}")
        self.rows, self.cols, self.square_mm, self.dark, self.light = rows, cols, float(square_mm), dark, light
        self.channels = 1

    def sample(self, coords: torch.Tensor) -> torch.Tensor:
        check_shape(coords, ["N", 2], "coords")
        i = torch.floor(coords / self.square_mm)
        inside = (i[:, 0] >= 0) & (i[:, 0] < self.cols) & (i[:, 1] >= 0) & (i[:, 1] < self.rows)
        black = inside & (torch.remainder(i[:, 0] + i[:, 1], 2) == 0)
        return torch.where(black, self.dark, self.light).to(coords.dtype)[:, None]


class CircleGridTexture:
    """Black circles of ``radius_mm`` on a ``rows`` x ``cols`` grid with pitch ``spacing_mm``, on white.

    Circle (r, c) is centred at ((c + 0.5) * spacing_mm, (r + 0.5) * spacing_mm) (a symmetric grid).

    Example:
        >>> CircleGridTexture(4, 5, spacing_mm=20.0, radius_mm=5.0).sample(torch.tensor([[10.0, 10.0], [0.0, 0.0]]))
        tensor([[0.],
                [1.]])
    """

    def __init__(self, rows: int, cols: int, spacing_mm: float, radius_mm: float) -> None:
        if rows < 2 or cols < 2 or not 0 < radius_mm < spacing_mm / 2:
            raise SceneError(
                f"a circle grid needs rows, cols >= 2 and 0 < radius < spacing / 2; got {rows}, {cols}, "
                f"{radius_mm}, {spacing_mm}"
            )
        self.rows, self.cols, self.spacing_mm, self.radius_mm = rows, cols, float(spacing_mm), float(radius_mm)
        self.channels = 1

    def sample(self, coords: torch.Tensor) -> torch.Tensor:
        check_shape(coords, ["N", 2], "coords")
        cell = torch.floor(coords / self.spacing_mm)
        inside = (cell[:, 0] >= 0) & (cell[:, 0] < self.cols) & (cell[:, 1] >= 0) & (cell[:, 1] < self.rows)
        offset = coords - (cell + 0.5) * self.spacing_mm
        dark = inside & (offset.norm(dim=-1) <= self.radius_mm)
        return torch.where(dark, 0.0, 1.0).to(coords.dtype)[:, None]
