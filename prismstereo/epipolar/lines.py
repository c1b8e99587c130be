"""Epipolar geometry of the bi-prism: the thesis' virtual epipolar lines, F-matrix lines, exact curves.

For a reference (left half) pixel, its scene point lies somewhere on the pixel's outgoing ray; the right
half sees that ray as a curve, the *exact epipolar curve*, computed here by projecting points of the ray
through the right face with :func:`~prismstereo.geometry.projection.project_points`. The thesis approximates
it by a straight line through two points (sec. 4.2): the projection of the ray's point at infinity
(eq. 4.5-4.9) and the epipole, the projection of the left virtual camera's centre (eq. 4.10), both by the
right *virtual pinhole*. The conventional alternative builds a fundamental matrix from the two virtual
pinholes (kornia ``fundamental_from_projections``). :func:`epipolar_line_accuracy` measures how far the
exact curves are from both lines.

All pixel coordinates are full-sensor (u, v); lines are (a, b, c) with a u + b v + c = 0 and a^2 + b^2 = 1,
so ``point_line_distance`` is in pixels.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from prismstereo.errors import RigError, check_floating, check_shape
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.projection import Projection, project_points
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import VirtualCamera, VirtualCameraPair, virtual_cameras

__all__ = [
    "EpipolarLines",
    "EpipolarAccuracy",
    "projection_matrix",
    "thesis_epipolar_lines",
    "fundamental_matrix",
    "fundamental_epipolar_lines",
    "exact_epipolar_curve",
    "exact_infinity_point",
    "point_line_distance",
    "epipolar_line_accuracy",
]


class EpipolarLines(NamedTuple):
    """Straight epipolar lines in the right half for reference pixels.

    Attributes:
        lines: (*, 3) normalised (a, b, c), a u + b v + c = 0.
        infinity_points: (*, 2) the right virtual camera's image of each reference ray's point at infinity
            (eq. 4.5-4.9).
        epipole: (2,) image of the left virtual camera's centre (eq. 4.10); every line passes through it.
    """

    lines: torch.Tensor
    infinity_points: torch.Tensor
    epipole: torch.Tensor


class EpipolarAccuracy(NamedTuple):
    """Distances (px) of exact epipolar curves from straight-line approximations, and pinhole errors.

    Attributes:
        thesis_max_px, thesis_mean_px: distance of exact curve points from the thesis' virtual lines.
        fundamental_max_px, fundamental_mean_px: the same for F-matrix lines.
        pinhole_mean_px, pinhole_max_px: reprojection error of the right virtual pinhole on the same points.
        samples: number of (pixel, depth) samples measured.
    """

    thesis_max_px: float
    thesis_mean_px: float
    fundamental_max_px: float
    fundamental_mean_px: float
    pinhole_mean_px: float
    pinhole_max_px: float
    samples: int


def projection_matrix(camera: VirtualCamera) -> torch.Tensor:
    """The 3x4 projection matrix P = K [R^T | -R^T C] of a virtual camera (real-frame points -> pixels).

    Example:
        >>> projection_matrix(virtual_cameras(thesis_setup1()).right).shape
        torch.Size([3, 4])
    """
    return camera.camera.intrinsics[0, :3, :3] @ camera.camera.extrinsics[0, :3, :]


def _project_h(p: torch.Tensor, xh: torch.Tensor) -> torch.Tensor:
    """Project homogeneous (*, 4) points with a 3x4 matrix to (*, 2) pixels."""
    q = xh @ p.T
    return q[..., :2] / q[..., 2:3]


def _normalise(lines: torch.Tensor) -> torch.Tensor:
    return lines / lines[..., :2].norm(dim=-1, keepdim=True)


def thesis_epipolar_lines(
    rig: BiPrismRig | RigParameters, uv_ref: torch.Tensor, cameras: VirtualCameraPair
) -> EpipolarLines:
    """The thesis' virtual epipolar lines (sec. 4.2, eq. 4.1-4.10) in the right half.

    The reference pixel's outgoing ray R3 is traced exactly (eq. 4.1-4.4); its point at infinity, the
    homogeneous point (R3, 0), and the left virtual centre OC_L are projected by the right virtual camera
    (eq. 4.5-4.9 and 4.10); the line joins the two images.

    Args:
        rig: the rig.
        uv_ref: (*, 2) reference (left half) pixels.
        cameras: the virtual cameras (:func:`~prismstereo.geometry.virtual_camera.virtual_cameras`).

    Returns:
        EpipolarLines with lines (*, 3), infinity_points (*, 2), epipole (2,); dtype of ``uv_ref``.

    Example:
        >>> rig = thesis_setup1()
        >>> ep = thesis_epipolar_lines(rig, torch.tensor([[300.0, 200.0]]), virtual_cameras(rig))
        >>> ep.lines.shape
        torch.Size([1, 3])
    """
    check_shape(uv_ref, ["*", 2], "uv_ref")
    check_floating(uv_ref, "uv_ref")
    p_right = projection_matrix(cameras.right).to(uv_ref)
    rays = trace_pixels(rig, uv_ref)
    inf_h = torch.cat([rays.directions, torch.zeros_like(rays.directions[..., :1])], dim=-1)
    infinity = _project_h(p_right, inf_h)
    centre = cameras.left.centre.to(uv_ref)
    epipole = _project_h(p_right, torch.cat([centre, torch.ones_like(centre[:1])]))
    e_h = torch.cat([epipole, torch.ones_like(epipole[:1])]).expand_as(inf_h[..., :3])
    i_h = torch.cat([infinity, torch.ones_like(infinity[..., :1])], dim=-1)
    lines = _normalise(torch.linalg.cross(e_h, i_h))
    return EpipolarLines(lines, infinity, epipole)


def fundamental_matrix(cameras: VirtualCameraPair) -> torch.Tensor:
    """F with x_right^T F x_left = 0 from the two virtual pinholes (kornia ``fundamental_from_projections``).

    Example:
        >>> fundamental_matrix(virtual_cameras(thesis_setup1())).shape
        torch.Size([3, 3])
    """
    # kornia imported where used: a cached graph's depth run never loads it
    from kornia.geometry.epipolar import fundamental_from_projections

    p_left, p_right = projection_matrix(cameras.left), projection_matrix(cameras.right)
    return fundamental_from_projections(p_left[None], p_right[None])[0]


def fundamental_epipolar_lines(uv_ref: torch.Tensor, fundamental: torch.Tensor) -> torch.Tensor:
    """Epipolar lines F x of reference pixels in the right half (kornia ``compute_correspond_epilines``).

    Args:
        uv_ref: (*, 2) reference pixels.
        fundamental: (3, 3) from :func:`fundamental_matrix`.

    Returns:
        (*, 3) normalised lines.

    Example:
        >>> F = fundamental_matrix(virtual_cameras(thesis_setup1()))
        >>> fundamental_epipolar_lines(torch.tensor([[300.0, 200.0]], dtype=torch.float64), F).shape
        torch.Size([1, 3])
    """
    check_shape(uv_ref, ["*", 2], "uv_ref")
    check_shape(fundamental, [3, 3], "fundamental")
    # kornia imported where used: a cached graph's depth run never loads it
    from kornia.geometry.epipolar import compute_correspond_epilines

    flat = uv_ref.reshape(1, -1, 2)
    lines = compute_correspond_epilines(flat, fundamental.to(uv_ref)[None])
    return lines.reshape(*uv_ref.shape[:-1], 3)


def exact_epipolar_curve(
    rig: BiPrismRig | RigParameters, uv_ref: torch.Tensor, depths: torch.Tensor
) -> Projection:
    """The exact epipolar curve: right-half pixels of the reference pixels' points at the given depths.

    Reference ray traced exactly -> point at depth Z (:func:`points_at_depth`) -> projected through the
    right face (:func:`project_points`). Differentiable w.r.t. pixels, depths and rig parameters.

    Args:
        rig: the rig.
        uv_ref: (*, 2) reference pixels.
        depths: (D,) depths Z (mm) beyond the back plane.

    Returns:
        Projection with uv (*, D, 2) and valid (*, D) (the reference ray must be valid and in the left half).

    Example:
        >>> depths = torch.tensor([300.0, 900.0])
        >>> exact_epipolar_curve(thesis_setup1(), torch.tensor([[300.0, 200.0]]), depths).uv.shape
        torch.Size([1, 2, 2])
    """
    check_shape(uv_ref, ["*", 2], "uv_ref")
    check_shape(depths, ["D"], "depths")
    rays = trace_pixels(rig, uv_ref)
    along = rays._replace(origins=rays.origins.unsqueeze(-2), directions=rays.directions.unsqueeze(-2))
    pts = points_at_depth(along, depths.to(uv_ref))  # (*, D, 3)
    proj = project_points(rig, pts, "right")
    ok = (rays.valid & rays.left).unsqueeze(-1)
    return Projection(proj.uv, proj.valid & ok)


def exact_infinity_point(rig: BiPrismRig | RigParameters, uv_ref: torch.Tensor, far_mm: float = 1e8) -> Projection:
    """The exact asymptote of the epipolar curve: the right-half pixel whose outgoing ray is parallel to
    the reference pixel's (the exact counterpart of eq. 4.5-4.9), found as the image of the ray's point at
    ``far_mm`` (mm beyond its exit point; at 1e8 mm the parallax is below 1e-6 px).

    Example:
        >>> exact_infinity_point(thesis_setup1(), torch.tensor([[300.0, 200.0]], dtype=torch.float64)).uv.shape
        torch.Size([1, 2])
    """
    check_shape(uv_ref, ["*", 2], "uv_ref")
    rays = trace_pixels(rig, uv_ref)
    proj = project_points(rig, rays.origins + far_mm * rays.directions, "right")
    return Projection(proj.uv, proj.valid & rays.valid & rays.left)


def point_line_distance(uv: torch.Tensor, lines: torch.Tensor) -> torch.Tensor:
    """Unsigned distance (px) of points (*, 2) from normalised lines (*, 3) (broadcast).

    Example:
        >>> point_line_distance(torch.tensor([3.0, 4.0]), torch.tensor([0.0, 1.0, -1.0]))
        tensor(3.)
    """
    return (uv[..., 0] * lines[..., 0] + uv[..., 1] * lines[..., 1] + lines[..., 2]).abs()


def epipolar_line_accuracy(
    rig: BiPrismRig,
    cameras: VirtualCameraPair | None = None,
    depth_range_mm: tuple[float, float] = (228.0, 1374.0),
    grid_step: int = 32,
    depths: int = 16,
    centre_fraction: float = 1.0,
) -> EpipolarAccuracy:
    """How far exact epipolar curves are from the thesis' lines and from F-matrix lines (float64).

    Reference pixels on a grid (step ``grid_step``) of the left half, restricted to the central
    ``centre_fraction`` of its width and height; depths uniform in inverse depth over ``depth_range_mm``;
    only samples whose exact correspondence exists (on the sensor, co-visible through the right face) count.

    Args:
        rig: the rig.
        cameras: virtual cameras (default: least squares, :func:`virtual_cameras`).
        depth_range_mm: (z_min, z_max).
        grid_step: pixel grid spacing.
        depths: number of depths.
        centre_fraction: in (0, 1], the central part of the half to evaluate.

    Returns:
        EpipolarAccuracy.

    Example:
        >>> acc = epipolar_line_accuracy(thesis_setup1(), grid_step=64, depths=4)
        >>> acc.thesis_max_px > 0
        True
    """
    if not 0 < centre_fraction <= 1:
        raise RigError(f"centre_fraction must be in (0, 1], got {centre_fraction}")
    z0, z1 = depth_range_mm
    if not rig.apex_distance_mm + rig.prism_thickness_mm < z0 < z1:
        raise RigError(f"depth_range_mm must lie beyond the prism's back plane and increase, got {depth_range_mm}")
    cameras = cameras or virtual_cameras(rig)
    f64 = torch.float64
    w_ref, h = rig.reference_width, rig.image_height
    cu, cv = (w_ref - 1) / 2, (h - 1) / 2
    half_u, half_v = centre_fraction * w_ref / 2, centre_fraction * h / 2
    u = torch.arange(0.0, w_ref, grid_step, dtype=f64)
    v = torch.arange(0.0, h, grid_step, dtype=f64)
    u, v = u[(u - cu).abs() <= half_u], v[(v - cv).abs() <= half_v]
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1).reshape(-1, 2)
    zs = 1.0 / torch.linspace(1.0 / z0, 1.0 / z1, depths, dtype=f64)
    curve = exact_epipolar_curve(rig, uv, zs)  # (N, D, 2)
    ok = curve.valid
    if not ok.any():
        raise RigError("no exact correspondence in the evaluated region and depth range")
    thesis = thesis_epipolar_lines(rig, uv, cameras).lines[:, None, :]
    fund = fundamental_epipolar_lines(uv, fundamental_matrix(cameras))[:, None, :]
    d_thesis = point_line_distance(curve.uv, thesis)[ok]
    d_fund = point_line_distance(curve.uv, fund)[ok]
    pts = points_at_depth(trace_pixels(rig, uv[:, None, :].expand(-1, depths, -1)), zs)
    pinhole = (cameras.right.camera.project(pts[ok]) - curve.uv[ok]).norm(dim=-1)
    return EpipolarAccuracy(
        thesis_max_px=float(d_thesis.max()), thesis_mean_px=float(d_thesis.mean()),
        fundamental_max_px=float(d_fund.max()), fundamental_mean_px=float(d_fund.mean()),
        pinhole_mean_px=float(pinhole.mean()), pinhole_max_px=float(pinhole.max()), samples=int(ok.sum()),
    )
