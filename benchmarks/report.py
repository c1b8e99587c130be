"""Regenerate ``docs/benchmarks.md``: run the benchmark scripts and write their tables, with the command that
produced each, the date and the machine.

Each benchmark is one section of the file, between ``<!-- benchmark: NAME -->`` and ``<!-- end: NAME -->``
markers; ``--only NAME ...`` re-runs those sections and keeps the others as they are, so a slow benchmark need
not run again to refresh a fast one. ``--log NAME=FILE`` takes a section's output from a file written earlier by
the same command (``python benchmarks/X.py ... > FILE``) instead of running it. Timings depend on what else the
machine does: run the timing benchmarks (``onnx_speed``, ``video_speed``) on an otherwise idle machine.

Run: .venv/bin/python benchmarks/report.py [--only NAME ...] [--log NAME=FILE ...] [--list] [--out docs/benchmarks.md]
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[1]


class Benchmark(NamedTuple):
    """One section: the script and its arguments, and what it measures."""

    script: str
    args: tuple[str, ...]
    title: str
    about: str


# the dense preset's valid pixels at a lower confidence threshold: what min_confidence trades
DENSE_AT_01 = 'dense c>=0.1={"preset": "dense", "min_confidence": 0.1}'
BENCHMARKS: dict[str, Benchmark] = {
    "depth_targets": Benchmark(
        "depth_targets.py", (), "Depth on the thesis' planes, slanted plane and step (both setups)",
        "Mean / median relative depth error, share off by > 2 %, coverage of the co-visible pixels and false matches "
        "of the default model at 1024 x 768, searched 205-1511 mm; 8-bit renders with read noise 1/255."),
    "dense_depth": Benchmark(
        "dense_depth.py", ("--model", DENSE_AT_01),
        "Dense depth on weak texture, photographs and defocus (1024 x 768)",
        "Held-out captures (Middlebury photographs as height fields, a weakly textured surface, thin-lens defocus, "
        "Fresnel, read noise 2/255): coverage, bad > 1 %, mean error per model, the reliability of the "
        "confidence, and the photographs' errors by distance to a depth jump."),
    "dense_depth_512": Benchmark(
        "dense_depth.py", ("--scale", "2", "--model", DENSE_AT_01),
        "Dense depth on weak texture, photographs and defocus (512 x 384)",
        "The same captures on a 512 x 384 sensor, where the default is one coarse-to-fine level."),
    "onnx_speed": Benchmark(
        "onnx_speed.py", (), "Speed against OpenCV (torch, onnxruntime, StereoSGBM, StereoBM)",
        "Interleaved rounds on 2 threads, 1024 x 768; ratios are medians of same-round ratios to StereoSGBM."),
    "video_speed": Benchmark(
        "video_speed.py", (), "Video: frame times, accuracy and flicker",
        "Per frame and with the temporal prior in onnxruntime against OpenCV (a moving slanted plane, a depth step "
        "entering the view, a cut) at 1024 x 768 and 640 x 480, and the per-pixel depth flicker of a static plane "
        "over 30 noisy frames. `temporal ONNX` is the default temporal graph (`TemporalOptions()`: the band on the "
        "2 x 2-binned frame for the 1024 x 768 pyramid, at full resolution for the one-level 640 x 480 model), "
        "`temporal k=...` the band at the other resolution and, at 1024 x 768, on the 3 x 3-binned frame "
        "(`--temporal-binning 3`); `hybrid keys` the hybrid's key frames tracked by those bands (what `prismstereo "
        "depth` runs). What the numbers mean: usage.md, *Video and streams*. First, `prismstereo depth` end to end "
        "on a video and on 16 captures (1 and 2 worker processes)."),
    "startup": Benchmark(
        "startup.py", (), "Start-up",
        "One 1024 x 768 capture through `prismstereo depth`, a new process per run as a user runs it: the first ONNX "
        "run (the model built, its graphs exported), the same command again (the remembered graphs through the "
        "torch-free pipeline) and the torch backend; with bytecode written and with `PYTHONDONTWRITEBYTECODE=1`. "
        "Wall time and the process's peak resident memory."),
    "keyframe_interval": Benchmark(
        "keyframe_interval.py", (), "Video: the key-frame interval of the temporal prior",
        "A 240-frame smooth sequence (back and forth over the moving plane) through the temporal ONNX stream as "
        "`prismstereo depth` runs it (the hybrid's key frames, the classical band between them) with key frames at "
        "least every 30, 60 and 120 frames: time per frame, depth error and coverage."),
    "hybrid_budget": Benchmark(
        "hybrid_budget.py", (), "The time budget of a hybrid chain (block mode + a learned refinement stage)",
        "Untrained candidate refinement stages (warp + dilated 3 x 3 CNN) at 1/2 and full resolution beside the "
        "classical block mode in onnxruntime, against StereoSGBM in the same interleaved rounds, 1024 x 768: which "
        "stage sizes keep the chain within 0.8x SGBM."),
    "learned_start": Benchmark(
        "learned_start.py", (), "The learned first stage against the classical block level",
        "Where each first stage leaves the hybrid's refinement on held-out photographs as surfaces and a weakly "
        "textured surface (1024 x 768, 228-1374 mm): the share of reliable co-visible blocks on the 4 x 4-binned grid "
        "whose start is within 1, 2 (the refinement's cost curve) and 4 steps of the truth; then each one's exported "
        "graph against StereoSGBM in the same interleaved rounds."),
    "default_chain": Benchmark(
        "default_chain.py", ("--plot", "docs/frontier.png"), "One dense, exact and fast default: every chain",
        "Photographs as surfaces (Tsukuba, Venus, Motorcycle), textured planes (at 1024 x 768 through both setups), "
        "weak texture and defocus, 228-1374 mm, on three sensors: thesis setup 1 at 512 x 384 and 1024 x 768, and a "
        "1920 x 1080 rig no training saw. Valid and dense coverage with their bad > 1 % shares, the share a confidence "
        "threshold keeps at <= 3 % bad, the reliability of each chain's confidence per band, and each chain's "
        "exported graph against StereoSGBM on each sensor in the same run. `hybrid` is the default (the learned "
        "first stage, learned stages, the exact last stage and its confidence head), `hybrid-learned` the same "
        "without its exact last stage (and so without the head), `hybrid-block` the previous default: its stages "
        "started from the classical block level (`block`) and trained on its estimates. The hybrid is the "
        "default of `prismstereo depth` (captures) and `prismstereo export` from 512 x 384 up "
        "(`prismstereo.models.default_kind`: all three sensors here); its stages run where the classical default "
        "fits its band (2 x 2 bins at 1024 x 768 and 1920 x 1080, the full sensor at 512 x 384).\n\n"
        "![time against the photographs' share kept at <= 3 % bad, every chain](frontier.png)"),
    "middlebury": Benchmark(
        "middlebury.py", (), "The rectified matcher on the Middlebury pairs",
        "bad > 1 px (missing output counts as bad) against OpenCV StereoSGBM / StereoBM."),
    "joint_calibration": Benchmark(
        "joint_calibration.py", (), "Calibration from the board users have: checkerboard views and scenes",
        "The calibration issue's rig (k1 -0.3, principal point off by (+3, -2) px, prism shifted 0.4 mm, T_o + 2 mm, "
        "alpha + 0.1 deg) at 1024 x 768, calibrated from the nominal rig with 12 ChArUco views, 3 textured scenes "
        "alone, 10 views of a 7 x 5 checkerboard of 5 mm (tilted up to 35 deg) and those views with the scenes in "
        "one bundle adjustment: depth error on two fresh planes, the uncertainty each calibration predicts for "
        "itself and the solve's time (2 threads)."),
    "thesis_tables": Benchmark(
        "thesis_tables.py", (), "The thesis' tables: virtual cameras, calibration, depth",
        "The thesis' published numbers beside the exact optics' and the calibration's."),
}


def _machine() -> str:
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").exists() else ""
    return f"{os.cpu_count()} cores ({cpu}), Python {platform.python_version()}, {platform.system()}"


def run(name: str, log: Path | None = None) -> str:
    """The section of benchmark ``name``: its output (run now, or read from ``log``) under its command."""
    bench = BENCHMARKS[name]
    command = [".venv/bin/python", f"benchmarks/{bench.script}", *bench.args]
    if log is not None:
        output, how = log.read_text(), f"output read from {log.name}"
    else:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / bench.script), *bench.args], cwd=ROOT,
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise SystemExit(f"{name} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
        output, how = proc.stdout, f"ran in {time.perf_counter() - t0:.0f} s"
    lines = [line.rstrip() for line in output.splitlines() if "Warning" not in line and "warnings.warn" not in line]
    day = datetime.date.today().isoformat()
    return "\n".join([
        f"<!-- benchmark: {name} -->", f"## {bench.title}", "", bench.about, "",
        f"`{shlex.join(command)}` ({day}, {how})", "", "```", *lines, "```", f"<!-- end: {name} -->"])


def _sections(text: str) -> dict[str, str]:
    pattern = re.compile(r"<!-- benchmark: (\w+) -->.*?<!-- end: \1 -->", re.S)
    return {m.group(1): m.group(0) for m in pattern.finditer(text)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="+", choices=sorted(BENCHMARKS), help="re-run these sections only")
    parser.add_argument("--log", nargs="+", action="extend", default=[], metavar="NAME=FILE",
                        help="a section's output from a file written earlier by its command")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks.md")
    parser.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    args = parser.parse_args()
    if args.list:
        for name, bench in BENCHMARKS.items():
            print(f"{name:16s} " + shlex.join(["benchmarks/" + bench.script, *bench.args]) + f": {bench.title}")
        return
    logs: dict[str, Path] = {}
    for item in args.log:
        name, _, file = item.partition("=")
        if name not in BENCHMARKS or not file or not Path(file).is_file():
            parser.error(f"--log takes NAME=FILE with NAME one of {', '.join(BENCHMARKS)} and an existing file, "
                         f"got {item!r}")
        logs[name] = Path(file)
    old = _sections(args.out.read_text()) if args.out.exists() else {}
    todo = set(args.only or BENCHMARKS) | set(logs)
    sections = {}
    for name in BENCHMARKS:
        if name in todo:
            print(f"{name} ...", flush=True)
            sections[name] = run(name, logs.get(name))
        elif name in old:
            sections[name] = old[name]
    header = ("# Benchmarks\n\nThe current tables of the benchmark scripts, written by `benchmarks/report.py` (not by "
              "hand): each section gives the command that printed it and when. What the numbers mean and which "
              "defaults they chose: [design.md](design.md).\n\n"
              f"Machine of the last run: {_machine()}.\n")
    args.out.write_text(header + "\n" + "\n\n".join(sections.values()) + "\n")
    print(f"wrote {args.out} ({', '.join(sections)})")


if __name__ == "__main__":
    main()
