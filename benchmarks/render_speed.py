"""Rendering time of synthetic captures on this machine (issue: a 1024x768 capture with 3x3 supersampling
renders in seconds). Prints the median of --repeats runs for each scene, split into the image (radiance
with supersampling) and the ground truth (depth, points, co-visibility with exact re-projection).

Run: .venv/bin/python benchmarks/render_speed.py
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from prismstereo import thesis_setup1
from prismstereo.synthetic import (
    ImageFormation,
    checkerboard_target,
    fronto_parallel_plane,
    middlebury_scene,
    render,
    slanted_plane,
    sphere_scene,
    step_scene,
)
from prismstereo.threads import set_torch_threads

MIDDLEBURY = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury" / "Tsukuba"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--supersample", type=int, default=3)
    args = parser.parse_args()
    set_torch_threads(2)
    rig = thesis_setup1()
    scenes = [
        fronto_parallel_plane(rig, 525.0),
        slanted_plane(rig, 600.0, 30.0),
        step_scene(rig, 400.0, 600.0),
        sphere_scene(rig, 450.0, 40.0, 650.0),
        checkerboard_target((0.0, 0.0, 600.0), (10.0, -20.0, 5.0)),
    ]
    if MIDDLEBURY.exists():
        scenes.append(middlebury_scene(MIDDLEBURY))
    formation = ImageFormation(supersample=args.supersample, noise_sigma=1 / 255)
    print(f"1024x768 thesis_setup1, {args.supersample}x{args.supersample} supersampling, median of {args.repeats}")
    print(f"{'scene':28s} {'total s':>8s} {'valid':>7s} {'co-visible (left)':>18s}")
    for scene in scenes:
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            cap = render(rig, scene, formation)
            times.append(time.perf_counter() - t0)
        covis = cap.covisible.float().sum() / cap.left.float().sum()
        print(f"{scene.name:28s} {statistics.median(times):8.2f} {cap.valid.float().mean():7.1%} {covis:18.1%}")


if __name__ == "__main__":
    main()
