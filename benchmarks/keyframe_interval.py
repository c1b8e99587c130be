"""Rarer key frames: the temporal stream over a long smooth sequence with the key-frame interval varied.

The moving sequence of ``benchmarks/video_speed.py`` (30 frames of a slanted plane moving 525 -> 575 mm,
``thesis_setup1`` at 1024 x 768, range 228-1374 mm) played back and forth to ``--frames`` frames, through a
:class:`~prismstereo.stream.DepthStream` as ``prismstereo depth`` runs it: key frames by the sensor's default model
(the hybrid's exported graph, 2 intra-op threads), tracked by the classical model's temporal graph (one thread,
:func:`~prismstereo.threads.thread_plan`), with ``TemporalOptions(keyframe_interval=K)`` for each
``--intervals`` K.
Printed per K: the key frames, the mean and median per-frame time of the stream, the mean relative depth error over
the co-visible valid pixels (mean over frames, and the worst frame) and the coverage (mean and lowest frame).

Run: .venv/bin/python benchmarks/keyframe_interval.py [--frames 240] [--intervals 30 60 120]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from video_speed import Z_RANGE, _pingpong, sensor, sequences  # noqa: E402

from prismstereo import PrismStereo  # noqa: E402
from prismstereo.classical import TemporalOptions  # noqa: E402
from prismstereo.export import export_onnx  # noqa: E402
from prismstereo.learned import HybridStereo  # noqa: E402
from prismstereo.predictor import Predictor  # noqa: E402
from prismstereo.stream import DepthStream  # noqa: E402
from prismstereo.synthetic import ImageFormation, render  # noqa: E402
from prismstereo.threads import set_torch_threads  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=240, help="frames played (back and forth over 30)")
    parser.add_argument("--intervals", type=int, nargs="+", default=(30, 60, 120), help="key-frame intervals")
    args = parser.parse_args()
    set_torch_threads(2)
    rig = sensor(1024)
    caps = render(rig, sequences(rig, 30)["moving"], ImageFormation(supersample=2, noise_sigma=1 / 255, seed=3))
    w = rig.reference_width
    model = PrismStereo(rig, Z_RANGE).eval()
    print(f"thesis_setup1 1024 x 768, {Z_RANGE[0]:g}-{Z_RANGE[1]:g} mm, {args.frames} frames back and forth over the "
          "moving sequence's 30")
    with tempfile.TemporaryDirectory() as folder:
        graph = export_onnx(HybridStereo(rig, Z_RANGE).eval(), Path(folder) / "frame.onnx")
        tracker = export_onnx(model, Path(folder) / "temporal.onnx", temporal=TemporalOptions())
        for k in args.intervals:  # sessions as the CLI opens them
            predictor = Predictor.from_graphs(graph, tracker, threads=2, spinning=False)
            stream = DepthStream(predictor, temporal=TemporalOptions(keyframe_interval=k))
            errors, coverage = [], []
            for i in _pingpong(30, args.frames):
                res = stream.push(caps.image[i])
                seen = caps.covisible[i, :, :, :w]
                ok = res.valid[0] & seen
                truth = caps.depth[i, :, :, :w]
                errors.append(float(((res.depth[0].double() - truth).abs() / truth)[ok].mean()))
                coverage.append(float(ok.sum() / seen.sum()))
            mean, median = statistics.mean(stream.times_ms), statistics.median(stream.times_ms)
            print(f"interval {k:3d}: {stream.keyframes:3d} key frames, stream {mean:5.1f} ms mean / {median:5.1f} "
                  f"median per frame, error {100 * np.mean(errors):.4f} % (worst frame {100 * max(errors):.4f} %), "
                  f"coverage {100 * np.mean(coverage):.2f} % (lowest {100 * min(coverage):.2f} %)")


if __name__ == "__main__":
    main()
