"""Photographs with their depth as scenes: a picture laid over a depth map in front of the prism.

:class:`HeightField` is the surface Z = depth(x, y) over a rectangle of the camera frame (x-y), textured with the
picture pixel-aligned; rays are marched in depth and the first crossing refined by bisection, so occlusions between
the picture's own surfaces are exact up to the march's step. :func:`height_field_scene` stands a picture with its
depth map in front of the camera, :func:`disparity_scene` one with a stereo disparity map (1/Z linear in
disparity), and :func:`middlebury_scene` a Middlebury pair's left image with its true disparities: real textures
and real depth structure, rendered with exact ground truth. :class:`~prismstereo.synthetic.scenes.Scene` and the
surfaces of the geometric test scenes are in :mod:`prismstereo.synthetic.scenes`; frames and units as there (camera
frame, mm).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from prismstereo.synthetic.scenes import Hit, Scene, Surface, _check_texture, _positive_depth
from prismstereo.synthetic.textures import ImageTexture, SceneError, Texture

__all__ = ["HeightField", "height_field_scene", "disparity_scene", "middlebury_scene"]

F64 = torch.float64


class HeightField(Surface):
    """A surface Z = depth(x, y) over the rectangle [x0, x1] x [y0, y1] of the camera frame.

    ``depth`` (h, w) in mm is sampled bilinearly with texel (i, j) centred at
    (x0 + (j + 0.5) (x1 - x0) / w, y0 + (i + 0.5) (y1 - y0) / h). Surface coordinates are (x - x0, y - y0),
    so an :class:`ImageTexture` of width x1 - x0 lays a picture pixel-aligned over the depth map. Rays are
    marched in Z with steps shorter than half a texel laterally, then the first crossing is refined by 30
    bisections; occluding edges are the interpolated (steep) surface between texels, features thinner than
    a march step can be missed.

    Example:
        >>> from prismstereo.synthetic.textures import NoiseTexture
        >>> hf = HeightField(torch.full((4, 4), 600.0), NoiseTexture(0.3), (-50.0, 50.0), (-50.0, 50.0))
        >>> o, d = torch.zeros(1, 3, dtype=torch.float64), torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
        >>> hf.intersect(o, d).t
        tensor([600.], dtype=torch.float64)
    """

    def __init__(
        self, depth: torch.Tensor, texture: Texture, x_range: tuple[float, float], y_range: tuple[float, float]
    ) -> None:
        if not isinstance(depth, torch.Tensor) or depth.dim() != 2 or min(depth.shape) < 2:
            raise SceneError("depth must be a (h, w) tensor with h, w >= 2")
        if not torch.isfinite(depth).all() or depth.min() <= 0:
            raise SceneError("depth must be finite and positive everywhere (fill holes first)")
        if not (x_range[0] < x_range[1] and y_range[0] < y_range[1]):
            raise SceneError(f"x_range and y_range must be increasing, got {x_range}, {y_range}")
        self.depth = depth.to(F64)
        self.x_range, self.y_range = (float(x_range[0]), float(x_range[1])), (float(y_range[0]), float(y_range[1]))
        self.texture = _check_texture(texture)
        h, w = depth.shape
        self.texel_mm = min((x_range[1] - x_range[0]) / w, (y_range[1] - y_range[0]) / h)
        self.z_min, self.z_max = float(self.depth.min()), float(self.depth.max())

    def nearest_depth(self) -> float:
        return self.z_min

    def _depth_at(self, xy: torch.Tensor) -> torch.Tensor:
        """Bilinear depth at (M, 2) points, +inf outside the rectangle."""
        (x0, x1), (y0, y1) = self.x_range, self.y_range
        gx = 2.0 * (xy[:, 0] - x0) / (x1 - x0) - 1.0
        gy = 2.0 * (xy[:, 1] - y0) / (y1 - y0) - 1.0
        z = F.grid_sample(self.depth[None, None].to(xy), torch.stack([gx, gy], -1).view(1, 1, -1, 2),
                          mode="bilinear", padding_mode="border", align_corners=False).view(-1)
        inside = (gx >= -1) & (gx <= 1) & (gy >= -1) & (gy <= 1)
        return torch.where(inside, z, torch.full_like(z, math.inf))

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
        n = origins.shape[0]
        slope = (directions[:, :2] / directions[:, 2:3]).norm(dim=-1).max().item() if n else 0.0
        span = self.z_max - self.z_min
        steps = int(min(4096, max(16, math.ceil(span * slope / (0.5 * self.texel_mm)) + 2)))
        z_lo = torch.full((n,), self.z_min - 1e-6, dtype=origins.dtype)
        z_lo = torch.maximum(z_lo, origins[:, 2] + 1e-9)
        hit_t = torch.full((n,), math.inf, dtype=origins.dtype)
        lo = z_lo.clone()
        hi = torch.zeros_like(z_lo)
        found = torch.zeros(n, dtype=torch.bool)
        zs = torch.linspace(0.0, 1.0, steps, dtype=origins.dtype)
        rows = max(1, (1 << 22) // steps)
        for start in range(0, n, rows):
            sl = slice(start, start + rows)
            o, d = origins[sl], directions[sl]
            z = z_lo[sl, None] + zs[None] * (self.z_max + 1e-6 - z_lo[sl, None])  # (m, K)
            s = (z - o[:, 2:3]) / d[:, 2:3]
            xy = o[:, None, :2] + s[..., None] * d[:, None, :2]
            g = z - self._depth_at(xy.reshape(-1, 2)).view(z.shape)  # >= 0: at or behind the surface
            behind = g >= 0
            first = torch.argmax(behind.to(torch.int8), dim=1)
            any_hit = behind.any(dim=1)
            k = first.clamp_min(1)
            lo[sl] = torch.gather(z, 1, (k - 1)[:, None]).squeeze(1)
            hi[sl] = torch.gather(z, 1, k[:, None]).squeeze(1)
            found[sl] = any_hit & (first > 0)
        for _ in range(30):  # bisection on the bracket [lo, hi] of the first crossing
            mid = 0.5 * (lo + hi)
            s = (mid - origins[:, 2]) / directions[:, 2]
            xy = origins[:, :2] + s[:, None] * directions[:, :2]
            behind = mid - self._depth_at(xy) >= 0
            hi = torch.where(behind, mid, hi)
            lo = torch.where(behind, lo, mid)
        z = hi
        t = (z - origins[:, 2]) / directions[:, 2]
        pts = origins + t[:, None] * directions
        pts = torch.cat([pts[:, :2], z[:, None]], dim=-1)
        hit_t = torch.where(found, t, hit_t)
        coords = torch.stack([pts[:, 0] - self.x_range[0], pts[:, 1] - self.y_range[0]], dim=-1)
        return Hit(hit_t, pts, coords)



def height_field_scene(
    depth_mm: torch.Tensor, image: torch.Tensor, width_mm: float, centre_xy_mm: tuple[float, float] = (0.0, 0.0),
    name: str = "heightfield",
) -> Scene:
    """A photograph with its depth map, standing in front of the camera (x-y centred at ``centre_xy_mm``).

    Args:
        depth_mm: (h, w) depth in mm (finite, positive).
        image: (C, h, w) or (h, w) picture in [0, 1], pixel-aligned with ``depth_mm``.
        width_mm: physical width of the picture; its height keeps square texels.

    Example:
        >>> scene = height_field_scene(torch.full((30, 40), 600.0), torch.rand(30, 40), width_mm=200.0)
        >>> scene.surfaces[0].y_range
        (-75.0, 75.0)
    """
    if not isinstance(image, torch.Tensor) or image.shape[-2:] != depth_mm.shape[-2:]:
        raise SceneError("image and depth_mm must have the same (h, w)")
    h, w = depth_mm.shape
    height_mm = width_mm * h / w
    cx, cy = centre_xy_mm
    texture = ImageTexture(image, width_mm, height_mm)
    x_range, y_range = (cx - width_mm / 2, cx + width_mm / 2), (cy - height_mm / 2, cy + height_mm / 2)
    field = HeightField(depth_mm, texture, x_range, y_range)
    return Scene([field], name=name)


def disparity_scene(
    picture: torch.Tensor, disparity: torch.Tensor, near_mm: float = 450.0, far_mm: float = 700.0,
    width_mm: float | None = None, name: str = "disparity",
) -> Scene:
    """A stereo photograph placed in front of the prism with the depth structure of its disparity map.

    Disparity is mapped to depth as a real stereo camera does, 1/Z linear in disparity, with the largest
    disparity at ``near_mm`` and the smallest at ``far_mm``; pixels without a disparity (not finite or <= 0) are
    filled by inpainting (OpenCV's Telea). ``width_mm`` defaults to the width that fills the sensor at ``far_mm``
    for a 25 mm lens and a 4.76 mm sensor (190 mm at 1 m).

    Args:
        picture: (C, h, w) or (h, w) photograph in [0, 1].
        disparity: (h, w) its disparity map (any positive unit; invalid entries not finite or <= 0).
        near_mm, far_mm: depths of the largest and smallest disparity.
        width_mm: physical width of the picture.
        name: the scene's name.

    Raises:
        SceneError: bad depths, sizes that differ, fewer than 16 pixels with a disparity.

    Example:
        >>> disparity = torch.linspace(10.0, 20.0, 40).expand(30, 40)
        >>> field = disparity_scene(torch.rand(30, 40), disparity, 450.0, 700.0).surfaces[0]
        >>> round(field.z_min, 1), round(field.z_max, 1)
        (450.0, 700.0)
    """
    near_mm, far_mm = _positive_depth(near_mm, "near_mm"), _positive_depth(far_mm, "far_mm")
    if not near_mm < far_mm:
        raise SceneError(f"near_mm must be smaller than far_mm, got {near_mm}, {far_mm}")
    if not (isinstance(picture, torch.Tensor) and isinstance(disparity, torch.Tensor)) or disparity.dim() != 2 or (
            picture.shape[-2:] != disparity.shape):
        got = [tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__ for t in (picture, disparity)]
        raise SceneError(f"picture and disparity must be tensors, disparity (h, w) of the picture's size, got {got}")
    disp = disparity.detach().cpu().numpy().astype(np.float32)
    known = np.isfinite(disp) & (disp > 0)
    if known.sum() < 16:
        raise SceneError("the disparity map has no usable values (fewer than 16 finite, positive)")
    d_min, d_max = float(disp[known].min()), float(disp[known].max())
    inv = 1.0 / far_mm + (np.where(known, disp, d_min) - d_min) / max(d_max - d_min, 1e-6) * (
        1.0 / near_mm - 1.0 / far_mm)
    depth = np.where(known, 1.0 / np.maximum(inv, 1e-9), 0.0).astype(np.float32)
    depth = cv2.inpaint(depth, (~known).astype(np.uint8), 5, cv2.INPAINT_TELEA)
    depth = np.clip(depth, near_mm, far_mm)
    if width_mm is None:
        width_mm = far_mm * 4.7616 / 25.0
    return height_field_scene(torch.from_numpy(depth), picture, width_mm, name=name)


def middlebury_scene(
    folder: str | Path, near_mm: float = 450.0, far_mm: float = 700.0, width_mm: float | None = None,
    scale: float | None = None, channels: int = 1,
) -> Scene:
    """A Middlebury pair's left photograph placed in front of the prism with its true depth structure
    (:func:`disparity_scene`: 1/Z linear in disparity from ``far_mm`` to ``near_mm``, pixels without ground truth
    inpainted). ``scale`` divides the stored disparity (16 for Tsukuba's .pgm, 8 for Venus' .png by default, from
    the folder's README); the depths do not depend on it, since the map's own smallest and largest disparities are
    placed at ``far_mm`` and ``near_mm``.

    Example:
        >>> scene = middlebury_scene("../shared/data/middlebury/Tsukuba")  # doctest: +SKIP
    """
    folder = Path(folder)
    img_path = folder / "img_left.png"
    disp_path = next((p for p in (folder / "disp_gt.pgm", folder / "disp_gt.png") if p.exists()), None)
    if not img_path.exists() or disp_path is None:
        raise SceneError(f"{folder} must hold img_left.png and disp_gt.pgm or disp_gt.png")
    flag = cv2.IMREAD_COLOR if channels == 3 else cv2.IMREAD_GRAYSCALE
    img = cv2.imread(str(img_path), flag)
    disp = cv2.imread(str(disp_path), cv2.IMREAD_UNCHANGED).astype(np.float32)
    if scale is None:
        scale = 16.0 if disp_path.suffix == ".pgm" else 8.0
    picture = torch.from_numpy(img).float() / 255.0
    picture = picture.permute(2, 0, 1).flip(0) if picture.dim() == 3 else picture  # BGR -> RGB
    return disparity_scene(picture, torch.from_numpy(disp / scale), near_mm, far_mm, width_mm,
                           name=f"middlebury_{folder.name.lower()}")
