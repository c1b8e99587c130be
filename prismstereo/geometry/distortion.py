"""Lens distortion of the real camera: OpenCV's Brown-Conrady model on normalised coordinates.

A camera ray with direction (x, y, 1) (normalised, undistorted coordinates) reaches the sensor at the
normalised, *distorted* position (OpenCV ``projectPoints``, coefficients ``(k1, k2, p1, p2, k3)``)::

    r^2 = x^2 + y^2,   radial = 1 + k1 r^2 + k2 r^4 + k3 r^6
    x_d = x radial + 2 p1 x y + p2 (r^2 + 2 x^2)
    y_d = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y

and the pixel is (u, v) = (cx + f_px x_d, cy + f_px y_d). Tracing a pixel needs the inverse: :func:`undistort`
solves the two equations for (x, y) by a fixed number of Newton steps with the analytic 2 x 2 Jacobian
(OpenCV's ``undistortPoints`` uses a fixed-point iteration that stops at ~1e-3 px for strong distortion; the
Newton form reaches float64 rounding in four steps for |k1| <= 0.5 over a sensor of normalised radius 0.5; the
default takes six, then the differentiable one).
The steps run without autograd and a last step carries the gradient, which is then the implicit-function
gradient -J^-1 dD/dtheta: exact at convergence, cheap, and ONNX-traceable (no data-dependent loop).

With all coefficients zero every formula reduces exactly (bit for bit) to the pinhole: radial is exactly 1
and every correction exactly 0, so a distortion-free rig keeps its results.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from prismstereo.errors import check_floating, check_shape

__all__ = ["DISTORTION_NAMES", "DistortionJacobian", "distort", "distortion_jacobian", "max_round_trip_px",
           "round_trip_px", "undistort"]

DISTORTION_NAMES: tuple[str, ...] = ("k1", "k2", "p1", "p2", "k3")
_UNDISTORT_STEPS = 6


class DistortionJacobian(NamedTuple):
    """The distortion's 2 x 2 Jacobian d(x_d, y_d)/d(x, y), entry by entry, each (*,)."""

    xx: torch.Tensor
    xy: torch.Tensor
    yx: torch.Tensor
    yy: torch.Tensor


def _split(xy: torch.Tensor, coefficients: torch.Tensor) -> tuple[torch.Tensor, ...]:
    k = coefficients.to(xy)
    return (xy[..., 0], xy[..., 1], k[..., 0], k[..., 1], k[..., 2], k[..., 3], k[..., 4])


def _distort(xy: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    x, y, k1, k2, p1, p2, k3 = _split(xy, coefficients)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + (2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x))
    yd = y * radial + (p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)
    return torch.stack([xd, yd], dim=-1)


def _jacobian(xy: torch.Tensor, coefficients: torch.Tensor) -> DistortionJacobian:
    x, y, k1, k2, p1, p2, k3 = _split(xy, coefficients)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    g = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r^2
    cross = 2.0 * x * y * g + 2.0 * p1 * x + 2.0 * p2 * y
    return DistortionJacobian(
        xx=radial + 2.0 * x * x * g + 2.0 * p1 * y + 6.0 * p2 * x,
        xy=cross,
        yx=cross,
        yy=radial + 2.0 * y * y * g + 6.0 * p1 * y + 2.0 * p2 * x,
    )


def distort(xy: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """Normalised undistorted coordinates -> normalised distorted ones (OpenCV ``projectPoints``' model).

    Args:
        xy: (*, 2) normalised coordinates (X / Z, Y / Z) of camera rays.
        coefficients: (5,) or (*, 5) ``(k1, k2, p1, p2, k3)``, broadcastable.

    Returns:
        (*, 2) distorted normalised coordinates; pixels are cx + f_px x_d, cy + f_px y_d.

    Example:
        >>> k = torch.tensor([-0.2, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)
        >>> distort(torch.tensor([[0.1, 0.0]], dtype=torch.float64), k)
        tensor([[0.0998, 0.0000]], dtype=torch.float64)
    """
    check_shape(xy, ["*", 2], "xy")
    check_floating(xy, "xy")
    check_shape(coefficients, ["*", 5], "coefficients")
    return _distort(xy, coefficients)


def distortion_jacobian(xy: torch.Tensor, coefficients: torch.Tensor) -> DistortionJacobian:
    """The analytic Jacobian d(x_d, y_d) / d(x, y) of :func:`distort` at ``xy`` (*, 2): four (*,) entries.

    Example:
        >>> j = distortion_jacobian(torch.zeros(3, 2), torch.zeros(5))
        >>> j.xx
        tensor([1., 1., 1.])
    """
    check_shape(xy, ["*", 2], "xy")
    check_shape(coefficients, ["*", 5], "coefficients")
    return _jacobian(xy, coefficients)


def _newton(xy: torch.Tensor, target: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """One Newton step of distort(xy) = target, the 2 x 2 solve written out (ONNX friendly)."""
    r = _distort(xy, coefficients) - target
    with torch.no_grad():  # on detached inputs: forward-mode autograd ignores no_grad
        j = _jacobian(xy.detach(), coefficients.detach())
        det = j.xx * j.yy - j.xy * j.yx
        det = torch.where(det.abs() > 1e-30, det, torch.full_like(det, 1e-30))
    step = torch.stack([j.yy * r[..., 0] - j.xy * r[..., 1], -j.yx * r[..., 0] + j.xx * r[..., 1]], dim=-1)
    return xy - step / det.unsqueeze(-1)


def undistort(xy_distorted: torch.Tensor, coefficients: torch.Tensor, steps: int = _UNDISTORT_STEPS) -> torch.Tensor:
    """Invert :func:`distort`: normalised distorted coordinates -> normalised undistorted ones.

    Newton's method from x = x_d, ``steps`` steps without autograd and one more with it (implicit-function
    gradient w.r.t. ``xy_distorted`` and ``coefficients``). Zero coefficients return ``xy_distorted`` exactly.

    Args:
        xy_distorted: (*, 2) normalised distorted coordinates ((u - cx) / f_px, (v - cy) / f_px).
        coefficients: (5,) or (*, 5) ``(k1, k2, p1, p2, k3)``.
        steps: Newton steps before the differentiable one (>= 0).

    Returns:
        (*, 2) undistorted normalised coordinates: the camera ray's direction is (x, y, 1).

    Example:
        >>> k = torch.tensor([-0.1, 0.02, 1e-3, -1e-3, 0.0], dtype=torch.float64)
        >>> xy = torch.tensor([[0.2, -0.1]], dtype=torch.float64)
        >>> bool((distort(undistort(xy, k), k) - xy).abs().max() < 1e-15)
        True
    """
    check_shape(xy_distorted, ["*", 2], "xy_distorted")
    check_floating(xy_distorted, "xy_distorted")
    check_shape(coefficients, ["*", 5], "coefficients")
    target = xy_distorted
    with torch.no_grad():
        xy = target.detach()
        k = coefficients.detach()
        for _ in range(steps):
            xy = _newton(xy, target.detach(), k)
    return _newton(xy, target, coefficients)


def round_trip_px(xy: torch.Tensor, xy_distorted: torch.Tensor, coefficients: torch.Tensor,
                  focal_px: torch.Tensor | float) -> torch.Tensor:
    """How far an undistorted point ``xy`` (*, 2) is from being the preimage of ``xy_distorted`` (*, 2):
    |distort(xy) - xy_distorted| in pixels, inf where the lens model folds over there (Jacobian determinant
    <= 0). Beyond a strong lens model's fold a pixel has no preimage and Newton's iterate misses; no autograd.

    Example:
        >>> k = torch.tensor([-0.1, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)
        >>> xy_d = torch.tensor([[0.3, 0.2]], dtype=torch.float64)
        >>> bool(round_trip_px(undistort(xy_d, k), xy_d, k, 1000.0)[0] < 1e-9)
        True
    """
    with torch.no_grad():
        xy, target, k = xy.detach(), xy_distorted.detach(), coefficients.detach()
        j = _jacobian(xy, k)
        miss = (_distort(xy, k) - target).norm(dim=-1) * (focal_px.detach() if isinstance(focal_px, torch.Tensor)
                                                          else focal_px)
        return torch.where(j.xx * j.yy - j.xy * j.yx > 0, miss, torch.full_like(miss, float("inf")))


def max_round_trip_px(coefficients: torch.Tensor, corners: torch.Tensor, focal_px: float) -> float:
    """Largest |distort(undistort(c)) - c| in pixels over normalised sensor points ``corners`` (*, 2), and inf where
    the distortion folds over (Jacobian determinant <= 0): the rig's check that the lens model is invertible on its
    sensor.

    Example:
        >>> corners = torch.tensor([[0.5, 0.4], [-0.5, -0.4]], dtype=torch.float64)
        >>> max_round_trip_px(torch.tensor([-0.1, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64), corners, 1000.0) < 1e-9
        True
    """
    with torch.no_grad():
        return float(round_trip_px(undistort(corners, coefficients), corners, coefficients, focal_px).max())
