"""Calibration of a physical rig from its own captures (lens distortion, prism pose, alpha, n).

Data path: boards found in both half-images (:mod:`~prismstereo.calibration.targets`) -> the rig parameters to
estimate (:mod:`~prismstereo.calibration.parameters`) -> a bundle adjustment through the exact optics
(:mod:`~prismstereo.calibration.board`, solved by :mod:`~prismstereo.calibration.solver` on the structure of
:mod:`~prismstereo.calibration.problem`) -> the calibrated rig and its report (:mod:`~prismstereo.calibration.fit`,
:mod:`~prismstereo.calibration.report`). Without a target: correspondences between the halves and the exact
epipolar curves (:mod:`~prismstereo.calibration.selfcal`); both together in one bundle adjustment
(:mod:`~prismstereo.calibration.joint`).
"""

from prismstereo.calibration.fit import DEFAULT_FIXED, CalibrationResult, calibrate_board
from prismstereo.calibration.joint import JointReport, calibrate_joint
from prismstereo.calibration.parameters import NAMES
from prismstereo.calibration.selfcal import Correspondences, calibrate_self, find_correspondences
from prismstereo.calibration.targets import Board, HalfDetection, ViewDetection, detect_board, parse_target

__all__ = [
    "NAMES",
    "DEFAULT_FIXED",
    "Board",
    "HalfDetection",
    "ViewDetection",
    "CalibrationResult",
    "calibrate_board",
    "calibrate_joint",
    "JointReport",
    "calibrate_self",
    "Correspondences",
    "find_correspondences",
    "detect_board",
    "parse_target",
]
