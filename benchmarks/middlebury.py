"""The matcher on real photographs: prismstereo's rectified-pair matcher vs OpenCV on the Middlebury pairs.

Prints bad>1px (percentage of pixels with ground truth whose disparity is off by more than 1 px; invalid
output counts as bad) and the time per pair, for prismstereo (default MatchOptions) and OpenCV
StereoSGBM / StereoBM with the settings of shared/data/middlebury/README.md, side by side.

Run: .venv/bin/python benchmarks/middlebury.py
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import torch

from prismstereo.io import read_image
from prismstereo.matching.rectified import match_rectified

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"
SCENES = {"Tsukuba": ("disp_gt.pgm", 16.0, 16), "Venus": ("disp_gt.png", 8.0, 32)}


def bad_percent(disparity: np.ndarray, valid: np.ndarray, gt: np.ndarray) -> float:
    """bad>1px over pixels with ground truth, invalid output counted as bad."""
    known = gt > 0
    wrong = (np.abs(disparity - gt) > 1.0) | ~valid
    return 100.0 * float(wrong[known].mean())


def main() -> None:
    torch.set_num_threads(2)
    cv2.setNumThreads(2)
    print(f"{'scene':8s} {'method':22s} {'bad>1px %':>10s} {'ms':>8s}")
    for scene, (gt_name, scale, num_disp) in SCENES.items():
        folder = DATA / scene
        gt = cv2.imread(str(folder / gt_name), cv2.IMREAD_UNCHANGED).astype(np.float32) / scale
        left, right = read_image(folder / "img_left.png"), read_image(folder / "img_right.png")
        t0 = time.perf_counter()
        res = match_rectified(left[None], right[None], num_disp)
        ms = (time.perf_counter() - t0) * 1e3
        ours = bad_percent(res.disparity[0, 0].numpy(), res.valid[0, 0].numpy(), gt)
        print(f"{scene:8s} {'prismstereo (census+SGM)':22s} {ours:10.2f} {ms:8.0f}")
        grey_l = cv2.imread(str(folder / "img_left.png"), cv2.IMREAD_GRAYSCALE)
        grey_r = cv2.imread(str(folder / "img_right.png"), cv2.IMREAD_GRAYSCALE)
        for name, matcher in (
            ("OpenCV StereoSGBM", cv2.StereoSGBM_create(0, num_disp, 5, P1=200, P2=800, uniquenessRatio=5,
                                                        speckleWindowSize=0)),
            ("OpenCV StereoBM", cv2.StereoBM_create(num_disp, 11)),
        ):
            t0 = time.perf_counter()
            disp = matcher.compute(grey_l, grey_r).astype(np.float32) / 16.0
            ms = (time.perf_counter() - t0) * 1e3
            print(f"{scene:8s} {name:22s} {bad_percent(disp, disp >= 0, gt):10.2f} {ms:8.1f}")


if __name__ == "__main__":
    main()
