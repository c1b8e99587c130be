"""Depth from disparity in the thesis' models and the exact one (thesis sec. 6.1, eq. 6.2-6.15).

Split from :mod:`prismstereo.analysis.error` (whose module docstring defines the disparity D and lists the
thesis errata of these equations): :func:`disparity_mm` and :func:`project_pair` relate a point to its two
images exactly; :func:`depth_small_angle` (eq. 6.15), :func:`depth_planar` (the general form 6.2-6.9,
corrected) and :func:`depth_exact` (3D ray intersection) turn disparities back into depth.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from prismstereo.analysis._common import as_tensor
from prismstereo.errors import check_shape
from prismstereo.geometry.optics import trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig, as_parameters
from prismstereo.geometry.virtual_camera import ray_midpoint

__all__ = [
    "StereoPair",
    "ExactDepth",
    "depth_constants",
    "disparity_mm",
    "project_pair",
    "depth_small_angle",
    "disparity_small_angle",
    "depth_planar",
    "depth_exact",
]


class StereoPair(NamedTuple):
    """A point's two images. uv_left/uv_right (*, 2) px, disparity (*,) mm, valid (*,) both halves see it."""

    uv_left: torch.Tensor
    uv_right: torch.Tensor
    disparity: torch.Tensor
    valid: torch.Tensor


class ExactDepth(NamedTuple):
    """Intersection of a pixel pair's traced rays: points (*, 3) (mid-point, Appendix C), depth (*,) = Z,
    valid (*,) both rays valid."""

    points: torch.Tensor
    depth: torch.Tensor
    valid: torch.Tensor


def disparity_mm(rig: BiPrismRig | RigParameters, uv_left: torch.Tensor, uv_right: torch.Tensor) -> torch.Tensor:
    """D = (u_r - u_l) * pixel_size (mm): the thesis' disparity (eq. 6.14) in our frame.

    Args:
        rig: the rig.
        uv_left: (*, 2) pixel in the left (reference) half.
        uv_right: (*, 2) pixel in the right half.

    Returns:
        (*,) D in mm (positive for a real point).

    Example:
        >>> disparity_mm(thesis_setup1(), torch.tensor([[300.0, 10.0]]), torch.tensor([[700.0, 10.0]]))
        tensor([1.8600])
    """
    check_shape(uv_left, ["*", 2], "uv_left")
    check_shape(uv_right, ["*", 2], "uv_right")
    p = as_parameters(rig, uv_left)
    return (uv_right[..., 0] - uv_left[..., 0]) * p.pixel_size


def project_pair(rig: BiPrismRig | RigParameters, points: torch.Tensor) -> StereoPair:
    """The images of points in both halves (exact, :func:`project_points`) and their disparity D (mm).

    Args:
        rig: the rig.
        points: (*, 3) camera-frame points (mm).

    Example:
        >>> pair = project_pair(thesis_setup1(), torch.tensor([[0.0, 0.0, 1000.0]], dtype=torch.float64))
        >>> round(float(pair.disparity[0]), 4), bool(pair.valid[0])
        (2.2378, True)
    """
    left = project_points(rig, points, "left")
    right = project_points(rig, points, "right")
    return StereoPair(left.uv, right.uv, disparity_mm(rig, left.uv, right.uv), left.valid & right.valid)


# ----------------------------------------------------------------------------------- depth models
def depth_constants(p: RigParameters) -> tuple[torch.Tensor, torch.Tensor]:
    """A = (T_o + T)(n - 1)/n and B = T_o (n - 1)/n of eq. 6.21-6.22, the constants of the thesis' depth
    formula (eq. 6.15) and its sensitivities.

    Example:
        >>> p = as_parameters(thesis_setup1(), torch.zeros(1, dtype=torch.float64))
        >>> a, b = depth_constants(p); bool(a > b > 0)
        True
    """
    k = (p.n - 1) / p.n
    return (p.T_o + p.T) * k, p.T_o * k


def depth_small_angle(rig: BiPrismRig | RigParameters, disparity: torch.Tensor | float) -> torch.Tensor:
    """Eq. 6.15: Z = (T_o + T)(n - 1)/n - T_o (n - 1)/n (D + 2 f alpha) / (D + 2 f alpha - 2 f alpha n).

    Valid for D < 2 f alpha (n - 1) (the asymptote: Z -> infinity); beyond it the formula returns
    meaningless (negative) depths. Differentiable w.r.t. D and every rig tensor.

    Args:
        rig: rig or tensors (T, T_o, f, alpha, n are used; d and tilt are ignored, as in the thesis).
        disparity: D (mm), any shape; sets dtype (float64 for Python numbers).

    Returns:
        Z (mm), shape of ``disparity``.

    Example:
        >>> round(float(depth_small_angle(thesis_setup1(), 2.2377542782724764)), 1)  # exact point at 1000 mm
        1030.4
    """
    d = as_tensor(disparity, name="disparity")
    p = as_parameters(rig, d)
    a, b = depth_constants(p)
    s = d + 2 * p.f * p.alpha
    return a - b * s / (s - 2 * p.f * p.alpha * p.n)


def disparity_small_angle(rig: BiPrismRig | RigParameters, depth: torch.Tensor | float) -> torch.Tensor:
    """Eq. 6.15 solved for D: D = 2 f alpha n (Z - A) / (Z - A + B) - 2 f alpha.

    Example:
        >>> rig = thesis_setup1()
        >>> round(float(depth_small_angle(rig, disparity_small_angle(rig, 800.0))), 6)
        800.0
    """
    z = as_tensor(depth, name="depth")
    p = as_parameters(rig, z)
    a, b = depth_constants(p)
    q = 2 * p.f * p.alpha * p.n
    return q * (z - a) / (z - a + b) - 2 * p.f * p.alpha


def _planar_ray(p: RigParameters, x: torch.Tensor, side: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Back-plane exit x and exit angle of the top-view ray of sensor coordinate x (eq. 6.2-6.8, our frame;
    side -1: left face z = T_o + (d - x) tan(a), +1: right face z = T_o + (x - d) tan(a))."""
    tw, ta = x / p.f, torch.tan(p.alpha)
    z_e = (p.T_o - side * p.d * ta) / (1 - side * tw * ta)  # entry depth (eq. 6.6, corrected)
    inside = -side * p.alpha + torch.asin(torch.sin(torch.atan(tw) + side * p.alpha) / p.n)  # eq. 6.2-6.4
    x_b = z_e * tw + (p.T_o + p.T - z_e) * torch.tan(inside)  # eq. 6.6-6.7 (corrected)
    s = (p.n * torch.sin(inside)).clamp(-1 + 1e-15, 1 - 1e-15)
    return x_b, torch.asin(s)  # eq. 6.5


def depth_planar(
    rig: BiPrismRig | RigParameters, x_left_mm: torch.Tensor | float, x_right_mm: torch.Tensor | float
) -> torch.Tensor:
    """The general depth equation (eq. 6.2-6.9): intersect Ray 3_L and Ray 3_R in the top view.

    Exact trigonometry without the small-angle approximation, including the prism offset d; exact for
    points on the principal row of an untilted prism (it ignores y and tilt).

    Args:
        rig: rig or tensors.
        x_left_mm: sensor x of the left image, (u_l - cx) * pixel_size (negative), any shape.
        x_right_mm: sensor x of the right image (positive), broadcastable.

    Returns:
        Z (mm).

    Example:
        >>> rig = thesis_setup1()
        >>> pair = project_pair(rig, torch.tensor([[0.0, 0.0, 1000.0]], dtype=torch.float64))
        >>> x = (torch.stack([pair.uv_left[0, 0], pair.uv_right[0, 0]]) - rig.cx) * rig.pixel_size_mm
        >>> round(float(depth_planar(rig, x[0], x[1])), 6)
        1000.0
    """
    xl = as_tensor(x_left_mm, name="x_left_mm")
    xr = as_tensor(x_right_mm, xl, "x_right_mm")
    p = as_parameters(rig, xl)
    bl, al = _planar_ray(p, xl, -1.0)
    br, ar = _planar_ray(p, xr, 1.0)
    return p.T_o + p.T + (br - bl) / (torch.tan(al) - torch.tan(ar))  # eq. 6.9


def depth_exact(rig: BiPrismRig | RigParameters, uv_left: torch.Tensor, uv_right: torch.Tensor) -> ExactDepth:
    """Depth of a pixel pair by the exact model: trace both pixels through their faces and take the
    mid-point of the two rays (they meet exactly for true correspondences).

    Args:
        rig: rig or tensors (may require grad).
        uv_left: (*, 2) left (reference) pixel; uv_right: (*, 2) right pixel.

    Returns:
        ExactDepth(points (*, 3), depth (*,), valid (*,)), differentiable w.r.t. pixels and rig tensors.

    Example:
        >>> rig = thesis_setup1()
        >>> pair = project_pair(rig, torch.tensor([[20.0, 5.0, 700.0]], dtype=torch.float64))
        >>> round(float(depth_exact(rig, pair.uv_left, pair.uv_right).depth[0]), 6)
        700.0
    """
    check_shape(uv_left, ["*", 2], "uv_left")
    check_shape(uv_right, ["*", 2], "uv_right")
    left = trace_pixels(rig, uv_left, "left")
    right = trace_pixels(rig, uv_right, "right")
    x = ray_midpoint(left.origins, left.directions, right.origins, right.directions)
    return ExactDepth(x, x[..., 2], left.valid & right.valid)


