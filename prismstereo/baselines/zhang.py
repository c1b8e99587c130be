"""Zhang's calibration of the two virtual cameras (thesis sec. 3.3.1), with OpenCV, one half-image per camera.

The thesis cuts every board capture into its two half-images and calibrates each as a camera of its own with
Zhang's method (Bouguet's Matlab toolbox, refined by Levenberg-Marquardt), then the pair. Here:

1. ``cv2.calibrateCamera`` on each half's checkerboard corners (board points at z = 0,
   :meth:`~prismstereo.calibration.targets.Board.points`): K, distortion and a board pose per view. **Pixel
   coordinates stay full-sensor** and the image size passed is the full sensor's, so both principal points live
   in full-sensor pixels, as the geometric virtual cameras' do (:mod:`prismstereo.geometry.virtual_camera`), and
   OpenCV's initial principal point (the sensor centre) is where the prism's apex images; cropping each half
   would start the principal point at the crop's centre, a quarter sensor away from it.
2. ``cv2.stereoCalibrateExtended`` on the corners seen in both halves: the right camera's pose relative to the
   left one (X_R = R X_L + T) and the board poses in the left camera's frame.
3. The frame. Zhang's method cannot see the real camera, only the two virtual ones; its world frame is the left
   virtual camera's. With ``reference_points`` (each view's board points in the real camera frame: a measured
   board pose, as the thesis' bench measured its targets, :mod:`prismstereo.baselines.targets`) the left
   camera's frame is registered to the real frame by the rigid transform that best maps the board points as
   Zhang reconstructed them (step 2's poses) onto their known positions (least squares, no scale): depths are
   then Z in the real camera frame, the thesis' origin (sec. 3.3.1: "the optical centre of the CCD camera was
   chosen as the origin"). Without them the left virtual camera's frame is the world (``frame == 'left'``).

Options, decided with ``benchmarks/thesis_tables.py`` (12 views of a 4 x 7-corner board of 6 mm at 550-850 mm
(setup 1) / 300-500 mm (setup 2), 512 x 384 px, ``--seed`` 0-3, ``--zhang-stereo``; depth error = mean over the
thesis' ten depths of the error of 50 exact correspondences near the common view's centre, triangulated with the
registered cameras):

* ``flags`` default ``CALIB_FIX_K3``: k1, k2, p1, p2, fx, fy, cx, cy free, the defaults of Bouguet's toolbox
  (the thesis' tool). A narrow-angle half-image hardly separates the principal point from the camera's rotation
  (a shift of cx by f dtheta looks like a turn by dtheta) nor the centre's distance from the focal length: per
  half, cx lands hundreds of pixels from the apex column at 512 x 384, the distortion coefficients come out large
  and the left centre millimetres off our least-squares one along the axis, the thesis' "quite high" standard
  deviations, while the board's corners are still reprojected to about a tenth of a pixel.
  ``CALIB_FIX_PRINCIPAL_POINT`` holds cx, cy at the sensor centre (a larger depth error here).
* ``stereo`` default ``'refine'``: ``stereoCalibrate`` re-estimates both cameras' intrinsics with their relative
  pose, every view's board pose shared by the two halves (as Bouguet's stereo calibration does), instead of
  ``'fix_intrinsic'`` (``CALIB_FIX_INTRINSIC``, only R and T). Over seeds 0-3 the two give the same depth error
  on average on both setups, 'refine' with the smaller spread.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, NamedTuple

import cv2
import numpy as np
import torch

from prismstereo.baselines.pinhole import Pinhole, PinholePair
from prismstereo.calibration.board import rigid_fit
from prismstereo.calibration.targets import Board, ViewDetection
from prismstereo.errors import CalibrationError, check_option

__all__ = ["Stereo", "ZhangResult", "calibrate_zhang", "check_image_size"]

F64 = torch.float64
Stereo = Literal["refine", "fix_intrinsic"]
_STEREO = ("refine", "fix_intrinsic")
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)


class ZhangResult(NamedTuple):
    """Zhang's calibration of both virtual cameras.

    Attributes:
        cameras: the left and right :class:`~prismstereo.baselines.pinhole.Pinhole` in the world frame.
        frame: 'real' (registered to the real camera frame by reference points) or 'left' (the left virtual
            camera's frame is the world).
        rms_px: (3,) RMS reprojection error of the left and right ``calibrateCamera`` and of ``stereoCalibrate``.
        rotation: (3, 3) OpenCV's R, left to right virtual camera (X_R = R X_L + T).
        translation: (3,) OpenCV's T (mm).
        registration_rms_mm: RMS distance of the registered board points to their reference positions (NaN for
            ``frame == 'left'``).
        views: indices of the views used (board in both halves).
    """

    cameras: PinholePair
    frame: str
    rms_px: torch.Tensor
    rotation: torch.Tensor
    translation: torch.Tensor
    registration_rms_mm: float
    views: tuple[int, ...]


def check_image_size(image_size: Sequence[int]) -> tuple[int, int]:
    """``(width, height)`` as two positive ints, else a :class:`~prismstereo.errors.CalibrationError`.

    Example:
        >>> check_image_size((512, 384))
        (512, 384)
    """
    try:
        w, h = (int(s) for s in image_size)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"image_size must be (width, height), got {image_size!r}") from exc
    if w < 1 or h < 1 or (w, h) != tuple(image_size):
        raise CalibrationError(f"image_size must be two positive ints (width, height), got {image_size!r}")
    return w, h


def _common(detection: ViewDetection) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Ids seen in both halves and their left / right pixels."""
    left, right = detection.left, detection.right
    ids = sorted(set(left.ids.tolist()) & set(right.ids.tolist()))
    li = {k: i for i, k in enumerate(left.ids.tolist())}
    ri = {k: i for i, k in enumerate(right.ids.tolist())}
    sel_l = torch.tensor([li[k] for k in ids], dtype=torch.int64)
    sel_r = torch.tensor([ri[k] for k in ids], dtype=torch.int64)
    return torch.tensor(ids, dtype=torch.int64), left.uv[sel_l], right.uv[sel_r]


def _f32(x: torch.Tensor, cols: int) -> np.ndarray:
    return x.detach().to(F64).numpy().astype(np.float32).reshape(-1, cols)


def calibrate_zhang(
    detections: Sequence[ViewDetection],
    board: Board,
    image_size: Sequence[int],
    *,
    flags: int = cv2.CALIB_FIX_K3,
    stereo: Stereo = "refine",
    reference_points: Sequence[torch.Tensor | None] | None = None,
    min_views: int = 3,
    min_common: int = 6,
) -> ZhangResult:
    """Calibrate both virtual cameras with Zhang's method, one half-image each (module docstring).

    Args:
        detections: one :class:`~prismstereo.calibration.targets.ViewDetection` per capture
            (:func:`~prismstereo.calibration.targets.detect_board`), full-sensor pixels.
        board: the target.
        image_size: (width, height) of the full sensor.
        flags: ``cv2.calibrateCamera`` flags of each half (also used by ``stereo='refine'``).
        stereo: 'refine' (``stereoCalibrate`` refines the intrinsics too) or 'fix_intrinsic'.
        reference_points: per capture, None or (board.num_points, 3) real-frame board points by id (NaN where
            unknown, :func:`~prismstereo.baselines.targets.reference_points`); registers the world frame to the
            real camera frame.
        min_views: captures with the board in both halves required.
        min_common: corners seen in both halves required for a capture to count.

    Returns:
        ZhangResult.

    Raises:
        CalibrationError: fewer than ``min_views`` usable captures, a bad image size, reference points of the
            wrong shape or too few, or a calibration OpenCV rejects.
        OptionError: unknown ``stereo``.

    Example:
        >>> from prismstereo.calibration import parse_target
        >>> calibrate_zhang([], parse_target("checkerboard:4x7:6"), (512, 384))
        Traceback (most recent call last):
        ...
        prismstereo.errors.CalibrationError: Zhang's method needs the board in both halves of ... got 0 of 0
    """
    check_option(stereo, _STEREO, "stereo")
    size = check_image_size(image_size)
    if reference_points is not None and len(reference_points) != len(detections):
        raise CalibrationError(f"reference_points must have one entry per detection ({len(detections)}), got "
                               f"{len(reference_points)}")
    views = _usable_views(detections, min_views, min_common)
    pts = board.points()
    per_half, common, (rms, k1, d1, k2, d2, r, t, _, _, rvecs, tvecs, _) = _calibrate_opencv(
        detections, views, pts, size, flags, stereo)
    r, t = torch.from_numpy(r).to(F64), torch.from_numpy(t).to(F64).reshape(3)
    rot_w, centre_w, reg_rms, frame = torch.eye(3, dtype=F64), torch.zeros(3, dtype=F64), float("nan"), "left"
    if reference_points is not None:
        rot_w, centre_w, reg_rms = _register(common, rvecs, tvecs, views, reference_points, board, pts)
        frame = "real"
    left = Pinhole(torch.from_numpy(k1).to(F64), torch.from_numpy(d1).to(F64).reshape(-1)[:5], rot_w, centre_w)
    right_rot = rot_w @ r.T  # X_L = R^T (X_R - T): the right camera's axes in the world
    right = Pinhole(torch.from_numpy(k2).to(F64), torch.from_numpy(d2).to(F64).reshape(-1)[:5], right_rot,
                    centre_w - right_rot @ t)
    rms_all = torch.tensor([per_half[0][0], per_half[1][0], float(rms)], dtype=F64)
    return ZhangResult(PinholePair(left, right), frame, rms_all, r, t, reg_rms, tuple(views))


def _usable_views(detections: Sequence[ViewDetection], min_views: int, min_common: int) -> list[int]:
    """The captures with at least ``min_common`` corners seen in both halves; at least ``min_views`` of them."""
    views = [i for i, d in enumerate(detections) if d.left is not None and d.right is not None
             and len(set(d.left.ids.tolist()) & set(d.right.ids.tolist())) >= min_common]
    if len(views) < min_views:
        raise CalibrationError(f"Zhang's method needs the board in both halves of at least {min_views} views, got "
                               f"{len(views)} of {len(detections)}")
    return views


def _calibrate_opencv(detections: Sequence[ViewDetection], views: list[int], pts: torch.Tensor,
                      size: tuple[int, int], flags: int, stereo: Stereo) -> tuple[list, list, tuple]:
    """Steps 1 and 2 of the module docstring: ``calibrateCamera`` per half ((rms, K, distortion) each), then
    ``stereoCalibrateExtended`` on the corners both halves see (:func:`_common` per view). Returns those two lists and
    OpenCV's stereo result tuple."""
    per_half = []
    try:
        for half in ("left", "right"):
            obj = [_f32(pts[getattr(detections[i], half).ids], 3) for i in views]
            img = [_f32(getattr(detections[i], half).uv, 2) for i in views]
            rms, k, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None, flags=flags, criteria=_CRITERIA)
            per_half.append((float(rms), k, dist))
        common = [_common(detections[i]) for i in views]
        obj = [_f32(pts[ids], 3) for ids, _, _ in common]
        stereo_flags = cv2.CALIB_FIX_INTRINSIC if stereo == "fix_intrinsic" else flags | cv2.CALIB_USE_INTRINSIC_GUESS
        result = cv2.stereoCalibrateExtended(
            obj, [_f32(uv, 2) for _, uv, _ in common], [_f32(uv, 2) for _, _, uv in common],
            per_half[0][1], per_half[0][2], per_half[1][1], per_half[1][2], size, None, None,
            flags=stereo_flags, criteria=_CRITERIA)
    except cv2.error as exc:
        raise CalibrationError(f"OpenCV rejected the calibration: {exc}") from exc
    return per_half, common, result


def _register(common: list, rvecs: Sequence[np.ndarray], tvecs: Sequence[np.ndarray], views: list[int],
              reference_points: Sequence[torch.Tensor | None], board: Board,
              pts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Step 3 of the module docstring: the rigid transform (rotation (3, 3), translation (3,)) that best maps the
    board points ``pts`` in the left camera's frame (stereo poses ``rvecs``, ``tvecs``) onto their known real-frame
    positions, and its RMS (mm)."""
    src, dst = [], []
    for (ids, _, _), rv, tv, i in zip(common, rvecs, tvecs, views, strict=True):
        ref = reference_points[i]
        if ref is None:
            continue
        if not isinstance(ref, torch.Tensor) or tuple(ref.shape) != (board.num_points, 3):
            raise CalibrationError(f"reference_points[{i}] must be a ({board.num_points}, 3) tensor, got "
                                   f"{getattr(ref, 'shape', type(ref).__name__)}")
        known = torch.isfinite(ref[ids]).all(dim=1)
        rot = torch.from_numpy(cv2.Rodrigues(np.asarray(rv, dtype=np.float64))[0])
        in_left = pts[ids] @ rot.T + torch.from_numpy(np.asarray(tv, dtype=np.float64)).reshape(1, 3)
        src.append(in_left[known])
        dst.append(ref[ids][known].to(F64))
    src_all, dst_all = (torch.cat(src), torch.cat(dst)) if src else (torch.zeros(0, 3), torch.zeros(0, 3))
    if src_all.shape[0] < 3 or torch.linalg.matrix_rank(src_all - src_all.mean(0)) < 2:
        raise CalibrationError("reference_points must give at least 3 non-collinear known board points over "
                               "the views to register the real frame")
    rot_w, centre_w = rigid_fit(src_all, dst_all)
    reg_rms = float((src_all @ rot_w.T + centre_w - dst_all).norm(dim=1).square().mean().sqrt())
    return rot_w, centre_w, reg_rms
