"""Throughput of the exact optics on this machine: trace every pixel of a 1024x768 sensor, and project the
points they see back (torch eager float32/float64, and onnxruntime float32 for the exported graph).

Run: .venv/bin/python benchmarks/optics_speed.py     (prints a table; median of --repeats runs)
"""

from __future__ import annotations

import argparse
import tempfile
import warnings
from pathlib import Path

import onnxruntime as ort
import torch
from _timing import median_ms  # benchmarks/_timing.py (scripts run from this folder)

from prismstereo import thesis_setup1
from prismstereo.geometry import points_at_depth, project_points, trace_pixels
from prismstereo.threads import set_torch_threads


class _Project(torch.nn.Module):
    def __init__(self, rig) -> None:
        super().__init__()
        self.p = rig.parameters(dtype=torch.float32)

    def forward(self, points: torch.Tensor):
        proj = project_points(self.p, points, "left")
        return proj.uv, proj.valid


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    set_torch_threads(2)
    rig = thesis_setup1()
    h, w = rig.image_height, rig.image_width
    rows = []
    for dtype in (torch.float32, torch.float64):
        vv, uu = torch.meshgrid(torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij")
        uv = torch.stack([uu, vv], dim=-1)
        rays = trace_pixels(rig, uv)
        left = rays.left & rays.valid
        pts = points_at_depth(rays, 600.0)[left]
        name = str(dtype).removeprefix("torch.")
        with torch.no_grad():
            ms = median_ms(lambda uv=uv: trace_pixels(rig, uv), args.repeats)
            rows.append((f"trace_pixels   torch {name}", h * w, ms))
            ms = median_ms(lambda pts=pts: project_points(rig, pts, "left"), args.repeats)
            rows.append((f"project_points torch {name}", len(pts), ms))
        if dtype == torch.float32:
            with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
                warnings.simplefilter("ignore")
                path = str(Path(tmp) / "project.onnx")
                torch.onnx.export(_Project(rig), (pts,), path, dynamo=False, opset_version=17,
                                  input_names=["points"], output_names=["uv", "valid"])
                opts = ort.SessionOptions()
                opts.intra_op_num_threads, opts.inter_op_num_threads = 2, 1
                sess = ort.InferenceSession(path, opts)
                feed = {"points": pts.numpy()}
                ms = median_ms(lambda sess=sess, feed=feed: sess.run(None, feed), args.repeats)
                rows.append(("project_points onnxruntime float32", len(pts), ms))
    print(f"{'operation':40s} {'items':>9s} {'ms':>9s} {'Mitems/s':>9s}")
    for name, n, ms in rows:
        print(f"{name:40s} {n:9d} {ms:9.1f} {n / ms / 1e3:9.2f}")


if __name__ == "__main__":
    main()
