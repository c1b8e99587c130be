"""Pinhole virtual cameras with OpenCV lens distortion: what the conventional calibrations of the baselines give.

A :class:`Pinhole` is one half-image's virtual camera as Zhang's and Tsai's methods model it: intrinsic matrix K
(full-sensor pixels: both halves keep the real sensor's pixel coordinates, as
:mod:`prismstereo.geometry.virtual_camera` does), OpenCV's distortion ``(k1, k2, p1, p2, k3)`` and its pose in
the real camera frame (:mod:`prismstereo.conventions`): ``rotation`` R holds the camera's axes as columns and
``centre`` C is its optical centre, so X_cam = R^T (X - C), the same convention as
:class:`~prismstereo.geometry.virtual_camera.VirtualCamera`. OpenCV's extrinsics (X_cam = R_cv X + t_cv) convert
by R = R_cv^T, C = -R_cv^T t_cv (:func:`pinhole_from_opencv`).

Everything is float64 on the CPU (calibration, not a graph layer); OpenCV is called through NumPy.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
import torch

from prismstereo.errors import CalibrationError, check_shape
from prismstereo.geometry.virtual_camera import VirtualCamera

__all__ = ["Pinhole", "PinholePair", "pinhole_from_opencv", "pinhole_from_virtual", "project_pinhole"]

F64 = torch.float64


class Pinhole(NamedTuple):
    """One virtual camera as a distorted pinhole, posed in the real camera frame.

    Attributes:
        matrix: (3, 3) float64 intrinsic matrix K (full-sensor pixels).
        distortion: (5,) float64 OpenCV coefficients (k1, k2, p1, p2, k3).
        rotation: (3, 3) float64 camera axes as columns (camera-to-real-frame rotation).
        centre: (3,) float64 optical centre in the real camera frame (mm).
    """

    matrix: torch.Tensor
    distortion: torch.Tensor
    rotation: torch.Tensor
    centre: torch.Tensor


class PinholePair(NamedTuple):
    """The left (reference) and right virtual cameras as pinholes."""

    left: Pinhole
    right: Pinhole


def _matrix(x: torch.Tensor | np.ndarray, shape: tuple[int, ...], name: str) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(x, dtype=np.float64)).to(F64)
    if t.numel() != int(np.prod(shape)) or not bool(torch.isfinite(t).all()):
        raise CalibrationError(f"{name} must hold {int(np.prod(shape))} finite numbers {shape}, got shape "
                               f"{tuple(t.shape)}")
    return t.reshape(shape)


def pinhole_from_opencv(
    matrix: torch.Tensor | np.ndarray,
    distortion: torch.Tensor | np.ndarray | None,
    rotation: torch.Tensor | np.ndarray,
    translation: torch.Tensor | np.ndarray,
) -> Pinhole:
    """A :class:`Pinhole` from OpenCV's intrinsics and extrinsics (X_cam = R_cv X + t_cv, X in the real frame).

    Args:
        matrix: (3, 3) K.
        distortion: (k1, k2, p1, p2[, k3]) or None for none (4 coefficients get k3 = 0).
        rotation: (3, 3) R_cv or a Rodrigues vector (3,) / (3, 1).
        translation: (3,) / (3, 1) t_cv (mm).

    Returns:
        Pinhole with rotation R_cv^T and centre -R_cv^T t_cv.

    Raises:
        CalibrationError: wrong sizes or non-finite values.

    Example:
        >>> cam = pinhole_from_opencv(torch.eye(3), None, torch.zeros(3), torch.tensor([10.0, 0.0, 0.0]))
        >>> cam.centre
        tensor([-10.,  -0.,  -0.], dtype=torch.float64)
    """
    k = _matrix(matrix, (3, 3), "matrix")
    dist = torch.zeros(5, dtype=F64)
    if distortion is not None:
        d = torch.as_tensor(np.asarray(distortion, dtype=np.float64)).reshape(-1)
        if d.numel() not in (4, 5) or not bool(torch.isfinite(d).all()):
            raise CalibrationError(f"distortion must be 4 or 5 finite coefficients, got {d.numel()}")
        dist[: d.numel()] = d
    r = np.asarray(rotation, dtype=np.float64)
    if r.size == 3:
        r = cv2.Rodrigues(r.reshape(3, 1))[0]
    r_cv = _matrix(r, (3, 3), "rotation")
    t_cv = _matrix(translation, (3,), "translation")
    return Pinhole(k, dist, r_cv.T.contiguous(), -(r_cv.T @ t_cv))


def pinhole_from_virtual(camera: VirtualCamera) -> Pinhole:
    """The geometric virtual camera of :func:`~prismstereo.geometry.virtual_camera.virtual_camera` (thesis
    two-point or our all-pixel least squares) as a distortion-free :class:`Pinhole`.

    Raises:
        CalibrationError: ``camera`` is not a :class:`~prismstereo.geometry.virtual_camera.VirtualCamera`.

    Example:
        >>> from prismstereo.geometry import virtual_camera
        >>> cam = pinhole_from_virtual(virtual_camera(thesis_setup1().downscaled(4), "left", "two_point"))
        >>> cam.matrix.shape, round(float(cam.centre[0]), 2)
        (torch.Size([3, 3]), -9.27)
    """
    if not isinstance(camera, VirtualCamera):
        raise CalibrationError(f"camera must be a VirtualCamera (virtual_camera(...)), got {type(camera).__name__}")
    k = camera.camera.intrinsics[0, :3, :3].to(F64)
    return Pinhole(k.clone(), torch.zeros(5, dtype=F64), camera.rotation.to(F64), camera.centre.to(F64))


def project_pinhole(camera: Pinhole, points: torch.Tensor) -> torch.Tensor:
    """Pixels of real-frame points through a pinhole with its distortion (``cv2.projectPoints``).

    Args:
        camera: the pinhole.
        points: (N, 3) points in the real camera frame (mm), in front of the camera.

    Returns:
        (N, 2) float64 full-sensor pixels (u, v).

    Example:
        >>> cam = pinhole_from_opencv(torch.eye(3), None, torch.zeros(3), torch.zeros(3))
        >>> project_pinhole(cam, torch.tensor([[1.0, 2.0, 4.0]], dtype=torch.float64))
        tensor([[0.2500, 0.5000]], dtype=torch.float64)
    """
    check_shape(points, ["N", 3], "points")
    r_cv = camera.rotation.T.numpy()
    t_cv = -(r_cv @ camera.centre.numpy())
    uv, _ = cv2.projectPoints(points.detach().to(F64).numpy().reshape(-1, 1, 3), cv2.Rodrigues(r_cv)[0], t_cv,
                              camera.matrix.numpy(), camera.distortion.numpy())
    return torch.from_numpy(uv.reshape(-1, 2)).to(F64)
