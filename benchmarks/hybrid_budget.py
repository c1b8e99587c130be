"""The time budget of a hybrid chain (one dense, exact and fast default): the classical model in block mode as the
initial estimate, then a learned image-guided 2-D refinement stage, timed in onnxruntime against OpenCV's StereoSGBM
in the same run, ``thesis_setup1`` at 1024 x 768 over 228-1374 mm.

Rows (interleaved rounds after a warm-up each, ``benchmarks/_timing.py``; onnxruntime 2 intra-op threads, all graph
optimisations; ``cv2.setNumThreads(2)``):

* OpenCV ``StereoSGBM`` on the two 8-bit halves (numDisparities covering the range, blockSize 5; as
  ``benchmarks/onnx_speed.py``), the reference of the "x SGBM" column;
* the classical model in block mode (``downsample 2``, ``full_band 0``: matching on the 2 x 2-binned capture, each
  pixel its block's depth) with its ``valid`` output and with the dense one (``validity.dense``: a depth for every
  covered pixel), exported graphs;
* candidate refinement stages at 1/2 and at full resolution of the reference half: untrained (the time does not
  depend on the weights) 2-D CNNs of L 3 x 3 layers of C channels (dilations 1, 2, 4, 8, 1, 1, ... as in the
  StereoNet / HITNet refinements), whose input is the reference image, the other half sampled at the current match
  (one ``grid_sample``: the warp), their difference and the estimate, and whose output is a residual and a confidence
  logit; and block mode + that stage, the chain's total.

The issue's speed target is the chain at <= 0.8x SGBM: the rows say which stage sizes fit beside block mode.

Run: .venv/bin/python benchmarks/hybrid_budget.py [--rounds 9]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import interleaved_ms, paired_ratio  # noqa: E402
from onnx_speed import opencv_halves, pixel_sweep  # noqa: E402
from video_speed import disparities  # noqa: E402

from prismstereo import PrismStereo, thesis_setup1  # noqa: E402
from prismstereo.export import OnnxDepth, export_onnx  # noqa: E402
from prismstereo.synthetic import ImageFormation, render, slanted_plane  # noqa: E402
from prismstereo.threads import set_torch_threads  # noqa: E402

Z_RANGE = (228.0, 1374.0)
DILATIONS = (1, 2, 4, 8, 1, 1, 1, 1)


class Refinement(nn.Module):
    """A candidate stage: warp, then L dilated 3 x 3 convolutions of C channels, to a residual and a logit."""

    def __init__(self, channels: int, layers: int) -> None:
        super().__init__()
        convs = [nn.Conv2d(4, channels, 3, padding=1)]
        convs += [nn.Conv2d(channels, channels, 3, padding=d, dilation=d) for d in DILATIONS[1:layers - 1]]
        self.convs = nn.ModuleList(convs)
        self.head = nn.Conv2d(channels, 2, 3, padding=1)

    def forward(self, reference: torch.Tensor, other: torch.Tensor, grid: torch.Tensor,
                estimate: torch.Tensor) -> torch.Tensor:
        warped = F.grid_sample(other, grid, mode="bilinear", padding_mode="border", align_corners=True)
        x = torch.cat([reference, warped, reference - warped, estimate], 1)
        for conv in self.convs:
            x = F.leaky_relu(conv(x), 0.2)
        return self.head(x)


def stage_inputs(rig, factor: int) -> tuple[np.ndarray, ...]:
    """Inputs of a stage at 1 / ``factor`` of the reference half: reference, other half, grid, estimate."""
    h, w = rig.image_height // factor, rig.reference_width // factor
    g = torch.Generator().manual_seed(0)
    grid = torch.rand(1, h, w, 2, generator=g) * 2 - 1
    return (torch.rand(1, 1, h, w, generator=g).numpy(), torch.rand(1, 1, h, rig.image_width // factor - w,
                                                                    generator=g).numpy(),
            grid.numpy(), torch.rand(1, 1, h, w, generator=g).numpy())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=9, help="interleaved timing rounds")
    args = parser.parse_args()
    set_torch_threads(2)
    cv2.setNumThreads(2)
    rig = thesis_setup1()
    capture = render(rig, [slanted_plane(rig, 525.0, 30.0)], ImageFormation(supersample=2, noise_sigma=1 / 255))
    image = capture.image[:, :1].numpy()
    sweep = pixel_sweep(rig, Z_RANGE)
    left, right = opencv_halves(capture.image[:, :1], rig.reference_width, False)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=disparities(sweep), blockSize=5)
    runs = {"StereoSGBM": lambda: sgbm.compute(left, right)}
    block = {"downsample": 2, "full_band": 0}
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        for name, config in (("block mode", block), ("block mode, dense", {**block, "dense": True})):
            graph = OnnxDepth(export_onnx(PrismStereo(rig, Z_RANGE, config).eval(), tmp / f"{len(runs)}.onnx"))
            runs[name] = (lambda g: lambda: g(image))(graph)
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads = 2, 1
        stages = {}
        for factor in (2, 1):
            for channels, layers in ((8, 4), (16, 4), (16, 6), (32, 6)):
                name = f"refinement 1/{factor}, {layers} x {channels} ch"
                torch.manual_seed(0)
                module = Refinement(channels, layers).eval()
                inputs = stage_inputs(rig, factor)
                path = tmp / f"stage_{factor}_{channels}_{layers}.onnx"
                torch.onnx.export(module, tuple(torch.from_numpy(x) for x in inputs), str(path), opset_version=18,
                                  input_names=["reference", "other", "grid", "estimate"], dynamo=False)
                session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
                feed = dict(zip(["reference", "other", "grid", "estimate"], inputs, strict=True))
                runs[name] = (lambda s, f: lambda: s.run(None, f))(session, feed)
                stages[name] = sum(p.numel() for p in module.parameters())
        times = interleaved_ms(runs, rounds=args.rounds)
    sgbm_ms = times["StereoSGBM"]
    print(f"thesis_setup1 1024 x 768, {Z_RANGE[0]:g}-{Z_RANGE[1]:g} mm; {args.rounds} interleaved rounds; "
          f"StereoSGBM median {statistics.median(sgbm_ms):.1f} ms")
    print(f"{'run':40s} {'median ms':>9s} {'x SGBM':>7s} {'+ block mode, x SGBM':>21s} {'parameters':>10s}")
    for name, values in times.items():
        total = ""
        if name in stages:
            summed = [a + b for a, b in zip(values, times["block mode, dense"], strict=True)]
            total = f"{paired_ratio(summed, sgbm_ms):.2f}"
        print(f"{name:40s} {statistics.median(values):9.1f} {paired_ratio(values, sgbm_ms):7.2f} {total:>21s} "
              f"{stages.get(name, ''):>10}")


if __name__ == "__main__":
    main()
