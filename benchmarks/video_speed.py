"""Video: frame times of the depth graph in onnxruntime through ``DepthStream``, per frame and with the temporal
prior, against OpenCV's StereoSGBM and StereoBM on the same moving sequences, and frame-to-frame flicker on a
static scene.

1. **Sequences** of ``--frames`` captures (2 x 2 supersampling, read noise 1/255, 8 bits) through ``thesis_setup1``
   at 1024 x 768 and the same optics on a 640 x 480 sensor (pixels 1.6x larger: the common endoscope size):

   * ``moving``: a noise-textured plane slanted 25-35 deg about y whose centre moves from 525 to 575 mm;
   * ``step``: a near plane at 450 mm entering the view from the right in front of a plane at 600 mm (its edge
     moves 60 mm over the sequence);
   * ``cut``: the moving plane for the first half, then a cut to another texture on a plane at 800 -> 780 mm.

   Every frame goes through the ``DepthStream`` s of the default ``PrismStereo`` over 228-1374 mm, exported once
   (onnxruntime, 2 intra-op threads, a temporal graph 1: ``threads.thread_plan``): per frame, with the temporal
   prior (its own temporal graph, ``TemporalOptions()``, whose band runs on the 2 x 2-binned frame for the 1024 x 768
   pyramid and at full resolution for the one-level 640 x 480 model; key frames by its rules) and with the band at
   the other of the two resolutions (``temporal k=1`` / ``k=2``) and, for the pyramid, on the 3 x 3-binned frame
   (``temporal k=3``: ``--temporal-binning 3``), where the hybrid is the sensor's default (1024 x 768) also with its
   key frames tracked by the binned temporal graphs (``hybrid keys``: what ``prismstereo depth`` runs), and through
   OpenCV's ``StereoSGBM`` (numDisparities covering the range's correspondence spread, blockSize 5, else defaults)
   and ``StereoBM`` (same) on the two 8-bit halves, one method after the other per frame, 0.1 s apart
   (``cv2.setNumThreads(2)``). Printed per method: median and 95th-percentile ms per frame, frames/s, the median over
   frames of the same-frame ratio to SGBM, the mean relative depth error and coverage over the co-visible reference
   pixels (OpenCV's disparities converted to depth through the exact sweep, as ``benchmarks/onnx_speed.py``) and the
   temporal stream's key frames.
2. **Flicker**: ``--static`` captures of a textured plane at 600 mm that differ only in their noise (read noise
   2/255, a new seed per frame): per pixel valid in every frame, the standard deviation of depth over the frames;
   the median over pixels (mm and % of depth) per frame, with the temporal prior and for SGBM.

3. **End to end** (``--cli N``, 1024 x 768 only): a lossless FFV1 video of N frames going back and forth over the
   moving sequence's 30 (so the motion stays smooth), through ``prismstereo depth VIDEO --out DIR`` in a subprocess
   as a user runs it (temporal and ``--no-temporal``, onnx and torch backends): the wall time on all frames minus
   that on the first 3 (``--stop 3``), per remaining frame, each wall the least of two runs (start-up cancels, and
   a start-up that once ran seconds slow does not decide the difference), beside StereoSGBM's median time per
   frame on the same frames in the same run, and the time OpenCV takes to decode the video alone (FFV1 is a costly
   codec; the CLI decodes on a reader thread beside the graph). Also the CLI's own figures: its end-to-end rate
   (``run``'s wall, without start-up), the median depth computation per frame (the graph and the stream's work on
   it) and the key frames; and the per-frame graphs alone as the CLI opens them (the ``--no-temporal`` rows'
   budget). ``--captures M`` single captures (the sequence's first M frames as 8-bit PNGs) with ``--workers 1``
   and ``--workers 2``: (least wall on M - least wall on 2) / (M - 2) per capture, the least of four runs each (the
   difference of 14 captures' walls is about a second, of the order of two processes' start-up jitter), and the
   CLI's rate. Each run with the model the CLI picks (the sensor's default, the hybrid; under the temporal prior its
   key frames, tracked by the classical model's band), with ``--temporal-binning 3``, and ``--model classical`` with
   and without the prior beside it.

Run: .venv/bin/python benchmarks/video_speed.py [--frames 20] [--static 30] [--sizes 1024 640] [--cli 120]
     [--captures 16]
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
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
from prismstereo.classical.model import PrismStereo  # noqa: E402
from prismstereo.classical.prior import TemporalOptions  # noqa: E402
from prismstereo.classical.temporal import temporal_downsample  # noqa: E402
from prismstereo.export import export_onnx  # noqa: E402
from prismstereo.learned import HybridStereo  # noqa: E402
from prismstereo.models import build_model, default_kind  # noqa: E402
from prismstereo.predictor import Predictor  # noqa: E402
from prismstereo.stream import DepthStream  # noqa: E402
from prismstereo.synthetic import (  # noqa: E402
    ImageFormation,
    fronto_parallel_plane,
    render,
    slanted_plane,
    step_scene,
)
from prismstereo.threads import set_torch_threads  # noqa: E402

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


def sequences(rig, frames: int) -> dict[str, list]:
    """The scenes of the moving sequences (the module docstring)."""
    last = max(1, frames - 1)
    moving = [slanted_plane(rig, 525.0 + 50.0 * k / last, 25.0 + 10.0 * k / last, seed=11) for k in range(frames)]
    step = [step_scene(rig, 450.0, 600.0, edge_x_mm=30.0 - 60.0 * k / last, seed=5) for k in range(frames)]
    half = frames // 2
    other = [fronto_parallel_plane(rig, 800.0 - 20.0 * k / last, seed=21) for k in range(frames - half)]
    return {"moving": moving, "step": step, "cut": moving[:half] + other}


def streams(rig, tmp: Path, name: str) -> tuple[PrismStereo, dict[str, DepthStream]]:
    """The default model and its per-frame and temporal ONNX streams: the default temporal graph
    (``TemporalOptions()``: its band binned by 2 for a pyramid, at full resolution for one level) and the band at
    the other resolution."""
    model = PrismStereo(rig, Z_RANGE).eval()
    graph = export_onnx(model, tmp / f"{name}_{rig.image_width}.onnx")
    default = temporal_downsample(model)
    runs = {"per-frame ONNX": DepthStream(Predictor.from_graphs(graph, threads=2))}
    # the full-resolution band for a binned default, and the coarser binning of --temporal-binning 3; the binned
    # band otherwise
    others = (1, 3) if default > 1 else (2,)
    hybrid = None
    if default_kind(rig) == "hybrid":  # the CLI's default: the hybrid's key frames
        hybrid = export_onnx(HybridStereo(rig, Z_RANGE).eval(), tmp / f"{name}_{rig.image_width}_hybrid.onnx")
    for k in (default, *others):
        temporal = export_onnx(model, tmp / f"{name}_{rig.image_width}_temporal_{k}.onnx",
                               temporal=TemporalOptions() if k == default else TemporalOptions(downsample=k))
        label = "" if k == default else f" k={k}"
        runs[f"temporal{label} ONNX"] = DepthStream(Predictor.from_graphs(graph, temporal, threads=2), temporal=True)
        if hybrid is not None and k != 1:
            keyed = Predictor.from_graphs(hybrid, temporal, threads=2)
            runs[f"hybrid keys{label} ONNX"] = DepthStream(keyed, temporal=True)
    return model, runs


def moving(rig, frames: int, model: PrismStereo, runs: dict[str, DepthStream]) -> None:
    split = rig.reference_width
    sweep = pixel_sweep(rig, Z_RANGE)
    nd = disparities(sweep)
    print(f"\n{rig.image_width} x {rig.image_height}, {frames} frames per sequence, range {Z_RANGE[0]:g}-"
          f"{Z_RANGE[1]:g} mm, model: {model.summary()}; OpenCV numDisparities {nd}")
    print(f"{'sequence':9s}{'method':22s} {'median ms':>9s} {'p95 ms':>7s} {'frames/s':>8s} {'x SGBM':>7s} "
          f"{'mean err %':>10s} {'coverage %':>10s} {'key frames':>10s}")
    for sequence, scenes in sequences(rig, frames).items():
        caps = render(rig, scenes, ImageFormation(supersample=2, noise_sigma=1 / 255, seed=3))
        first = type("C", (), {"covisible": caps.covisible[:1], "match_uv": caps.match_uv[:1],
                               "depth": caps.depth[:1]})
        _, mirror = spread_report(sweep, first)
        matchers = {"StereoSGBM": cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd, blockSize=5),
                    "StereoBM": cv2.StereoBM_create(numDisparities=nd, blockSize=5)}
        times: dict[str, list[float]] = {**{k: [] for k in runs}, **{k: [] for k in matchers}}
        errors: dict[str, list[tuple[float, float]]] = {k: [] for k in times}
        keys = {k: 0 for k in runs}
        for stream in runs.values():  # warm-up, then a fresh start: the sequence's first frame is a key frame
            stream.push(caps.image[0])
            stream.reset()
        for k in range(frames):
            image = caps.image[k:k + 1]
            capture = type("C", (), {"depth": caps.depth[k:k + 1], "covisible": caps.covisible[k:k + 1]})
            for name, stream in runs.items():
                time.sleep(0.1)
                res = stream.push(image[0])
                times[name].append(res.milliseconds)
                keys[name] += res.keyframe
                mean, _, cover = score(res.depth, res.valid, capture, split)
                errors[name].append((mean, cover))
            left, right = opencv_halves(image, split, mirror)
            for name, matcher in matchers.items():
                time.sleep(0.1)
                t0 = time.perf_counter()
                disparity = matcher.compute(left, right)
                times[name].append(1e3 * (time.perf_counter() - t0))
                depth, valid = opencv_depth(sweep, disparity, mirror)
                mean, _, cover = score(depth, valid & sweep.inside, capture, split)
                errors[name].append((mean, cover))
        sgbm = times["StereoSGBM"]
        for name, t in times.items():
            ratio = statistics.median(a / b for a, b in zip(t, sgbm, strict=True))
            mean = statistics.mean(e[0] for e in errors[name])
            cover = statistics.mean(e[1] for e in errors[name])
            key = f"{keys[name]:10d}" if name in keys else f"{'':10s}"
            print(f"{sequence:9s}{name:22s} {statistics.median(t):9.1f} {percentile(t, 95):7.1f} "
                  f"{1e3 / statistics.median(t):8.1f} {ratio:7.2f} {mean:10.3f} {cover:10.1f} {key}")


def flicker(rig, frames: int, runs: dict[str, DepthStream]) -> None:
    scene = fronto_parallel_plane(rig, 600.0, seed=4)
    caps = [render(rig, scene, ImageFormation(supersample=2, noise_sigma=2 / 255, seed=100 + k)) for k in range(frames)]
    for stream in runs.values():
        stream.reset()
    split = rig.reference_width
    sweep = pixel_sweep(rig, Z_RANGE)
    _, mirror = spread_report(sweep, caps[0])
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=disparities(sweep), blockSize=5)
    depth: dict[str, list[torch.Tensor]] = {**{k: [] for k in runs}, "StereoSGBM": []}
    valid: dict[str, list[torch.Tensor]] = {k: [] for k in depth}
    for cap in caps:
        for name, stream in runs.items():
            res = stream.push(cap.image[0])
            depth[name].append(res.depth[0, 0].double())
            valid[name].append(res.valid[0, 0])
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
        print(f"{name:22s} median std over frames {float(std.median()):.3f} mm ({float(rel.median()):.4f} %), "
              f"95th percentile {float(std.quantile(0.95)):.3f} mm, on {100 * float(ok.sum() / covisible.sum()):.1f} % "
              "of the co-visible pixels (valid in every frame)")


def _cli_seconds(args: list[str]) -> tuple[float, str]:
    """Wall seconds of ``prismstereo depth ARGS`` in a subprocess, and what it printed."""
    cli = Path(sys.executable).with_name("prismstereo")
    start = time.perf_counter()
    done = subprocess.run([str(cli), "depth", *args], capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode:  # the CLI's own reasons (a failed input, a full disk), not only its exit status
        raise SystemExit(f"prismstereo depth {' '.join(args)} exited {done.returncode}:\n{done.stderr[-2000:]}")
    return seconds, done.stdout


def _pingpong(count: int, frames: int) -> list[int]:
    """``frames`` indices going back and forth over 0 .. count - 1."""
    period = max(1, 2 * (count - 1))
    return [k % period if k % period < count else period - k % period for k in range(frames)]


def _model_name(text: str) -> str:
    """The model a ``prismstereo depth`` run printed it used."""
    if "tracked between key frames by the classical model" in text:
        return "hybrid key frames, classical band"
    return "hybrid" if "hybrid: " in text else "classical"


def end_to_end(frames: int, captures: int, tmp: Path) -> None:
    """Section 3 of the module docstring."""
    rig = sensor(1024)
    rendered = 30
    scenes = sequences(rig, max(rendered, captures))["moving"]
    caps = render(rig, scenes, ImageFormation(supersample=2, noise_sigma=1 / 255, seed=3))
    video = tmp / "moving.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 10.0, (rig.image_width, rig.image_height))
    grey = [np.clip(np.rint(image[0].numpy() * 255), 0, 255).astype(np.uint8) for image in caps.image]
    order = _pingpong(rendered, frames)
    for k in order:
        writer.write(cv2.cvtColor(grey[k], cv2.COLOR_GRAY2BGR))
    writer.release()
    for k in range(captures):
        cv2.imwrite(str(tmp / f"capture{k:02d}.png"), grey[k])
    rig.to_json(tmp / "rig.json")
    sweep = pixel_sweep(rig, Z_RANGE)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=disparities(sweep), blockSize=5)
    _, mirror = spread_report(sweep, type("C", (), {"covisible": caps.covisible[:1], "match_uv": caps.match_uv[:1],
                                                   "depth": caps.depth[:1]}))
    sgbm_ms = []
    for k in order:
        left, right = opencv_halves(caps.image[k:k + 1], rig.reference_width, mirror)
        start = time.perf_counter()
        sgbm.compute(left, right)
        sgbm_ms.append(1000 * (time.perf_counter() - start))
    sgbm_frame = statistics.median(sgbm_ms)
    decoding = cv2.VideoCapture(str(video))
    start, decoded = time.perf_counter(), 0
    while decoding.read()[0]:
        decoded += 1
    decode_ms = 1000 * (time.perf_counter() - start) / max(decoded, 1)
    common = ["--rig", str(tmp / "rig.json"), "--z-range", str(Z_RANGE[0]), str(Z_RANGE[1])]
    print(f"\nend to end, prismstereo depth in a subprocess, {frames}-frame FFV1 video (back and forth over the "
          f"moving sequence) and {captures} PNG captures at 1024 x 768; StereoSGBM {sgbm_frame:.1f} ms per frame "
          f"(median, same frames); decoding the video alone (OpenCV, on the CLI's reader thread) {decode_ms:.1f} ms "
          "per frame")
    print(f"{'run':48s} {'ms per frame':>12s} {'x SGBM':>7s} {'CLI ms/frame':>12s} {'depth median':>12s} "
          f"{'key frames':>10s} model")
    runs = {f"video --backend {b}{' --no-temporal' if not t else ''}": [str(video), "--backend", b] +
            ([] if t else ["--no-temporal"]) for b in ("onnx", "torch") for t in (True, False)}
    for extra in (["--temporal-binning", "3"], ["--model", "classical"], ["--no-temporal", "--model", "classical"]):
        runs[" ".join(["video --backend onnx", *extra])] = [str(video), "--backend", "onnx", *extra]
    for name, extra in runs.items():
        heads, wholes, rates, medians, keys, model = [], [], [], [], "-", "-"
        _cli_seconds([*extra, *common, "--out", str(tmp / "warm"), "--stop", "1"])  # exports into the cache
        for repeat in range(2):
            out = tmp / f"out{repeat}"
            heads.append(_cli_seconds([*extra, *common, "--out", str(out / "head"), "--stop", "3"])[0])
            whole, text = _cli_seconds([*extra, *common, "--out", str(out / "all")])
            wholes.append(whole)
            rates.append(1000 / float(re.search(r"([\d.]+) depth maps/s end to end", text).group(1)))
            medians.append(float(re.search(r"([\d.]+) ms per frame \(median", text).group(1)))
            found = re.search(r"(\d+) key frames", text)
            keys = found.group(1) if found else "-"
            model = _model_name(text)
        best = 1000 * (min(wholes) - min(heads)) / (frames - 3)
        print(f"{name:48s} {best:12.1f} {best / sgbm_frame:7.2f} {min(rates):12.1f} {min(medians):12.1f} {keys:>10s} "
              f"{model}")
    alone = []  # the per-frame graphs without the CLI around them, for the --no-temporal rows
    for name in ("hybrid", "classical"):  # as the CLI's pipeline opens them
        session = Predictor(build_model(rig, name, Z_RANGE), backend="onnx", threads=2, spinning=False)
        session.depth(caps.image[:1])
        times = []
        for k in order[:30]:
            start = time.perf_counter()
            session.depth(caps.image[k:k + 1])
            times.append(1000 * (time.perf_counter() - start))
        alone.append(f"{name} {statistics.median(times):.1f} ms")
    print("per-frame graphs alone, as the CLI runs them (onnxruntime, 2 threads, not spinning; median of 30 frames): "
          + ", ".join(alone))
    images = [str(tmp / f"capture{k:02d}.png") for k in range(captures)]
    _cli_seconds([images[0], "--backend", "onnx", *common, "--out", str(tmp / "warm.npy")])
    for workers in (1, 2):
        heads, wholes, rates = [], [], []
        for repeat in range(4):
            flags = ["--backend", "onnx", "--workers", str(workers), *common]
            heads.append(_cli_seconds([*images[:2], *flags, "--out", str(tmp / f"c{repeat}h")])[0])
            whole, text = _cli_seconds([*images, *flags, "--out", str(tmp / f"c{repeat}a")])
            wholes.append(whole)
            rates.append(1000 / float(re.search(r"([\d.]+) depth maps/s end to end", text).group(1)))
        best = 1000 * (min(wholes) - min(heads)) / (captures - 2)
        print(f"{f'{captures} captures --backend onnx --workers {workers}':48s} {best:12.1f} "
              f"{best / sgbm_frame:7.2f} {min(rates):12.1f} {'':>12s} {'-':>10s} {_model_name(text)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=20, help="frames of the moving sequence")
    parser.add_argument("--static", type=int, default=30, help="frames of the flicker measurement (0 skips it)")
    parser.add_argument("--sizes", type=int, nargs="*", default=(1024, 640), help="sensor widths (none: only --cli)")
    parser.add_argument("--cli", type=int, default=120, metavar="N", help="video frames end to end (0 skips)")
    parser.add_argument("--captures", type=int, default=16, metavar="M", help="captures end to end")
    args = parser.parse_args()
    set_torch_threads(2)
    cv2.setNumThreads(2)
    with tempfile.TemporaryDirectory() as folder:
        if args.cli:
            end_to_end(args.cli, args.captures, Path(folder))
        for width in args.sizes:
            rig = sensor(width)
            model, runs = streams(rig, Path(folder), "model")
            moving(rig, args.frames, model, runs)
            if args.static:
                flicker(rig, args.static, runs)


if __name__ == "__main__":
    main()
