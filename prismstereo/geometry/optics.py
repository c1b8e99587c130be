"""Exact ray optics of the bi-prism: pixel -> ray tracing through both faces.

This is the thesis' ray construction (eq. 3.1-3.10: camera ray R1, refracted R2 inside the glass, R3 after
the back plane) written in vector form, batched over any leading dims and differentiable w.r.t. pixels,
3D points and every rig parameter. Conventions: :mod:`prismstereo.conventions`.

The prism's planes and the refraction at them are in :mod:`prismstereo.geometry.surfaces`. A camera ray from the
origin enters where it crosses the later of the two face planes (the front surface z' = |x'| tan(alpha) is the
maximum of the two planes); the face it enters through decides its half-image: the left face (x < d at the apex
depth when untilted) is the left, reference half.

A ray is *valid* when it enters within the prism's extent, is not lost to total internal reflection at
the back plane, and leaves the glass through the back plane (not through the other face). Invalid rays
still get finite numbers (square roots are clamped) so no NaN reaches a gradient.

:func:`trace_pixels` and :func:`trace_directions` are the checked entry points (a rig or its tensors, any
dtype); :func:`trace_pixel_rays` and :func:`trace_rays`, the same tracer without checks and optionally through
a face's infinite plane, serve the solvers of :mod:`prismstereo.geometry.projection` and
:mod:`prismstereo.epipolar.sweep`.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import torch

from prismstereo.conventions import HALVES as _HALVES
from prismstereo.conventions import Half
from prismstereo.errors import RigError, check_floating, check_option, check_shape
from prismstereo.geometry.distortion import round_trip_px, undistort
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig, as_parameters
from prismstereo.geometry.surfaces import _dot, _planes, refract

__all__ = [
    "Half",
    "RayBundle",
    "pixel_directions",
    "trace_pixels",
    "trace_directions",
    "trace_pixel_rays",
    "trace_rays",
    "apex_direction",
    "apex_ray",
    "points_at_depth",
    "half_of_pixels",
    "check_rig_images",
]

_TRACE_HALVES = ("auto", "left", "right")


class RayBundle(NamedTuple):
    """Rays leaving the prism's back plane, in the camera frame.

    Attributes:
        origins: (*, 3) exit points on the back plane (mm).
        directions: (*, 3) unit directions of the outgoing rays (thesis ray R3).
        valid: (*,) bool, False for rays that miss the prism, leave through a face, or suffer total
            internal reflection.
        left: (*,) bool, True for rays through the left face (the left, reference half-image).
        entries: (*, 3) points where the camera rays enter the prism's face (thesis P', eq. 3.4).
    """

    origins: torch.Tensor
    directions: torch.Tensor
    valid: torch.Tensor
    left: torch.Tensor
    entries: torch.Tensor




def pixel_directions(rig: BiPrismRig | RigParameters, uv: torch.Tensor) -> torch.Tensor:
    """Unit directions of the real camera's rays through pixels (thesis ray R1, eq. 3.2).

    d = normalize(((u - cx) s, (v - cy) s, f)) with s the pixel size: pinhole in the camera frame. A rig with
    lens distortion first undistorts the pixel's normalised coordinates
    (:func:`~prismstereo.geometry.distortion.undistort`, OpenCV's model): d = normalize((x f, y f, f)).

    Args:
        rig: the rig.
        uv: (*, 2) pixel coordinates.

    Returns:
        (*, 3) unit directions.

    Example:
        >>> pixel_directions(thesis_setup1(), torch.tensor([[511.5, 383.5]]))
        tensor([[0., 0., 1.]])
    """
    check_shape(uv, ["*", 2], "uv")
    check_floating(uv, "uv")
    p = as_parameters(rig, uv)
    return _pixel_directions(p, uv)[0]


def _pixel_directions(p: RigParameters, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Unit camera-ray directions (*, 3) and, for a distorting lens, (*,) whether the undistortion converged to a
    true preimage (beyond the fold of a strong lens model the pixel has none: the ray is then invalid)."""
    ok = None
    if p.distortion is None:
        x = (uv[..., 0] - p.cx) * p.pixel_size
        y = (uv[..., 1] - p.cy) * p.pixel_size
    else:  # the lens' distortion undone on normalised coordinates (Newton, fixed steps)
        fpx = p.f / p.pixel_size
        xy_d = torch.stack([(uv[..., 0] - p.cx) / fpx, (uv[..., 1] - p.cy) / fpx], dim=-1)
        xy = undistort(xy_d, p.distortion)
        ok = round_trip_px(xy, xy_d, p.distortion, fpx) < (1e-6 if uv.dtype == torch.float64 else 1e-2)
        x, y = xy[..., 0] * p.f, xy[..., 1] * p.f
    d = torch.stack([x, y, p.f.expand_as(x)], dim=-1)
    return d / d.norm(dim=-1, keepdim=True), ok


def trace_pixel_rays(p: RigParameters, uv: torch.Tensor, half: str = "auto", extended: bool = False) -> RayBundle:
    """:func:`trace_pixels` without its checks: :func:`trace_rays` (same ``p``, ``half``, ``extended``) of the
    pixels' (*, 2) camera rays, invalid where the lens model has no preimage.

    Example:
        >>> uv = torch.tensor([[100.0, 300.0]], dtype=torch.float64)
        >>> trace_pixel_rays(as_parameters(thesis_setup1(), uv), uv).left
        tensor([True])
    """
    directions, ok = _pixel_directions(p, uv)
    rays = trace_rays(p, directions, half, extended)
    return rays if ok is None else rays._replace(valid=rays.valid & ok)




def trace_rays(p: RigParameters, directions: torch.Tensor, half: str = "auto", extended: bool = False) -> RayBundle:
    """Trace camera rays from the optical centre through the prism: :func:`trace_directions` on the rig's
    tensors, without argument checks.

    ``half`` 'auto' picks the face the ray really hits; 'left'/'right' force that face's plane (extended past
    the apex), and validity then also requires it to be the face the ray really hits. With ``extended`` the
    forced face is its infinite plane and none of the prism's edges count (no apex, back-plane edge or
    other-face checks): the analytic continuation through which the sweep is fitted smoothly
    (:mod:`prismstereo.epipolar.sweep`).

    Args:
        p: the rig's tensors on ``directions``' dtype and device (:func:`~prismstereo.geometry.rig.as_parameters`).
        directions: (*, 3) unit directions in the camera frame (z > 0).
        half: 'auto', 'left' or 'right'.
        extended: trace through the face's infinite plane.

    Returns:
        RayBundle with origins/directions/entries (*, 3), valid/left (*,).

    Example:
        >>> d = torch.tensor([[0.01, 0.0, 1.0]], dtype=torch.float64); d = d / d.norm(dim=-1, keepdim=True)
        >>> trace_rays(as_parameters(thesis_setup1(), d), d, "left", extended=True).valid
        tensor([True])
    """
    pl = _planes(p)
    den_l = _dot(directions, pl.n_left)
    den_r = _dot(directions, pl.n_right)
    tiny = torch.finfo(directions.dtype).tiny
    t_l = _dot(pl.n_left, pl.apex) / torch.where(den_l > 0, den_l, torch.ones_like(den_l))
    t_r = _dot(pl.n_right, pl.apex) / torch.where(den_r > 0, den_r, torch.ones_like(den_r))
    natural_left = t_l > t_r  # a ray exactly at the apex (x = d) belongs to the right half
    if half == "auto":
        use_left = natural_left
    else:
        use_left = torch.ones_like(natural_left) if half == "left" else torch.zeros_like(natural_left)
    ul = use_left.unsqueeze(-1)
    t1 = torch.where(use_left, t_l, t_r)
    n1 = torch.where(ul, pl.n_left, pl.n_right)
    n_other = torch.where(ul, pl.n_right, pl.n_left)
    p1 = t1.unsqueeze(-1) * directions  # entry point on the face (R1 meets the face, eq. 3.4)
    inside = refract(directions, -n1, 1.0 / p.n)  # R2 (eq. 3.5-3.9)
    d1 = inside.directions
    den_b = _dot(d1, pl.n_back)
    t_b = _dot(pl.n_back, pl.back - p1) / torch.where(den_b > 0, den_b, torch.ones_like(den_b))
    p2 = p1 + t_b.unsqueeze(-1) * d1  # exit point on the back plane
    out = refract(d1, -pl.n_back, p.n)  # R3 (eq. 3.10)
    # Leaving through the other face first? (the glass is convex: the first plane crossed outward wins)
    den_o = _dot(d1, n_other)
    t_o = _dot(n_other, pl.apex - p1) / torch.where(den_o < 0, den_o, -torch.ones_like(den_o))
    exits_back = (den_o >= 0) | (t_o >= t_b)
    entry_on_surface = _dot(n_other, p1 - pl.apex) >= 0  # the forced face is the one really hit
    entry_within = _dot(pl.n_back, p1 - pl.back) <= 0  # enters before the face meets the back plane
    valid = (den_l > tiny) & (den_r > tiny) & (t1 > 0) & (den_b > 0) & inside.valid & out.valid
    if extended:
        return RayBundle(p2, out.directions, valid, use_left, p1)
    valid = valid & exits_back & entry_within
    if half != "auto":
        valid = valid & entry_on_surface
    return RayBundle(p2, out.directions, valid, use_left, p1)


def trace_directions(
    rig: BiPrismRig | RigParameters, directions: torch.Tensor, half: Literal["auto", "left", "right"] = "auto"
) -> RayBundle:
    """Trace camera rays leaving the optical centre with the given directions through the prism.

    Args:
        rig: the rig (:class:`BiPrismRig` or tensors :class:`RigParameters`).
        directions: (*, 3) unit directions in the camera frame (z > 0).
        half: 'auto' uses the face each ray really hits; 'left'/'right' force that face (its plane extended
            past the apex), with ``valid`` False where the ray would really hit the other face.

    Returns:
        RayBundle with origins/directions/entries (*, 3), valid/left (*,).

    Example:
        >>> d = torch.tensor([[0.01, 0.0, 1.0]]); d = d / d.norm(dim=-1, keepdim=True)
        >>> trace_directions(thesis_setup1(), d).left
        tensor([False])
    """
    check_shape(directions, ["*", 3], "directions")
    check_floating(directions, "directions")
    check_option(half, _TRACE_HALVES, "half")
    return trace_rays(as_parameters(rig, directions), directions, half)


def trace_pixels(
    rig: BiPrismRig | RigParameters, uv: torch.Tensor, half: Literal["auto", "left", "right"] = "auto"
) -> RayBundle:
    """Trace pixels through the prism to the rays leaving its back plane (thesis R1 -> R2 -> R3).

    Args:
        rig: the rig (:class:`BiPrismRig` or tensors :class:`RigParameters`, which may require grad).
        uv: (*, 2) pixel coordinates (u, v), any leading dims, float32 or float64.
        half: see :func:`trace_directions`.

    Returns:
        RayBundle(origins (*, 3), directions (*, 3), valid (*,), left (*,), entries (*, 3)), dtype of ``uv``.

    Example:
        >>> rays = trace_pixels(thesis_setup1(), torch.tensor([[100.0, 300.0], [900.0, 300.0]]))
        >>> rays.left, rays.directions.shape
        (tensor([ True, False]), torch.Size([2, 3]))
    """
    check_shape(uv, ["*", 2], "uv")
    check_floating(uv, "uv")
    check_option(half, _TRACE_HALVES, "half")
    p = as_parameters(rig, uv)
    return trace_pixel_rays(p, uv, half)


def half_of_pixels(rig: BiPrismRig | RigParameters, uv: torch.Tensor) -> torch.Tensor:
    """True where a pixel belongs to the left (reference) half-image, i.e. its ray enters the left face.

    Args:
        rig: the rig.
        uv: (*, 2) pixel coordinates.

    Returns:
        (*,) bool.

    Example:
        >>> half_of_pixels(thesis_setup1(), torch.tensor([[511.0, 0.0], [512.0, 0.0]]))
        tensor([ True, False])
    """
    return trace_pixels(rig, uv).left


def apex_ray(rig: BiPrismRig | RigParameters, half: Half, like: torch.Tensor | None = None) -> RayBundle:
    """The central ray of a half: the camera ray through the apex point, refracted by that half's face.

    Its outgoing direction is the optical axis of the half's virtual camera (thesis sec. 3.2.2, eq.
    3.11-3.12 and, for an offset prism, eq. 5.27-5.33).

    Args:
        rig: the rig.
        half: 'left' or 'right'.
        like: tensor giving dtype/device (default float64 on CPU for a BiPrismRig, else the parameters').

    Returns:
        RayBundle with (3,) origin/direction and 0-d valid/left.

    Example:
        >>> apex_ray(thesis_setup1(), "left").directions[0] > 0   # bent toward the prism's base
        tensor(True)
    """
    check_option(half, _HALVES, "half")
    if like is None:
        like = rig.alpha if isinstance(rig, RigParameters) else torch.zeros((), dtype=torch.float64)
    p = as_parameters(rig, like)
    return trace_rays(p, apex_direction(p), half)


def apex_direction(p: RigParameters) -> torch.Tensor:
    """The (3,) unit direction of the camera ray through the prism's apex point A = (d, 0, T_o).

    Traced through a face it is that half's central ray (:func:`apex_ray`), the axis of its virtual camera.

    Example:
        >>> apex_direction(as_parameters(thesis_setup1(), torch.zeros(1, dtype=torch.float64)))
        tensor([0., 0., 1.], dtype=torch.float64)
    """
    apex = _planes(p).apex
    return apex / apex.norm()


def points_at_depth(rays: RayBundle, depth: torch.Tensor | float) -> torch.Tensor:
    """Points of outgoing rays at camera-frame depth Z (the scene point a pixel sees on a plane z = Z).

    Args:
        rays: RayBundle with (*, 3) origins/directions.
        depth: Z in mm, broadcastable to (*,).

    Returns:
        (*, 3) points o + s d with s = (Z - o_z) / d_z.

    Example:
        >>> rays = trace_pixels(thesis_setup1(), torch.tensor([[300.0, 200.0]]))
        >>> points_at_depth(rays, 500.0)[..., 2]
        tensor([500.])
    """
    s = (depth - rays.origins[..., 2]) / rays.directions[..., 2]
    pts = rays.origins + s.unsqueeze(-1) * rays.directions
    # Set Z exactly (removes rounding of the division; keeps the gradient w.r.t. depth).
    z = torch.as_tensor(depth, dtype=pts.dtype, device=pts.device).expand_as(pts[..., 2])
    return torch.cat([pts[..., :2], z.unsqueeze(-1)], dim=-1)


# ----------------------------------------------------------------------------------- rig check
def check_rig_images(rig: BiPrismRig, samples: int = 33) -> None:
    """Raise :class:`RigError` if a half-image sees nothing through the prism.

    The geometric validation of a rig (:class:`BiPrismRig` itself checks its fields only): traces a grid of
    ``samples`` x ``samples`` pixels over the sensor in float64; every half must have at least one valid ray
    (rays that miss the prism or are totally internally reflected are invalid). About a millisecond; called by
    :func:`~prismstereo.geometry.presets.load_rig`, the depth models and :class:`~prismstereo.nn.PrismCostVolume`.

    Args:
        rig: the rig.
        samples: pixels per sensor side in the traced grid (>= 2).

    Raises:
        RigError: if ``rig`` is not a :class:`BiPrismRig`, ``samples`` is bad, or a half-image sees nothing
            through the prism.

    Example:
        >>> check_rig_images(thesis_setup1())
        >>> check_rig_images(thesis_setup1().replace(prism_offset_x_mm=40.0))
        Traceback (most recent call last):
        ...
        prismstereo.errors.RigError: no pixel of the right half-image sees through the prism: ...
    """
    if not isinstance(rig, BiPrismRig):
        raise RigError(f"rig must be a BiPrismRig, got {type(rig).__name__}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise RigError(f"samples must be an int >= 2, got {samples!r}")
    u = torch.linspace(-0.5, rig.image_width - 0.5, samples, dtype=torch.float64)
    v = torch.linspace(-0.5, rig.image_height - 0.5, samples, dtype=torch.float64)
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1).reshape(-1, 2)
    rays = trace_pixel_rays(rig.parameters(uv), uv, "auto")
    for name, mask in (("left", rays.left), ("right", ~rays.left)):
        if not bool((rays.valid & mask).any()):
            raise RigError(f"no pixel of the {name} half-image sees through the prism: "
                           f"{_why_blind(rig, rays, mask, name)}")


def _why_blind(rig: BiPrismRig, rays: RayBundle, mask: torch.Tensor, half: str) -> str:
    """What makes the ``half`` of ``rig`` blind (its traced ``rays`` where ``mask``), and the fields to change."""
    t_o, scale = rig.apex_distance_mm, rig.pixel_size_mm / rig.focal_length_mm
    left, right = t_o * (-0.5 - rig.cx) * scale, t_o * (rig.image_width - 0.5 - rig.cx) * scale
    d = rig.prism_offset_x_mm
    span = f"the field of view spans x = {left:.4g} to {right:.4g} mm at the apex depth ({t_o:.4g} mm)"
    if not any(rig.prism_tilt_deg) and (d <= left if half == "left" else d >= right):
        return f"its apex line x = {d:g} mm (prism_offset_x_mm) is outside it: {span}"
    # a ray meets the face within the prism when it enters before the back plane
    inside = rays.entries[..., 2] <= t_o + rig.prism_thickness_mm * (1 + 1e-9)
    if bool((inside & mask).any()):
        return (f"its rays are totally internally reflected in the glass: a smaller angle (alpha_deg "
                f"{rig.alpha_deg:g}) or index (refractive_index {rig.refractive_index:g}) lets them out")
    reach = rig.prism_thickness_mm / math.tan(math.radians(rig.alpha_deg))
    return (f"its rays miss the prism, whose faces end {reach:.4g} mm from the apex line (prism_thickness_mm / tan "
            f"alpha_deg) while {span}: bring the prism closer (apex_distance_mm), make it thicker "
            f"(prism_thickness_mm) or its angle smaller (alpha_deg); prism_offset_x_mm {d:g}, prism_tilt_deg "
            f"{rig.prism_tilt_deg}")
