"""Boards rendered through setup 1 at quarter resolution, shared by the baseline tests (rendered once)."""

from __future__ import annotations

from typing import NamedTuple

import pytest

from prismstereo import thesis_setup1
from prismstereo.baselines import checkerboard_corners, reference_points
from prismstereo.calibration import detect_board, parse_target
from prismstereo.synthetic import ImageFormation, calibration_views, render
from prismstereo.threads import torch_threads

BOARD = parse_target("checkerboard:4x7:6")
RIG = thesis_setup1().downscaled(4)  # 256 x 192
SIZE = (RIG.image_width, RIG.image_height)


class BoardViews(NamedTuple):
    scenes: list
    detections: list
    references: list


@pytest.fixture(scope="session")
def board_views() -> BoardViews:
    """Eight 4 x 7-corner boards (550-850 mm, tilted up to 45 deg), detected in both halves, with their true
    real-frame corners by id."""
    with torch_threads(1):
        scenes = calibration_views(8, seed=0)
        caps = render(RIG, scenes, ImageFormation(supersample=3, noise_sigma=1 / 255, seed=0))
        dets = [detect_board(image, RIG, BOARD) for image in caps.image]
        refs = [reference_points(RIG, checkerboard_corners(s), d, BOARD) for s, d in zip(scenes, dets, strict=True)]
    return BoardViews(scenes, dets, refs)
