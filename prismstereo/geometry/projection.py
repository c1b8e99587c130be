"""Exact point -> pixel projection through the bi-prism: the inverse of tracing, by Newton's method.

A 3D point X seen through one half of the prism lands on the pixel uv whose traced ray
(:func:`~prismstereo.geometry.optics.trace_pixels`, thesis eq. 3.1-3.10) passes through X. There is no
closed form (the ray bends at two surfaces), so :func:`solve_projection` solves trace(uv) through X for uv by a
fixed number of Newton steps on the slope mismatch, started from the half's virtual pinhole (thesis sec. 3.2,
eq. 3.11-3.12); the loop has no data-dependent exit, so the graph is ONNX-traceable, and a last step carries
the implicit-function gradient w.r.t. the point and every rig parameter. :func:`project_points` adds the
sensor bounds. With ``extended`` the face is its infinite plane: the analytic continuation the exact sweep
(:mod:`prismstereo.epipolar.sweep`) is fitted through.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from prismstereo.conventions import HALVES as _HALVES
from prismstereo.conventions import Half
from prismstereo.errors import RigError, check_floating, check_option, check_shape
from prismstereo.geometry.distortion import distort
from prismstereo.geometry.optics import RayBundle, apex_direction, trace_pixel_rays, trace_rays
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig, as_parameters
from prismstereo.runtime import tracing

__all__ = ["Projection", "project_points", "solve_projection"]


class Projection(NamedTuple):
    """Result of :func:`project_points`.

    Attributes:
        uv: (*, 2) pixel coordinates (u, v) in the full sensor image.
        valid: (*,) bool: the point is beyond the back plane, the solver converged, the pixel is on the
            sensor inside the requested half, and its ray is valid.
    """

    uv: torch.Tensor
    valid: torch.Tensor


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cross product over the last dim, written out (exports to plain ONNX arithmetic)."""
    return torch.stack(
        [a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
         a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
         a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]],
        dim=-1,
    )


def _residual(
    p: RigParameters, points: torch.Tensor, uv: torch.Tensor, half: str, extended: bool
) -> tuple[torch.Tensor, RayBundle]:
    """Slope mismatch (2,) between the traced ray of ``uv`` and the line from its exit point to the point."""
    rays = trace_pixel_rays(p, uv, half, extended)
    rel = points - rays.origins
    dz = rel[..., 2:3]
    dz = torch.where(dz.abs() > 1e-9, dz, torch.full_like(dz, 1e-9))
    r = rays.directions[..., :2] / rays.directions[..., 2:3] - rel[..., :2] / dz
    return r, rays


def _newton_step(
    p: RigParameters, points: torch.Tensor, uv: torch.Tensor, half: str, extended: bool, h: float, max_step: float,
    residual: tuple[torch.Tensor, RayBundle] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, RayBundle]:
    """One Newton step on uv; the Jacobian (forward differences) is computed without grad so that the
    returned step's gradient is the implicit-function gradient -J^-1 dr/dtheta. ``residual``: :func:`_residual`
    at ``uv`` when the caller has it (the undifferentiated iterations trace it with the differences)."""
    with torch.no_grad():
        # detached inputs: no_grad stops reverse-mode autograd only, and under forward mode (the calibration's
        # Jacobian) these residuals would otherwise carry tangents that the step discards
        p0, points0, uv0 = p.detach(), points.detach(), uv.detach()
        du = torch.zeros_like(uv0)
        du[..., 0] = h
        dv = torch.zeros_like(uv0)
        dv[..., 1] = h
        # the differences' two pixels traced as one batch (element for element the same arithmetic as two
        # calls, with a third of the calls: small batches cost their calls), with uv itself when not given
        shifted = [uv0 + du, uv0 + dv] if residual is not None else [uv0, uv0 + du, uv0 + dv]
        rs, rays_s = _residual(p0, points0, torch.stack(shifted), half, extended)
        if residual is None:
            residual = rs[0], RayBundle(*(t[0] for t in rays_s))
        ru, rv = rs[-2], rs[-1]
        r0 = residual[0].detach()
        a, c = (ru[..., 0] - r0[..., 0]) / h, (ru[..., 1] - r0[..., 1]) / h
        b, d = (rv[..., 0] - r0[..., 0]) / h, (rv[..., 1] - r0[..., 1]) / h
        det = a * d - b * c
        det = torch.where(det.abs() > 1e-30, det, torch.full_like(det, 1e-30))
    r, rays = residual
    # delta = -J^-1 r (2x2 solve written out: ONNX friendly, no linalg ops)
    step = -torch.stack([d * r[..., 0] - b * r[..., 1], -c * r[..., 0] + a * r[..., 1]], dim=-1) / det.unsqueeze(-1)
    norm = step.norm(dim=-1, keepdim=True).detach()
    step = step * torch.clamp(max_step / norm.clamp_min(1e-30), max=1.0)
    return uv + step, step.norm(dim=-1), rays


def project_points(
    rig: BiPrismRig | RigParameters,
    points: torch.Tensor,
    half: Half,
    iterations: int = 5,
    initial_uv: torch.Tensor | None = None,
) -> Projection:
    """Project 3D points through one half of the prism to sensor pixels (the inverse of tracing).

    Solves trace(uv) passes through X for uv by a fixed number of Newton iterations (no data-dependent
    loop, so the graph is ONNX-traceable), started from the half's virtual pinhole built on its apex ray
    (thesis sec. 3.2) and finished by one more step whose gradient is the implicit-function gradient, so
    results are differentiable w.r.t. the points and every rig parameter. Converges to < 1e-6 px (float64)
    and < 1e-3 px (float32) for points between the back plane and 5 m.

    Args:
        rig: the rig (:class:`BiPrismRig` or :class:`RigParameters`).
        points: (*, 3) points in the camera frame (mm), float32 or float64.
        half: 'left' (reference) or 'right'.
        iterations: Newton iterations before the final step (>= 1). Measured on the thesis setups and a
            tilted, offset prism: 3 reach 1e-11 px in float64 from the pinhole start (up to ~30 px off for
            setup 2); the default 5 leaves margin. Non-converged points come back with ``valid`` False.
        initial_uv: (*, 2) optional starting pixels (e.g. the solution at a neighbouring depth), replacing
            the virtual-pinhole start where they are not NaN; two or three iterations then suffice.

    Returns:
        Projection(uv (*, 2), valid (*,)).

    Example:
        >>> proj = project_points(thesis_setup1(), torch.tensor([[10.0, 5.0, 600.0]]), "left")
        >>> proj.uv.shape, proj.valid
        (torch.Size([1, 2]), tensor([True]))
    """
    check_floating(points, "points")
    if not isinstance(iterations, int) or iterations < 1:
        raise RigError(f"iterations must be a positive int, got {iterations!r}")
    p = as_parameters(rig, points)
    uv, converged = solve_projection(p, points, half, iterations, initial_uv)
    on_sensor = (
        (uv[..., 0] >= -0.5) & (uv[..., 0] <= p.width - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= p.height - 0.5)
    )
    return Projection(uv, converged & on_sensor)


def solve_projection(
    rig: BiPrismRig | RigParameters,
    points: torch.Tensor,
    half: Half,
    iterations: int = 5,
    initial_uv: torch.Tensor | None = None,
    extended: bool = False,
) -> Projection:
    """:func:`project_points` without the sensor bounds: the sensor-plane position (*, 2) of each point seen
    through ``half``'s prism face, valid where the ray exists (no miss, no TIR), reaches the point and the
    Newton solve converged, even if the position lies off the sensor. With ``extended`` the face is its
    infinite plane (no apex, edge or other-face checks): the analytic continuation used to fit smooth
    sweep curves (:mod:`prismstereo.epipolar.sweep`) through depths where the real ray does not exist.
    ``iterations`` may be 0 here: only the final, differentiable step, from ``initial_uv`` already converged for
    these points (the calibration's Jacobian at the pixels it has just projected).

    Example:
        >>> solve_projection(thesis_setup1(), torch.tensor([[10.0, 5.0, 600.0]]), "right").valid
        tensor([True])
    """
    check_shape(points, ["*", 3], "points")
    check_floating(points, "points")
    check_option(half, _HALVES, "half")
    if not isinstance(iterations, int) or iterations < 0:
        raise RigError(f"iterations must be an int >= 0, got {iterations!r}")
    p = as_parameters(rig, points)
    f64 = points.dtype == torch.float64
    h = 1e-4 if f64 else 2e-2
    tol = 1e-6 if f64 else 2e-3
    settle = 1e-9 if f64 else 1e-4  # px: Newton's steps once converged are rounding (~1e-13 px in float64)
    max_step = 0.25 * p.width
    if initial_uv is not None:
        check_shape(initial_uv, ["*", 2], "initial_uv")
    with torch.no_grad():
        # detached rig and points: forward-mode autograd (the calibration's Jacobian) ignores no_grad
        p0, points0 = p.detach(), points.detach()
        uv = _initial_guess(p0, points0, half, extended)
        if initial_uv is not None:
            start = initial_uv.detach().to(points).expand_as(uv)
            uv = torch.where(torch.isnan(start), uv, start)
        for _ in range(iterations):
            uv, step, _ = _newton_step(p0, points0, uv, half, extended, h, max_step)
            uv = torch.stack([uv[..., 0].clamp(-p.width, 2.0 * p.width),
                              uv[..., 1].clamp(-p.height, 2.0 * p.height)], dim=-1)
            if not tracing() and step.numel() and float(step.max()) < settle:  # every point at its fixed point
                break
    uv = uv.detach()
    uv, last, rays = _newton_step(p, points, uv, half, extended, h, max_step, _residual(p, points, uv, half, extended))
    beyond = ((points - rays.origins) * rays.directions).sum(-1) > 0
    return Projection(uv, rays.valid & beyond & (last.detach() < tol))


def _initial_guess(p: RigParameters, points: torch.Tensor, half: str, extended: bool) -> torch.Tensor:
    """Project through the half's virtual pinhole: centre where the apex ray's back-extension meets z = 0,
    axis the apex ray's direction (the thesis' virtual camera, eq. 3.11-3.12), real intrinsics."""
    axis_ray = trace_rays(p, apex_direction(p), half, extended)
    o, a = axis_ray.origins, axis_ray.directions
    centre = o - a * (o[2] / a[2])
    # minimal rotation taking the axis a to e_z: R = I + [v]x + [v]x^2 / (1 + c), v = a x e_z, c = a_z
    v = torch.stack([a[1], -a[0], torch.zeros_like(a[0])])
    w = points - centre
    cross = _cross(v.expand_as(w), w)
    w = w + cross + _cross(v.expand_as(w), cross) / (1.0 + a[2])
    z = w[..., 2].clamp_min(1e-6)
    fpx = p.f / p.pixel_size
    xy = torch.stack([w[..., 0] / z, w[..., 1] / z], dim=-1)
    if p.distortion is not None:
        xy = distort(xy, p.distortion)
    return torch.stack([p.cx + fpx * xy[..., 0], p.cy + fpx * xy[..., 1]], dim=-1)
