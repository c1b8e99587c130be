"""The matcher on real photographs: ``prismstereo match``'s matcher vs OpenCV on the Middlebury pairs.

Prints, for the Tsukuba and Venus pairs of shared/data/middlebury (their README gives the ground truth's scale)
and scikit-image's Motorcycle (Middlebury 2014, 741 x 500, sub-pixel truth; held out from every training),
bad>1px (percentage of pixels with ground truth whose disparity is off by more than 1 px; missing output counts as
bad: for prismstereo the pixels neither valid nor filled, for OpenCV its invalid value), the ratio to StereoSGBM
and the time per pair (2 threads; other jobs on the machine make the times longer), side by side for:

* prismstereo: :func:`~prismstereo.classical.rectified.match_rectified` with the default ``MatchOptions`` (the depth
  model's shift volume and decision with the matcher's config: truncated colour + gradient cost, guided-filter
  aggregation; then the matcher's own post-processing: sub-pixel fit on the colour difference, left-right check,
  background fill, medians, colour-weighted median);
* OpenCV StereoSGBM and StereoBM with the settings of shared/data/middlebury/README.md.

The current figures are in docs/benchmarks.md (``benchmarks/report.py --only middlebury`` reruns this script and
rewrites that section).

Run: .venv/bin/python benchmarks/middlebury.py
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import torch

from prismstereo.classical.rectified import match_rectified
from prismstereo.threads import set_torch_threads

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"
SCENES = {"Tsukuba": ("disp_gt.pgm", 16.0, 16), "Venus": ("disp_gt.png", 8.0, 32), "Motorcycle": (None, 1.0, 64)}
"""name -> (ground-truth file, its scale, disparities searched); Motorcycle's comes from scikit-image."""


def pair(scene: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(left, right) uint8 (H, W, 3) RGB and the ground-truth disparity (H, W) float32, 0 where unknown."""
    if scene == "Motorcycle":
        import skimage.data

        left, right, disparity = skimage.data.stereo_motorcycle()
        return left, right, np.where(np.isfinite(disparity), disparity, 0.0).astype(np.float32)
    gt_name, scale, _ = SCENES[scene]
    folder = DATA / scene
    left, right = (cv2.cvtColor(cv2.imread(str(folder / f"img_{s}.png")), cv2.COLOR_BGR2RGB) for s in ("left", "right"))
    return left, right, cv2.imread(str(folder / gt_name), cv2.IMREAD_UNCHANGED).astype(np.float32) / scale


def bad_percent(disparity: np.ndarray, valid: np.ndarray, gt: np.ndarray) -> float:
    """bad>1px over pixels with ground truth, invalid output counted as bad."""
    known = gt > 0
    wrong = (np.abs(disparity - gt) > 1.0) | ~valid
    return 100.0 * float(wrong[known].mean())


def main() -> None:
    set_torch_threads(2)
    cv2.setNumThreads(2)
    print(f"{'scene':10s} {'method':27s} {'bad>1px %':>10s} {'x SGBM':>8s} {'ms':>8s}")
    for scene, (_, _, num_disp) in SCENES.items():
        rgb_l, rgb_r, gt = pair(scene)
        left, right = (torch.from_numpy(x).permute(2, 0, 1).float() / 255 for x in (rgb_l, rgb_r))
        match_rectified(left[None], right[None], num_disp)  # warm-up
        t0 = time.perf_counter()
        res = match_rectified(left[None], right[None], num_disp)
        ms = (time.perf_counter() - t0) * 1e3
        ours = bad_percent(res.disparity[0, 0].numpy(), (res.valid | res.filled)[0, 0].numpy(), gt)
        rows = [("prismstereo (guided filter)", ours, ms)]
        grey_l, grey_r = (cv2.cvtColor(x, cv2.COLOR_RGB2GRAY) for x in (rgb_l, rgb_r))
        for name, matcher in (
            ("OpenCV StereoSGBM", cv2.StereoSGBM_create(0, num_disp, 5, P1=200, P2=800, uniquenessRatio=5,
                                                        speckleWindowSize=0)),
            ("OpenCV StereoBM", cv2.StereoBM_create(num_disp, 11)),
        ):
            t0 = time.perf_counter()
            disp = matcher.compute(grey_l, grey_r).astype(np.float32) / 16.0
            ms = (time.perf_counter() - t0) * 1e3
            rows.append((name, bad_percent(disp, disp >= 0, gt), ms))
        sgbm = rows[1][1]
        for name, bad, ms in rows:
            print(f"{scene:10s} {name:27s} {bad:10.2f} {bad / sgbm:8.2f} {ms:8.0f}")


if __name__ == "__main__":
    main()
