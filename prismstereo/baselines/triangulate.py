"""Depth of matched pixel pairs (reference pixel, right-half pixel) from a calibration: pinholes or exact optics.

Both triangulations build one ray per pixel in the real camera frame and take the midpoint of the two rays'
common perpendicular (the thesis' mid-point theorem, Appendix C, which its Tables 4.3-4.4 use for every
calibration method: :func:`~prismstereo.geometry.virtual_camera.ray_midpoint`):

* :func:`triangulate_pinholes`: a :class:`~prismstereo.baselines.pinhole.PinholePair` (Zhang, Tsai, or the
  geometric virtual cameras): each pixel undistorted with ``cv2.undistortPoints`` to normalised coordinates
  (x, y), the ray from the camera's centre along R (x, y, 1);
* :func:`triangulate_exact`: the rig's exact optics, each pixel traced through its half of the prism
  (:func:`~prismstereo.geometry.optics.trace_pixels`) to the ray leaving the back plane.

``gap_mm`` is the length of the common perpendicular: zero for a consistent pair, the calibration's disagreement
with the matches otherwise. Depth is the midpoint's Z in the real camera frame. Float64 on the CPU.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
import torch

from prismstereo.baselines.pinhole import Pinhole, PinholePair
from prismstereo.errors import ShapeError, check_floating, check_shape
from prismstereo.geometry.optics import trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import ray_midpoint

__all__ = ["Triangulation", "pinhole_rays", "triangulate_pinholes", "triangulate_exact"]

F64 = torch.float64
# cv2.undistortPoints iterates a fixed-point scheme (5 steps by default): far from exact for the strong
# coefficients a narrow-angle calibration can return; 200 steps or 1e-14 change leave < 1e-9 px on the examples.
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)


class Triangulation(NamedTuple):
    """Midpoint triangulation of N matched pairs.

    Attributes:
        points: (N, 3) float64 midpoints in the real camera frame (mm).
        depth: (N,) float64 their Z (mm).
        gap_mm: (N,) float64 distance between the two rays (mm).
        valid: (N,) bool: both rays exist (exact optics: the pixel sees through its half) and the point is in
            front of both cameras (pinholes) or beyond the prism's back plane (exact).
    """

    points: torch.Tensor
    depth: torch.Tensor
    gap_mm: torch.Tensor
    valid: torch.Tensor


def _check_pairs(uv_left: torch.Tensor, uv_right: torch.Tensor) -> None:
    check_shape(uv_left, ["N", 2], "uv_left")
    check_shape(uv_right, ["N", 2], "uv_right")
    check_floating(uv_left, "uv_left")
    check_floating(uv_right, "uv_right")
    if uv_left.shape != uv_right.shape:
        raise ShapeError(f"uv_left and uv_right must have the same shape, got {tuple(uv_left.shape)} and "
                         f"{tuple(uv_right.shape)}")


def _gap(o1: torch.Tensor, d1: torch.Tensor, o2: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
    n = torch.linalg.cross(d1, d2)
    return ((o2 - o1) * n).sum(-1).abs() / n.norm(dim=-1)


def pinhole_rays(camera: Pinhole, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays of pixels through a distorted pinhole, in the real camera frame.

    Args:
        camera: the pinhole.
        uv: (N, 2) full-sensor pixels.

    Returns:
        origins (N, 3) (the camera centre, repeated) and unit directions (N, 3), float64.

    Example:
        >>> from prismstereo.baselines.pinhole import pinhole_from_opencv
        >>> cam = pinhole_from_opencv(torch.eye(3), None, torch.zeros(3), torch.zeros(3))
        >>> pinhole_rays(cam, torch.tensor([[0.0, 0.0]], dtype=torch.float64))[1]
        tensor([[0., 0., 1.]], dtype=torch.float64)
    """
    check_shape(uv, ["N", 2], "uv")
    check_floating(uv, "uv")
    pts = uv.detach().to(F64).numpy().reshape(-1, 1, 2)
    xy = cv2.undistortPoints(pts, camera.matrix.numpy(), camera.distortion.numpy(), criteria=_UNDISTORT)
    xy = torch.from_numpy(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    local = torch.cat([xy, torch.ones_like(xy[:, :1])], dim=1)
    directions = torch.nn.functional.normalize(local @ camera.rotation.T, dim=1)
    return camera.centre.expand_as(directions).clone(), directions


def triangulate_pinholes(cameras: PinholePair, uv_left: torch.Tensor, uv_right: torch.Tensor) -> Triangulation:
    """Triangulate matched pixels with two distorted pinholes (undistort, rays, midpoint).

    Args:
        cameras: the left (reference) and right virtual cameras.
        uv_left: (N, 2) reference-half pixels (full sensor).
        uv_right: (N, 2) their matches in the right half (full sensor).

    Returns:
        Triangulation (N points).

    Raises:
        ShapeError: shapes that are not (N, 2) or differ.

    Example:
        >>> from prismstereo.baselines.pinhole import PinholePair, pinhole_from_opencv
        >>> k = torch.tensor([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
        >>> pair = PinholePair(pinhole_from_opencv(k, None, torch.zeros(3), torch.tensor([10.0, 0, 0])),
        ...                    pinhole_from_opencv(k, None, torch.zeros(3), torch.tensor([-10.0, 0, 0])))
        >>> uv_l, uv_r = torch.tensor([[60.0, 40.0]]), torch.tensor([[40.0, 40.0]])
        >>> triangulate_pinholes(pair, uv_l, uv_r).points.round(decimals=6)
        tensor([[ 0.,  0., 100.]], dtype=torch.float64)
    """
    _check_pairs(uv_left, uv_right)
    o1, d1 = pinhole_rays(cameras.left, uv_left)
    o2, d2 = pinhole_rays(cameras.right, uv_right)
    points = ray_midpoint(o1, d1, o2, d2)
    ahead = [((points - cam.centre) @ cam.rotation[:, 2]) > 0 for cam in cameras]
    valid = torch.isfinite(points).all(dim=1) & ahead[0] & ahead[1]
    return Triangulation(points, points[:, 2], _gap(o1, d1, o2, d2), valid)


def triangulate_exact(rig: BiPrismRig, uv_left: torch.Tensor, uv_right: torch.Tensor) -> Triangulation:
    """Triangulate matched pixels through the rig's exact optics (traced rays, midpoint).

    Args:
        rig: the rig (true, nominal or calibrated).
        uv_left: (N, 2) reference-half pixels (full sensor).
        uv_right: (N, 2) their matches in the right half (full sensor).

    Returns:
        Triangulation (N points); ``valid`` False where a pixel does not see through its half's face or the
        midpoint is not beyond the prism's back plane.

    Raises:
        ShapeError: shapes that are not (N, 2) or differ.

    Example:
        >>> from prismstereo.geometry import project_points
        >>> rig = thesis_setup1().downscaled(4)
        >>> x = torch.tensor([[5.0, -3.0, 600.0]], dtype=torch.float64)
        >>> uv_l, uv_r = project_points(rig, x, "left").uv, project_points(rig, x, "right").uv
        >>> round(float(triangulate_exact(rig, uv_l, uv_r).depth[0]), 6)
        600.0
    """
    _check_pairs(uv_left, uv_right)
    left = trace_pixels(rig, uv_left.detach().to(F64), "left")
    right = trace_pixels(rig, uv_right.detach().to(F64), "right")
    points = ray_midpoint(left.origins, left.directions, right.origins, right.directions)
    back = rig.apex_distance_mm + rig.prism_thickness_mm
    valid = left.valid & right.valid & torch.isfinite(points).all(dim=1) & (points[:, 2] > back)
    gap = _gap(left.origins, left.directions, right.origins, right.directions)
    return Triangulation(points, points[:, 2], gap, valid)
