"""Small renders of boards through misaligned rigs, shared by the calibration tests (quarter resolution)."""

from __future__ import annotations

from prismstereo import thesis_setup1
from prismstereo.calibration import parse_target
from prismstereo.synthetic import ImageFormation, calibration_views, render

BOARD = parse_target("checkerboard:4x7:6")
NOMINAL = thesis_setup1().downscaled(4)  # 256 x 192


def board_scenes(n: int, seed: int):
    """``n`` checkerboards (5 x 8 squares of 6 mm) tilted up to 45 deg, inside setup 1's common field of view."""
    return calibration_views(n, seed)


def board_captures(rig, n: int = 8, seed: int = 0):
    return render(rig, board_scenes(n, seed), ImageFormation(supersample=3, noise_sigma=2 / 255, seed=seed))
