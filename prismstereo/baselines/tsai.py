"""Calibration of each virtual camera from a known non-planar 3-D target (the thesis' Tsai column, Tables 4.3-4.4).

Tsai's method calibrates a camera from points whose 3-D positions are known in the world frame and do not lie on
one plane. OpenCV does not ship Tsai's two-stage radial-alignment algorithm; the same data and model are
calibrated here with OpenCV's general non-planar path, one half-image per camera:

1. The target is a set of planar groups (boards) at known poses in the real camera frame, e.g. one board at
   several measured poses taken as one 3-D point set (:mod:`prismstereo.baselines.targets`). An initial K comes
   from ``cv2.initCameraMatrix2D`` on the groups, each expressed in its own plane's coordinates (Zhang's
   closed-form homography initialisation; OpenCV refuses a non-planar rig without an initial K).
2. A first pose of the camera in the real frame from every point with that K: ``cv2.solvePnP`` (SQPnP, a
   global solver).
3. ``cv2.calibrateCamera`` with ``CALIB_USE_INTRINSIC_GUESS`` on *one* view holding every point, expressed in
   step 2's camera frame: OpenCV initialises that view's pose by a DLT on the non-planar points and refines K,
   distortion and the pose by Levenberg-Marquardt. (Given the points in the real frame, OpenCV's DLT converged
   to a mirrored pose behind a narrow-angle half's camera on some view sets, RMS ~40 px; in step 2's frame it
   starts next to the answer.) The composed pose is the camera's pose in the real frame: no registration step,
   the frame comes with the target, as in Tsai's method.

Default distortion ``CALIB_FIX_K3`` (k1, k2, p1, p2 free), as :func:`~prismstereo.baselines.zhang.calibrate_zhang`,
so the two columns differ by the target only (known 3-D points against planes at unknown poses); Tsai's own model
(k1 only) is ``CALIB_FIX_K2 | CALIB_FIX_K3 | CALIB_ZERO_TANGENT_DIST``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
import torch

from prismstereo.baselines.pinhole import Pinhole, PinholePair, pinhole_from_opencv
from prismstereo.baselines.zhang import check_image_size
from prismstereo.calibration.targets import ViewDetection
from prismstereo.errors import CalibrationError

__all__ = ["TsaiCamera", "TsaiResult", "tsai_camera", "calibrate_tsai"]

F64 = torch.float64
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
# singular-value ratios below which a point set counts as planar (a board) / as degenerate (the whole target)
_PLANAR = 1e-6
_NON_PLANAR = 1e-3


class TsaiCamera(NamedTuple):
    """One camera calibrated from a known 3-D target.

    Attributes:
        camera: the :class:`~prismstereo.baselines.pinhole.Pinhole`, posed in the target's (real) frame.
        rms_px: RMS reprojection error (px).
        initial_matrix: (3, 3) the K that ``initCameraMatrix2D`` started from.
    """

    camera: Pinhole
    rms_px: float
    initial_matrix: torch.Tensor


class TsaiResult(NamedTuple):
    """Both virtual cameras calibrated from a known 3-D target.

    Attributes:
        cameras: left and right pinholes in the real camera frame.
        rms_px: (2,) RMS reprojection error of the left and right camera.
        views: indices of the views whose known points entered (in either half).
    """

    cameras: PinholePair
    rms_px: torch.Tensor
    views: tuple[int, ...]


def _singular_ratio(points: torch.Tensor) -> torch.Tensor:
    s = torch.linalg.svdvals(points - points.mean(0))
    return s[-1] / s[0].clamp_min(1e-300)


def _plane_coordinates(points: torch.Tensor) -> np.ndarray:
    """(N, 3) float32 coordinates of coplanar points in their own plane's frame (z = 0)."""
    centred = points - points.mean(0)
    _, _, vt = torch.linalg.svd(centred, full_matrices=False)
    xy = centred @ vt[:2].T
    return torch.cat([xy, torch.zeros_like(xy[:, :1])], dim=1).numpy().astype(np.float32)


def tsai_camera(
    points: Sequence[torch.Tensor],
    uv: Sequence[torch.Tensor],
    image_size: Sequence[int],
    *,
    flags: int = cv2.CALIB_FIX_K3,
) -> TsaiCamera:
    """Calibrate one camera from a known non-planar target made of planar groups (module docstring).

    Args:
        points: G >= 2 groups of (N_g, 3) coplanar points (N_g >= 4) in the world (real camera) frame, mm.
        uv: G groups of (N_g, 2) their pixels (full sensor).
        image_size: (width, height) of the full sensor.
        flags: ``cv2.calibrateCamera`` flags (``CALIB_USE_INTRINSIC_GUESS`` is added).

    Returns:
        TsaiCamera.

    Raises:
        CalibrationError: mismatched or malformed groups, a group that is not planar, a target that is planar as
            a whole, or a calibration OpenCV rejects.

    Example:
        >>> from prismstereo.baselines.pinhole import project_pinhole, pinhole_from_opencv
        >>> k = torch.tensor([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
        >>> true = pinhole_from_opencv(k, None, torch.zeros(3), torch.zeros(3))
        >>> g = torch.stack(torch.meshgrid(torch.arange(5.0), torch.arange(4.0), indexing="xy"), -1).reshape(-1, 2)
        >>> flat = torch.cat([g * 20 - 40, torch.zeros(20, 1)], 1).double()
        >>> groups = [flat + torch.tensor([0, 0, 500.0]), flat[:, [2, 1, 0]] + torch.tensor([40.0, 0, 560])]
        >>> cam = tsai_camera(groups, [project_pinhole(true, p) for p in groups], (640, 480))
        >>> cam.camera.matrix.diagonal().round(decimals=3), cam.camera.centre.abs().max() < 1e-3
        (tensor([500., 500.,   1.], dtype=torch.float64), tensor(True))
    """
    size = check_image_size(image_size)
    if len(points) != len(uv) or len(points) < 2:
        raise CalibrationError(f"need >= 2 groups of points and as many groups of pixels, got {len(points)} and "
                               f"{len(uv)}")
    groups = []
    for g, (p, q) in enumerate(zip(points, uv, strict=True)):
        if not (isinstance(p, torch.Tensor) and isinstance(q, torch.Tensor) and p.dim() == 2 and p.shape[1] == 3
                and tuple(q.shape) == (p.shape[0], 2) and p.shape[0] >= 4):
            raise CalibrationError(f"group {g}: points must be (N, 3) and uv (N, 2) tensors with N >= 4, got "
                                   f"{tuple(getattr(p, 'shape', ()))} and {tuple(getattr(q, 'shape', ()))}")
        p, q = p.detach().to(F64), q.detach().to(F64)
        if not (bool(torch.isfinite(p).all()) and bool(torch.isfinite(q).all())):
            raise CalibrationError(f"group {g}: non-finite points or pixels")
        if _singular_ratio(p) > _PLANAR:
            raise CalibrationError(f"group {g}: its points are not coplanar (each group must be one board)")
        groups.append((p, q))
    every = torch.cat([p for p, _ in groups])
    if _singular_ratio(every) < _NON_PLANAR:
        raise CalibrationError("the target's points are (nearly) coplanar: Tsai's method needs a non-planar target "
                               "(boards at different known poses); for planes at unknown poses use Zhang's method")
    image = [q.numpy().astype(np.float32) for _, q in groups]
    pixels = np.concatenate(image)
    try:
        k0 = cv2.initCameraMatrix2D([_plane_coordinates(p) for p, _ in groups], image, size)
        _, rvec0, tvec0 = cv2.solvePnP(every.numpy(), pixels.astype(np.float64), k0, None, flags=cv2.SOLVEPNP_SQPNP)
        r0 = cv2.Rodrigues(rvec0)[0]
        local = every.numpy() @ r0.T + tvec0.reshape(1, 3)  # the target in the first pose's camera frame
        rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(
            [local.astype(np.float32)], [pixels], size, k0.copy(), None,
            flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=_CRITERIA)
    except cv2.error as exc:
        raise CalibrationError(f"OpenCV rejected the calibration: {exc}") from exc
    r1 = cv2.Rodrigues(rvecs[0])[0]  # X_cam = R1 (R0 X + t0) + t1
    camera = pinhole_from_opencv(k, dist.reshape(-1)[:5], r1 @ r0, r1 @ tvec0.reshape(3) + tvecs[0].reshape(3))
    return TsaiCamera(camera, float(rms), torch.from_numpy(k0).to(F64))


def calibrate_tsai(
    detections: Sequence[ViewDetection],
    reference_points: Sequence[torch.Tensor | None],
    image_size: Sequence[int],
    *,
    flags: int = cv2.CALIB_FIX_K3,
) -> TsaiResult:
    """Calibrate both virtual cameras from board views at known poses taken as one 3-D target.

    Args:
        detections: one :class:`~prismstereo.calibration.targets.ViewDetection` per capture.
        reference_points: per capture, None or (num_points, 3) real-frame board points by id (NaN where unknown,
            :func:`~prismstereo.baselines.targets.reference_points`).
        image_size: (width, height) of the full sensor.
        flags: ``cv2.calibrateCamera`` flags of each half.

    Returns:
        TsaiResult.

    Raises:
        CalibrationError: as :func:`tsai_camera` (fewer than two known views in a half), or lists of different
            lengths.

    Example:
        >>> calibrate_tsai([], [], (512, 384))
        Traceback (most recent call last):
        ...
        prismstereo.errors.CalibrationError: left half: need >= 2 groups of points ... got 0 and 0
    """
    if len(reference_points) != len(detections):
        raise CalibrationError(f"reference_points must have one entry per detection ({len(detections)}), got "
                               f"{len(reference_points)}")
    cams, rms, used = [], [], set()
    for half in ("left", "right"):
        pts, uvs = [], []
        for i, (det, ref) in enumerate(zip(detections, reference_points, strict=True)):
            found = getattr(det, half)
            if found is None or ref is None:
                continue
            known = ref[found.ids].to(F64)
            keep = torch.isfinite(known).all(dim=1)
            pts.append(known[keep])
            uvs.append(found.uv[keep].to(F64))
            used.add(i)
        try:
            cam = tsai_camera(pts, uvs, image_size, flags=flags)
        except CalibrationError as exc:
            raise CalibrationError(f"{half} half: {exc}") from exc
        cams.append(cam.camera)
        rms.append(cam.rms_px)
    return TsaiResult(PinholePair(*cams), torch.tensor(rms, dtype=F64), tuple(sorted(used)))
