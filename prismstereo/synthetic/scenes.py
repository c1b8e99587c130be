"""Scenes for the synthetic renderer: textured surfaces with exact ray intersection.

All geometry is in the camera frame (mm), see :mod:`prismstereo.conventions`. A :class:`Scene` is a list of
surfaces (nearest hit wins, so occlusion is exact) and a background intensity for rays that hit nothing.
Every surface defines surface coordinates (s, t) in mm at which its texture is sampled.

Surfaces: :class:`Plane` (optionally bounded: targets, half-planes for steps) and :class:`Sphere`; factories build
the geometric scenes of the test plan: :func:`fronto_parallel_plane`, :func:`slanted_plane`, :func:`step_scene`,
:func:`sphere_scene`. Photographs with their depth (a height field) are in
:mod:`prismstereo.synthetic.photo_scenes`, calibration boards in :mod:`prismstereo.synthetic.targets`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import torch

from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.surfaces import euler_rotation
from prismstereo.synthetic.textures import (
    NoiseTexture,
    SceneError,
    Texture,
    feature_size_for_depth,
)

__all__ = [
    "Hit",
    "Surface",
    "Plane",
    "Sphere",
    "Scene",
    "fronto_parallel_plane",
    "slanted_plane",
    "step_scene",
    "sphere_scene",
    "vector3",
]

F64 = torch.float64


class Hit(NamedTuple):
    """Ray-surface intersections of N rays.

    Attributes:
        t: (N,) distance along the (unit) ray, ``inf`` where the ray misses.
        points: (N, 3) hit points (meaningless where t is inf).
        coords: (N, 2) surface coordinates (mm) for texturing.
    """

    t: torch.Tensor
    points: torch.Tensor
    coords: torch.Tensor


def vector3(value: Sequence[float], name: str) -> torch.Tensor:
    """``value`` as a (3,) float64 tensor; :class:`SceneError` naming ``name`` unless it is 3 finite numbers.

    Example:
        >>> vector3([0, 0, 600], "centre")
        tensor([  0.,   0., 600.], dtype=torch.float64)
    """
    t = torch.as_tensor(value, dtype=F64).flatten()
    if t.numel() != 3 or not torch.isfinite(t).all():
        raise SceneError(f"{name} must be 3 finite numbers, got {value!r}")
    return t


def _check_texture(texture: Texture) -> Texture:
    if not isinstance(texture, Texture):
        raise SceneError(f"texture must have .channels and .sample(coords), got {type(texture).__name__}")
    return texture


class Surface:
    """Base class: a textured surface with ``intersect(origins, directions) -> Hit`` and a nearest depth."""

    texture: Texture

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> Hit:  # pragma: no cover
        raise NotImplementedError

    def nearest_depth(self) -> float:  # pragma: no cover
        """The smallest Z the renderer checks against the prism's back plane."""
        raise NotImplementedError


class Plane(Surface):
    """A plane through ``point`` with unit ``normal``, optionally bounded in its own coordinates.

    Surface coordinates: s = (p - point) . u_axis, t = (p - point) . v_axis with v_axis = normal x u_axis;
    u_axis defaults to the camera x axis made orthogonal to the normal. ``bounds_mm`` = (s_min, s_max,
    t_min, t_max) (infinite by default) crops the plane. Hit points are projected back onto the plane, so a
    fronto-parallel plane's hits have Z exactly equal to its depth.

    Example:
        >>> plane = Plane((0.0, 0.0, 500.0), (0.0, 0.0, 1.0), NoiseTexture(0.3))
        >>> o, d = torch.zeros(1, 3, dtype=torch.float64), torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
        >>> plane.intersect(o, d).t
        tensor([500.], dtype=torch.float64)
    """

    def __init__(
        self,
        point: Sequence[float],
        normal: Sequence[float],
        texture: Texture,
        u_axis: Sequence[float] | None = None,
        bounds_mm: tuple[float, float, float, float] | None = None,
    ) -> None:
        self.point = vector3(point, "point")
        n = vector3(normal, "normal")
        if n.norm() < 1e-12:
            raise SceneError("normal must be non-zero")
        self.normal = n / n.norm()
        u = vector3(u_axis, "u_axis") if u_axis is not None else torch.tensor([1.0, 0.0, 0.0], dtype=F64)
        u = u - (u @ self.normal) * self.normal
        if u.norm() < 1e-9:
            raise SceneError("u_axis must not be parallel to the normal")
        self.u_axis = u / u.norm()
        self.v_axis = torch.linalg.cross(self.normal, self.u_axis)
        if bounds_mm is not None and not (bounds_mm[0] < bounds_mm[1] and bounds_mm[2] < bounds_mm[3]):
            raise SceneError(f"bounds_mm must be (s_min, s_max, t_min, t_max) with min < max, got {bounds_mm}")
        self.bounds_mm = bounds_mm
        self.texture = _check_texture(texture)

    def nearest_depth(self) -> float:
        return float(self.point[2])

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
        n, p0 = self.normal.to(origins), self.point.to(origins)
        den = directions @ n
        safe = torch.where(den.abs() > 1e-12, den, torch.ones_like(den))
        t = ((p0 - origins) @ n) / safe
        pts = origins + t.unsqueeze(-1) * directions
        pts = pts - ((pts - p0) @ n).unsqueeze(-1) * n  # back onto the plane (exact Z for fronto-parallel)
        rel = pts - p0
        coords = torch.stack([rel @ self.u_axis.to(origins), rel @ self.v_axis.to(origins)], dim=-1)
        ok = (den.abs() > 1e-12) & (t > 0)
        if self.bounds_mm is not None:
            s0, s1, t0, t1 = self.bounds_mm
            ok = ok & (coords[:, 0] >= s0) & (coords[:, 0] <= s1) & (coords[:, 1] >= t0) & (coords[:, 1] <= t1)
        return Hit(torch.where(ok, t, torch.full_like(t, math.inf)), pts, coords)


class Sphere(Surface):
    """A sphere; surface coordinates are arc lengths (mm): s = r atan2(x, -z) around y, t = r asin(y / r).

    Example:
        >>> ball = Sphere((0.0, 0.0, 500.0), 50.0, NoiseTexture(0.3))
        >>> o, d = torch.zeros(1, 3, dtype=torch.float64), torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
        >>> ball.intersect(o, d).t
        tensor([450.], dtype=torch.float64)
    """

    def __init__(self, centre: Sequence[float], radius_mm: float, texture: Texture) -> None:
        self.centre = vector3(centre, "centre")
        if not radius_mm > 0:
            raise SceneError(f"radius_mm must be positive, got {radius_mm}")
        self.radius = float(radius_mm)
        self.texture = _check_texture(texture)

    def nearest_depth(self) -> float:
        return float(self.centre[2]) - self.radius

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> Hit:
        rel = origins - self.centre.to(origins)
        b = (rel * directions).sum(-1)
        c = rel.square().sum(-1) - self.radius**2
        disc = b * b - c
        t = -b - torch.sqrt(disc.clamp_min(0.0))
        ok = (disc >= 0) & (t > 0)
        pts = origins + t.unsqueeze(-1) * directions
        local = pts - self.centre.to(origins)
        coords = torch.stack(
            [self.radius * torch.atan2(local[:, 0], -local[:, 2]),
             self.radius * torch.asin((local[:, 1] / self.radius).clamp(-1.0, 1.0))], dim=-1
        )
        return Hit(torch.where(ok, t, torch.full_like(t, math.inf)), pts, coords)


class Scene:
    """Surfaces (nearest hit wins) and a background intensity for rays that hit nothing.

    Args:
        surfaces: one or more :class:`Surface`.
        background: intensity (or RGB) of rays that hit nothing, in [0, 1].
        name: a label (used in file names and notebooks).

    Example:
        >>> scene = fronto_parallel_plane(thesis_setup1(), 525.0)
        >>> scene.name
        'plane_525mm'
    """

    def __init__(self, surfaces: Sequence[Surface], background: float = 0.0, name: str = "scene") -> None:
        surfaces = tuple(surfaces)
        if not surfaces or not all(isinstance(s, Surface) for s in surfaces):
            raise SceneError("a scene needs at least one Surface")
        if not 0.0 <= background <= 1.0:
            raise SceneError(f"background must be in [0, 1], got {background}")
        self.surfaces, self.background, self.name = surfaces, float(background), name

    @property
    def channels(self) -> int:
        """1 if every texture is grey, else 3."""
        return 3 if any(s.texture.channels == 3 for s in self.surfaces) else 1

    def validate(self, rig: BiPrismRig) -> None:
        """Raise :class:`SceneError` if a surface starts at or before the prism's back plane."""
        back = rig.apex_distance_mm + rig.prism_thickness_mm
        for surface in self.surfaces:
            z = surface.nearest_depth()
            if z <= back:
                raise SceneError(
                    f"{type(surface).__name__} of scene {self.name!r} reaches Z = {z:.1f} mm, not beyond the prism's "
                    f"back plane at {back:.1f} mm: move it further away"
                )

    def intersect(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[Hit, torch.Tensor]:
        """Nearest hit over all surfaces; returns (Hit, index (N,) of the surface hit, -1 for none)."""
        best = Hit(torch.full(origins.shape[:1], math.inf, dtype=origins.dtype), torch.zeros_like(origins),
                   torch.zeros(origins.shape[0], 2, dtype=origins.dtype))
        index = torch.full(origins.shape[:1], -1, dtype=torch.long)
        for i, surface in enumerate(self.surfaces):
            hit = surface.intersect(origins, directions)
            closer = hit.t < best.t
            best = Hit(torch.where(closer, hit.t, best.t), torch.where(closer[:, None], hit.points, best.points),
                       torch.where(closer[:, None], hit.coords, best.coords))
            index = torch.where(closer, torch.full_like(index, i), index)
        return best, index

    def shade(self, hit: Hit, index: torch.Tensor, channels: int) -> torch.Tensor:
        """(N, channels) intensities: each surface's texture at its hits, background elsewhere; a grey texture
        is repeated into RGB, an RGB texture seen in grey is its channel mean."""
        out = torch.full((index.shape[0], channels), self.background, dtype=torch.float32)
        for i, surface in enumerate(self.surfaces):
            mask = index == i
            if mask.any():
                values = surface.texture.sample(hit.coords[mask]).to(torch.float32)
                if values.shape[1] != channels:  # grey -> RGB: repeated; RGB -> grey: the channel mean
                    values = values.expand(-1, channels) if values.shape[1] == 1 else values.mean(1, keepdim=True)
                out[mask] = values
        return out


# ----------------------------------------------------------------------------------- factories
def _noise(rig: BiPrismRig, depth_mm: float, seed: int, channels: int, texel_px: float) -> NoiseTexture:
    return NoiseTexture(feature_size_for_depth(rig, depth_mm, texel_px), seed=seed, channels=channels)


def _positive_depth(depth_mm: float, name: str = "depth_mm") -> float:
    if not math.isfinite(depth_mm) or depth_mm <= 0:
        raise SceneError(f"{name} must be a positive depth in mm, got {depth_mm}")
    return float(depth_mm)


def fronto_parallel_plane(
    rig: BiPrismRig, depth_mm: float, seed: int = 0, channels: int = 1, texel_px: float = 3.0
) -> Scene:
    """An infinite textured plane Z = depth_mm, noise features ``texel_px`` px wide at that depth.

    Example:
        >>> fronto_parallel_plane(thesis_setup1(), 525.0).surfaces[0].point
        tensor([  0.,   0., 525.], dtype=torch.float64)
    """
    depth_mm = _positive_depth(depth_mm)
    plane = Plane((0.0, 0.0, depth_mm), (0.0, 0.0, 1.0), _noise(rig, depth_mm, seed, channels, texel_px))
    return Scene([plane], name=f"plane_{depth_mm:g}mm")


def slanted_plane(
    rig: BiPrismRig, depth_mm: float, slant_deg: float = 30.0, tilt_deg: float = 0.0, seed: int = 0,
    channels: int = 1, texel_px: float = 3.0,
) -> Scene:
    """A plane through (0, 0, depth_mm) rotated ``slant_deg`` about y (depth grows with x) and ``tilt_deg``
    about x (depth grows with y).

    Example:
        >>> slanted_plane(thesis_setup1(), 600.0, slant_deg=20.0).name
        'slanted_600mm_20deg'
    """
    depth_mm = _positive_depth(depth_mm)
    if not (abs(slant_deg) < 80 and abs(tilt_deg) < 80):
        raise SceneError(f"slant_deg and tilt_deg must be within +-80 degrees, got {slant_deg}, {tilt_deg}")
    rot = euler_rotation(torch.tensor([math.radians(tilt_deg), -math.radians(slant_deg), 0.0], dtype=F64))
    plane = Plane((0.0, 0.0, depth_mm), rot[:, 2].tolist(), _noise(rig, depth_mm, seed, channels, texel_px),
                  u_axis=rot[:, 0].tolist())
    return Scene([plane], name=f"slanted_{depth_mm:g}mm_{slant_deg:g}deg")


def step_scene(
    rig: BiPrismRig, near_mm: float, far_mm: float, edge_x_mm: float = 0.0, near_side: str = "right", seed: int = 0,
    channels: int = 1, texel_px: float = 3.0,
) -> Scene:
    """A depth step: a near half-plane in front of an infinite far plane, with occlusions.

    ``near_side`` 'right' puts the near plane at x > edge_x_mm: then far-plane points just left of the
    edge are seen by the left (reference) half but hidden from the right half by the near plane, the
    occlusion a left-right check must catch. 'left' (x < edge_x_mm) hides points from the left half only.

    Example:
        >>> len(step_scene(thesis_setup1(), 400.0, 600.0).surfaces)
        2
    """
    near_mm, far_mm = _positive_depth(near_mm, "near_mm"), _positive_depth(far_mm, "far_mm")
    if not near_mm < far_mm:
        raise SceneError(f"near_mm must be smaller than far_mm, got {near_mm}, {far_mm}")
    if near_side not in ("left", "right"):
        raise SceneError(f"Unknown near_side {near_side!r}. Choose from: 'left', 'right'")
    bounds = (0.0, math.inf, -math.inf, math.inf) if near_side == "right" else (-math.inf, 0.0, -math.inf, math.inf)
    near = Plane((edge_x_mm, 0.0, near_mm), (0.0, 0.0, 1.0), _noise(rig, near_mm, seed, channels, texel_px),
                 bounds_mm=bounds)
    far = Plane((0.0, 0.0, far_mm), (0.0, 0.0, 1.0), _noise(rig, far_mm, seed + 1, channels, texel_px))
    return Scene([near, far], name=f"step_{near_mm:g}_{far_mm:g}mm")


def sphere_scene(
    rig: BiPrismRig, centre_depth_mm: float, radius_mm: float, background_depth_mm: float, seed: int = 0,
    channels: int = 1, texel_px: float = 3.0,
) -> Scene:
    """A textured sphere on the optical axis in front of a textured plane.

    Example:
        >>> sphere_scene(thesis_setup1(), 500.0, 40.0, 700.0).name
        'sphere_500mm_r40mm'
    """
    centre_depth_mm = _positive_depth(centre_depth_mm, "centre_depth_mm")
    background_depth_mm = _positive_depth(background_depth_mm, "background_depth_mm")
    if not centre_depth_mm + radius_mm < background_depth_mm:
        raise SceneError("the sphere must lie in front of the background plane")
    ball = Sphere((0.0, 0.0, centre_depth_mm), radius_mm, _noise(rig, centre_depth_mm, seed, channels, texel_px))
    back = Plane((0.0, 0.0, background_depth_mm), (0.0, 0.0, 1.0),
                 _noise(rig, background_depth_mm, seed + 1, channels, texel_px))
    return Scene([ball, back], name=f"sphere_{centre_depth_mm:g}mm_r{radius_mm:g}mm")
