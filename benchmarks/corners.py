"""Corner accuracy of the board detection: OpenCV's own sub-pixel corners against the point-symmetry refinement.

Renders ``--views`` boards (550-850 mm, tilted up to 45 deg) through ``thesis_setup1`` and compares every detected
corner with the exact projection of its board point through its half (``project_points``), for both corner
methods of ``detect_board`` (``corners='opencv'`` / ``'symmetric'``), under several image formations: the
calibration benchmark's (3 x 3 supersampling, noise 2/255), heavier noise, Gaussian blur, vignetting, thin-lens
defocus, and Fresnel transmission. Prints the RMS, 95th percentile and maximum error (px) and the number of
corners found. The board is the calibration benchmark's ChArUco board (16 x 12 squares of 8 mm) or, with
``--board checkerboard``, a 5 x 8-square checkerboard of 6 mm.

    .venv/bin/python benchmarks/corners.py [--scale 2] [--views 6] [--board charuco]
"""

from __future__ import annotations

import argparse
import time

import torch

from prismstereo import thesis_setup1
from prismstereo.calibration import detect_board, parse_target
from prismstereo.geometry.projection import project_points
from prismstereo.synthetic import ImageFormation, calibration_views, render

CONDITIONS = {
    "noise 2/255 (calibration benchmark)": dict(noise_sigma=2 / 255),
    "noise 5/255": dict(noise_sigma=5 / 255),
    "blur sigma 1 px + noise 2/255": dict(blur_sigma_px=1.0, noise_sigma=2 / 255),
    "vignetting 1.0 + noise 2/255": dict(vignetting=1.0, noise_sigma=2 / 255),
    "thin lens f/6.25 at 600 mm + noise": dict(f_number=6.25, focus_mm=600.0, noise_sigma=2 / 255),
    "Fresnel + noise 2/255": dict(fresnel=True, noise_sigma=2 / 255),
    "8x8 supersampling, no noise": dict(supersample=8),
}


def true_corners(scene, board, kind: str) -> torch.Tensor:
    """(N, 3) real-frame positions of every inner corner of the board scene (any order)."""
    plane = scene.surfaces[0]
    if kind == "charuco":  # board point (x, y) sits at surface (x + 2 sq, y + 2 sq): margin + outer row
        p = board.points()
        off = 2 * board.square_mm
    else:  # checkerboard_target: inner corner (i, j) at (j + 1, i + 1) squares
        tex = plane.texture
        i, j = torch.meshgrid(torch.arange(tex.rows - 1.0), torch.arange(tex.cols - 1.0), indexing="ij")
        p = torch.stack([j.flatten(), i.flatten()], -1).double() * tex.square_mm
        off = tex.square_mm
    return plane.point + (p[:, :1] + off) * plane.u_axis + (p[:, 1:2] + off) * plane.v_axis


def errors(rig, scenes, images, board, kind: str, method: str) -> torch.Tensor:
    """Distances (px) from each detected corner to the nearest exact projection in its half."""
    out = []
    for scene, image in zip(scenes, images, strict=True):
        det = detect_board(image, rig, board, corners=method)
        x = true_corners(scene, board, kind)
        for half in ("left", "right"):
            found = getattr(det, half)
            if found is None:
                continue
            proj = project_points(rig, x, half)
            exact = proj.uv[proj.valid]
            out.append(torch.cdist(found.uv, exact).min(dim=1).values)
    return torch.cat(out) if out else torch.zeros(0, dtype=torch.float64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scale", type=int, default=2, help="sensor downscaling of setup 1 (1 = 1024 x 768)")
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument("--board", choices=("charuco", "checkerboard"), default="charuco")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    rig = thesis_setup1().downscaled(args.scale) if args.scale > 1 else thesis_setup1()
    if args.board == "charuco":
        board = parse_target("charuco:16x12:8:6:DICT_4X4_250")
        scenes = calibration_views(args.views, args.seed, kind="charuco", cols=16, rows=12, square_mm=8.0,
                                   spread_mm=(10.0, 10.0))
    else:
        board = parse_target("checkerboard:4x7:6")
        scenes = calibration_views(args.views, args.seed)
    print(f"setup 1 at {rig.image_width} x {rig.image_height}, {args.views} views of {board.describe()}")
    print(f"{'image formation':<38} {'method':<10} {'corners':>7} {'RMS px':>7} {'p95':>6} {'max':>6} {'s':>5}")
    for name, kwargs in CONDITIONS.items():
        caps = render(rig, scenes, ImageFormation(**{"seed": args.seed, **kwargs}))
        for method in ("opencv", "symmetric"):
            t0 = time.perf_counter()
            e = errors(rig, scenes, caps.image, board, args.board, method)
            dt = time.perf_counter() - t0
            if e.numel() == 0:  # the board not found in any view under this formation (small sensors, strong blur)
                print(f"{name:<38} {method:<10} {0:>7}  no corners found {dt:>19.1f}", flush=True)
                continue
            print(f"{name:<38} {method:<10} {e.numel():>7} {float(e.pow(2).mean().sqrt()):>7.4f} "
                  f"{float(e.quantile(0.95)):>6.3f} {float(e.max()):>6.3f} {dt:>5.1f}", flush=True)


if __name__ == "__main__":
    main()
