"""Video: frame times of the depth graph in onnxruntime through ``DepthStream`` against OpenCV's StereoSGBM and
StereoBM on the same moving sequence, and frame-to-frame flicker on a static scene.

1. **Moving sequence**: ``--frames`` captures of a noise-textured plane slanted 30 deg about y whose centre moves
   from 525 to 575 mm while its slant turns by 10 deg (2 x 2 supersampling, read noise 1/255, 8 bits), through
   ``thesis_setup1`` at 1024 x 768 and the same optics on a 640 x 480 sensor (pixels 1.6x larger: the common
   endoscope size). Every frame goes through ``DepthStream`` (the default ``PrismStereo`` over 228-1374 mm,
   exported once, onnxruntime with 2 intra-op threads) and through OpenCV's ``StereoSGBM`` (numDisparities covering
   the range's correspondence spread, blockSize 5, else defaults) and ``StereoBM`` (same) on the two 8-bit halves,
   one method after the other per frame, 0.1 s apart (``cv2.setNumThreads(2)``). Printed per method: median and
   95th-percentile ms per frame, frames/s, the median over frames of the same-frame ratio to SGBM, and the mean
   relative depth error and coverage over the co-visible reference pixels (OpenCV's disparities converted to depth
   through the exact sweep, as ``benchmarks/onnx_speed.py``).
2. **Flicker**: ``--static`` captures of a textured plane at 600 mm that differ only in their noise (read noise
   2/255, a new seed per frame): per pixel valid in every frame, the standard deviation of depth over the frames;
   the median over pixels (mm and % of depth) for the per-frame model and for SGBM.

Every frame is processed on its own (the library has no temporal prior yet).

Run: .venv/bin/python benchmarks/video_speed.py [--frames 20] [--static 30] [--sizes 1024 640]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from onnx_speed import opencv_depth, opencv_halves, pixel_sweep, score, spread_report  # noqa: E402

from prismstereo import thesis_setup1  # noqa: E402
from prismstereo.export import export_onnx  # noqa: E402
from prismstereo.model import PrismStereo  # noqa: E402
from prismstereo.stream import DepthStream  # noqa: E402
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render, slanted_plane  # noqa: E402

Z_RANGE = (228.0, 1374.0)


def sensor(width: int):
    """``thesis_setup1``'s optics on a ``width``-column sensor of the same aspect and field of view."""
    base = thesis_setup1()
    factor = base.image_width / width
    return base.replace(image_width=width, image_height=round(base.image_height / factor),
                        pixel_size_mm=base.pixel_size_mm * factor, principal_point=None)


def disparities(sweep) -> int:
    """numDisparities (a multiple of 16) covering the match's move along u over the range."""
    from prismstereo.epipolar.sweep import chebyshev_basis

    coef = sweep.coefficients[..., 0]
    n = coef.shape[0]
    ends = (chebyshev_basis(torch.tensor([-1.0, 1.0], dtype=torch.float64), n) @ coef.reshape(n, -1))
    spread = float((ends[0] - ends[1]).abs().view(coef.shape[1:])[sweep.inside].max())
    return 16 * int(np.ceil((spread + 8) / 16))


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def moving(rig, frames: int, tmp: Path) -> None:
    scenes = [slanted_plane(rig, 525.0 + 50.0 * k / max(1, frames - 1), 25.0 + 10.0 * k / max(1, frames - 1),
                            seed=11) for k in range(frames)]
    caps = render(rig, scenes, ImageFormation(supersample=2, noise_sigma=1 / 255, seed=3))
    model = PrismStereo(rig, Z_RANGE).eval()
    stream = DepthStream(export_onnx(model, tmp / f"model_{rig.image_width}.onnx"), threads=2)
    split = rig.reference_width
    sweep = pixel_sweep(rig, Z_RANGE)
    first = type("C", (), {"covisible": caps.covisible[:1], "match_uv": caps.match_uv[:1], "depth": caps.depth[:1]})
    _, mirror = spread_report(sweep, first)
    nd = disparities(sweep)
    matchers = {"StereoSGBM": cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd, blockSize=5),
                "StereoBM": cv2.StereoBM_create(numDisparities=nd, blockSize=5)}
    times: dict[str, list[float]] = {"prismstereo ONNX": [], **{k: [] for k in matchers}}
    errors: dict[str, list[tuple[float, float]]] = {k: [] for k in times}
    stream.push(caps.image[0])  # warm-up
    for k in range(frames):
        image = caps.image[k:k + 1]
        capture = type("C", (), {"depth": caps.depth[k:k + 1], "covisible": caps.covisible[k:k + 1]})
        time.sleep(0.1)
        res = stream.push(image[0])
        times["prismstereo ONNX"].append(res.milliseconds)
        mean, _, cover = score(res.depth, res.valid, capture, split)
        errors["prismstereo ONNX"].append((mean, cover))
        left, right = opencv_halves(image, split, mirror)
        for name, matcher in matchers.items():
            time.sleep(0.1)
            t0 = time.perf_counter()
            disparity = matcher.compute(left, right)
            times[name].append(1e3 * (time.perf_counter() - t0))
            depth, valid = opencv_depth(sweep, disparity, mirror)
            mean, _, cover = score(depth, valid & sweep.inside, capture, split)
            errors[name].append((mean, cover))
    print(f"\n{rig.image_width} x {rig.image_height}, {frames} frames, range {Z_RANGE[0]:g}-{Z_RANGE[1]:g} mm, "
          f"model: {model.summary()}; OpenCV numDisparities {nd}")
    print(f"{'method':18s} {'median ms':>9s} {'p95 ms':>7s} {'frames/s':>8s} {'x SGBM':>7s} {'mean err %':>10s} "
          f"{'coverage %':>10s}")
    sgbm = times["StereoSGBM"]
    for name, t in times.items():
        ratio = statistics.median(a / b for a, b in zip(t, sgbm, strict=True))
        mean = statistics.mean(e[0] for e in errors[name])
        cover = statistics.mean(e[1] for e in errors[name])
        print(f"{name:18s} {statistics.median(t):9.1f} {percentile(t, 95):7.1f} {1e3 / statistics.median(t):8.1f} "
              f"{ratio:7.2f} {mean:10.3f} {cover:10.1f}")


def flicker(rig, frames: int, tmp: Path) -> None:
    scene = fronto_parallel_plane(rig, 600.0, seed=4)
    caps = [render(rig, scene, ImageFormation(supersample=2, noise_sigma=2 / 255, seed=100 + k)) for k in range(frames)]
    model = PrismStereo(rig, Z_RANGE).eval()
    stream = DepthStream(export_onnx(model, tmp / f"flicker_{rig.image_width}.onnx"), threads=2)
    split = rig.reference_width
    sweep = pixel_sweep(rig, Z_RANGE)
    _, mirror = spread_report(sweep, caps[0])
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=disparities(sweep), blockSize=5)
    depth = {"prismstereo ONNX": [], "StereoSGBM": []}
    valid = {"prismstereo ONNX": [], "StereoSGBM": []}
    for cap in caps:
        res = stream.push(cap.image[0])
        depth["prismstereo ONNX"].append(res.depth[0, 0].double())
        valid["prismstereo ONNX"].append(res.valid[0, 0])
        d, v = opencv_depth(sweep, sgbm.compute(*opencv_halves(cap.image, split, mirror)), mirror)
        depth["StereoSGBM"].append(d)
        valid["StereoSGBM"].append(v & sweep.inside)
    covisible = caps[0].covisible[0, 0, :, :split]
    print(f"\nflicker, {rig.image_width} x {rig.image_height}: plane at 600 mm, {frames} frames differing in their "
          "noise")
    for name in depth:
        stack, ok = torch.stack(depth[name]), torch.stack(valid[name]).all(0) & covisible
        std = stack.std(0)[ok]
        rel = (std / stack.mean(0)[ok]) * 100
        print(f"{name:18s} median std over frames {float(std.median()):.3f} mm ({float(rel.median()):.4f} %), "
              f"95th percentile {float(std.quantile(0.95)):.3f} mm, on {100 * float(ok.sum() / covisible.sum()):.1f} % "
              "of the co-visible pixels (valid in every frame)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=20, help="frames of the moving sequence")
    parser.add_argument("--static", type=int, default=30, help="frames of the flicker measurement (0 skips it)")
    parser.add_argument("--sizes", type=int, nargs="+", default=(1024, 640), help="sensor widths")
    args = parser.parse_args()
    torch.set_num_threads(2)
    cv2.setNumThreads(2)
    with tempfile.TemporaryDirectory() as folder:
        for width in args.sizes:
            rig = sensor(width)
            moving(rig, args.frames, Path(folder))
            if args.static:
                flicker(rig, args.static, Path(folder))


if __name__ == "__main__":
    main()
