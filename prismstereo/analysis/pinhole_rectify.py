"""Pinhole rectification of the two virtual cameras: analysis only (approximate; for visualisation, conventional
tools and measuring how far the virtual pinholes are from the exact optics). The depth model rectifies with
:mod:`prismstereo.epipolar.row_rectify` instead, fitted to the exact sweep.

The virtual cameras (:mod:`prismstereo.geometry.virtual_camera`) are rectified the classic way
(Fusiello, Trucco & Verri 2000): both are rotated to a common orientation whose x axis is the baseline
C_right - C_left, and given a common focal length, so their epipolar lines become image rows. Because the
bi-prism's virtual cameras are not pinholes (non-central rays, anamorphic distortion), *true*
correspondences stay vertically misaligned after this rectification, by an amount that depends on depth
and position: :func:`rectification_residual` measures it. Dense matching should use the exact grids of
:mod:`prismstereo.epipolar.grids` instead.

Output grids are full-sensor pixel coordinates for ``grid_sample`` on the full image (use
:func:`full_image_grid` to normalise them, align_corners=False).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from prismstereo.errors import RigError
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import VirtualCamera, VirtualCameraPair, virtual_cameras

__all__ = [
    "Rectification",
    "RectificationResidual",
    "rectify_virtual_cameras",
    "rectification_residual",
    "full_image_grid",
]


class Rectification(NamedTuple):
    """Rectifying warps of the two half-images.

    Attributes:
        left_grid: (H, W_r, 2) full-sensor source pixel (u, v) of each rectified left pixel.
        right_grid: (H, W_r, 2) the same for the right half.
        homography_left: (3, 3) original left pixel -> rectified left pixel.
        homography_right: (3, 3) original right pixel -> rectified right pixel.
        intrinsics_left, intrinsics_right: (3, 3) rectified intrinsics (same f and cy; cx differs).
        rotation: (3, 3) common rectified orientation (columns = axes in the real camera frame).
        baseline_mm: distance between the virtual centres.
    """

    left_grid: torch.Tensor
    right_grid: torch.Tensor
    homography_left: torch.Tensor
    homography_right: torch.Tensor
    intrinsics_left: torch.Tensor
    intrinsics_right: torch.Tensor
    rotation: torch.Tensor
    baseline_mm: float


class RectificationResidual(NamedTuple):
    """Vertical misalignment (px) of true correspondences after rectification, per depth.

    Attributes:
        depths: (D,) depths (mm).
        mean_px: (D,) mean |v_right - v_left| in rectified coordinates.
        max_px: (D,) maximum.
    """

    depths: torch.Tensor
    mean_px: torch.Tensor
    max_px: torch.Tensor


def _k(camera: VirtualCamera) -> torch.Tensor:
    return camera.camera.intrinsics[0, :3, :3]


def _apply(h: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    q = torch.cat([uv, torch.ones_like(uv[..., :1])], dim=-1) @ h.T
    return q[..., :2] / q[..., 2:3]


def rectify_virtual_cameras(rig: BiPrismRig, cameras: VirtualCameraPair | None = None) -> Rectification:
    """Rectify the two virtual pinholes (Fusiello): common rotation, common focal length and row.

    The rectified images are H x W_r with W_r = W_ref (the reference half's width); each camera's
    horizontal principal point is chosen so that the centre of its half maps to the centre column.

    Args:
        rig: the rig.
        cameras: virtual cameras (default: least squares).

    Returns:
        Rectification (float64).

    Example:
        >>> rect = rectify_virtual_cameras(thesis_setup1())
        >>> rect.left_grid.shape
        torch.Size([768, 512, 2])
    """
    cameras = cameras or virtual_cameras(rig)
    c_l, c_r = cameras.left.centre, cameras.right.centre
    baseline = c_r - c_l
    if baseline.norm() < 1e-9:
        raise RigError("the virtual cameras share their centre: nothing to rectify")
    x = baseline / baseline.norm()
    z_mean = cameras.left.rotation[:, 2] + cameras.right.rotation[:, 2]
    y = torch.linalg.cross(z_mean, x)
    y = y / y.norm()
    z = torch.linalg.cross(x, y)
    rot = torch.stack([x, y, z], dim=1)
    k_l, k_r = _k(cameras.left), _k(cameras.right)
    f = 0.5 * (k_l[0, 0] + k_l[1, 1] + k_r[0, 0] + k_r[1, 1]) / 2
    w_r, h = rig.reference_width, rig.image_height
    homs, ks = [], []
    for cam, k_old, centre_u in ((cameras.left, k_l, (w_r - 1) / 2),
                                 (cameras.right, k_r, (w_r + rig.image_width - 1) / 2)):
        # H = K_new R^T R_cam K_old^-1 maps original pixels to rectified pixels
        k_new = torch.tensor([[f, 0.0, 0.0], [0.0, f, rig.cy], [0.0, 0.0, 1.0]], dtype=rot.dtype)
        h0 = k_new @ rot.T @ cam.rotation @ torch.linalg.inv(k_old)
        centre = _apply(h0, torch.tensor([centre_u, rig.cy], dtype=rot.dtype))
        k_new[0, 2] = (w_r - 1) / 2 - centre[0]
        homs.append(k_new @ rot.T @ cam.rotation @ torch.linalg.inv(k_old))
        ks.append(k_new)
    v, u = torch.meshgrid(torch.arange(h, dtype=rot.dtype), torch.arange(w_r, dtype=rot.dtype), indexing="ij")
    rect_uv = torch.stack([u, v], dim=-1)
    grids = [_apply(torch.linalg.inv(hm), rect_uv) for hm in homs]
    return Rectification(grids[0], grids[1], homs[0], homs[1], ks[0], ks[1], rot, float(baseline.norm()))


def rectification_residual(
    rig: BiPrismRig, rect: Rectification, depths: torch.Tensor, grid_step: int = 16
) -> RectificationResidual:
    """Vertical misalignment of exact correspondences after pinhole rectification, per depth.

    Reference pixels on a grid of the left half see points at each depth; their exact right-half pixels
    (:func:`project_points`) and the reference pixels are mapped through the rectifying homographies; a
    perfect rectification would put both on the same row.

    Args:
        rig: the rig.
        rect: from :func:`rectify_virtual_cameras`.
        depths: (D,) depths (mm).
        grid_step: pixel grid spacing.

    Returns:
        RectificationResidual.

    Example:
        >>> rig = thesis_setup1()
        >>> depths = torch.tensor([300.0, 1000.0], dtype=torch.float64)
        >>> res = rectification_residual(rig, rectify_virtual_cameras(rig), depths)
        >>> bool((res.max_px > 0.1).all())
        True
    """
    f64 = torch.float64
    u = torch.arange(0.0, rig.reference_width, grid_step, dtype=f64)
    v = torch.arange(0.0, rig.image_height, grid_step, dtype=f64)
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1).reshape(-1, 2)
    rays = trace_pixels(rig, uv)
    means, maxes = [], []
    for z in depths.to(f64):
        proj = project_points(rig, points_at_depth(rays, z), "right")
        ok = proj.valid & rays.valid & rays.left
        if not ok.any():
            raise RigError(f"no exact correspondence at depth {float(z)} mm")
        dv = (_apply(rect.homography_right, proj.uv[ok])[:, 1] - _apply(rect.homography_left, uv[ok])[:, 1]).abs()
        means.append(dv.mean())
        maxes.append(dv.max())
    return RectificationResidual(depths.to(f64), torch.stack(means), torch.stack(maxes))


def full_image_grid(grid_uv: torch.Tensor, rig: BiPrismRig) -> torch.Tensor:
    """Full-sensor pixel grid (*, 2) -> ``grid_sample`` coordinates on the full image (align_corners=False).

    Example:
        >>> full_image_grid(torch.tensor([0.0, 0.0]), thesis_setup1())
        tensor([-0.9990, -0.9987])
    """
    x = (2 * grid_uv[..., 0] + 1) / rig.image_width - 1
    y = (2 * grid_uv[..., 1] + 1) / rig.image_height - 1
    return torch.stack([x, y], dim=-1)
