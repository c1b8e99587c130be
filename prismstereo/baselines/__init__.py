"""Conventional baselines of the thesis' calibration comparison (sec. 3.3, Tables 4.3-4.4), with OpenCV.

Data path: board corners (:func:`~prismstereo.calibration.targets.detect_board`) and, where a method needs
them, their known real-frame positions (:mod:`~prismstereo.baselines.targets`) -> two pinhole virtual cameras
(:mod:`~prismstereo.baselines.pinhole`) from Zhang's method (:mod:`~prismstereo.baselines.zhang`) or a known 3-D
target (Tsai, :mod:`~prismstereo.baselines.tsai`) -> depth of matched pixel pairs by the mid-point theorem, with
those pinholes or the exact optics (:mod:`~prismstereo.baselines.triangulate`). ``benchmarks/thesis_tables.py``
regenerates the thesis' tables with them.
"""

from prismstereo.baselines.pinhole import (
    Pinhole,
    PinholePair,
    pinhole_from_opencv,
    pinhole_from_virtual,
    project_pinhole,
)
from prismstereo.baselines.targets import checkerboard_corners, reference_points
from prismstereo.baselines.triangulate import Triangulation, pinhole_rays, triangulate_exact, triangulate_pinholes
from prismstereo.baselines.tsai import TsaiCamera, TsaiResult, calibrate_tsai, tsai_camera
from prismstereo.baselines.zhang import Stereo, ZhangResult, calibrate_zhang, check_image_size

__all__ = [
    "Pinhole",
    "PinholePair",
    "pinhole_from_opencv",
    "pinhole_from_virtual",
    "project_pinhole",
    "checkerboard_corners",
    "reference_points",
    "Triangulation",
    "pinhole_rays",
    "triangulate_exact",
    "triangulate_pinholes",
    "TsaiCamera",
    "TsaiResult",
    "calibrate_tsai",
    "tsai_camera",
    "Stereo",
    "ZhangResult",
    "calibrate_zhang",
    "check_image_size",
]
