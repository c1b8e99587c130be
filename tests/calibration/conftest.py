"""Small renders of boards through misaligned rigs, shared by the calibration tests (quarter resolution)."""

from __future__ import annotations

import torch

from prismstereo import thesis_setup1
from prismstereo.calibration import parse_target
from prismstereo.synthetic import ImageFormation, checkerboard_target, render

BOARD = parse_target("checkerboard:4x7:6")
NOMINAL = thesis_setup1().downscaled(4)  # 256 x 192


def board_scenes(n: int, seed: int, depth_range=(550.0, 850.0)):
    """``n`` checkerboards (5 x 8 squares of 6 mm) tilted up to 45 deg about x and y, inside the common field of
    view of setup 1's halves."""
    g = torch.Generator().manual_seed(seed)
    scenes = []
    for _ in range(n):
        z = depth_range[0] + (depth_range[1] - depth_range[0]) * float(torch.rand(1, generator=g))
        rx, ry, rz = ((torch.rand(3, generator=g) * 2 - 1) * torch.tensor([45.0, 45.0, 10.0])).tolist()
        x, y = ((torch.rand(2, generator=g) * 2 - 1) * torch.tensor([3.0, 15.0])).tolist()
        scenes.append(checkerboard_target((x, y, z), (rx, ry, rz), rows=8, cols=5, square_mm=6.0))
    return scenes


def board_captures(rig, n: int = 8, seed: int = 0):
    return render(rig, board_scenes(n, seed), ImageFormation(supersample=3, noise_sigma=2 / 255, seed=seed))
