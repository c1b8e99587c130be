"""Calibration of a physical rig from its own captures (lens distortion, prism pose, alpha, n).

Data path: boards found in both half-images (:mod:`~prismstereo.calibration.targets`) -> the rig parameters to
estimate (:mod:`~prismstereo.calibration.parameters`) -> a bundle adjustment through the exact optics
(:mod:`~prismstereo.calibration.board`, solved by :mod:`~prismstereo.calibration.solver`) -> the calibrated rig
and its report (:mod:`~prismstereo.calibration.fit`, :mod:`~prismstereo.calibration.report`).
"""

from prismstereo.calibration.fit import DEFAULT_FIXED, CalibrationResult, calibrate_board
from prismstereo.calibration.parameters import NAMES
from prismstereo.calibration.targets import Board, HalfDetection, ViewDetection, detect_board, parse_target

__all__ = [
    "NAMES",
    "DEFAULT_FIXED",
    "Board",
    "HalfDetection",
    "ViewDetection",
    "CalibrationResult",
    "calibrate_board",
    "detect_board",
    "parse_target",
]
