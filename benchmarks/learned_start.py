"""The learned first stage against the hybrid's classical block level: where each starts the refinement, and its time.

Captures (held out from training, 1024 x 768, ``thesis_setup1``, 228-1374 mm; the renders of
``benchmarks/dense_depth.py`` and ``benchmarks/default_chain.py``, shared cache): the Middlebury photographs Tsukuba
and Venus and scikit-image's Motorcycle as height fields 450-900 mm away, and a weakly textured height field.

On the 4 x 4-binned grid where :class:`~prismstereo.learned.HybridStereo`'s first refinement stage works, per capture:
the share of the co-visible blocks with a reliable truth (all 16 pixels co-visible, their true sweep coordinates
within half a step of that grid) whose start is within 1, 2 (the refinement's cost curve: offsets +- 2) and 4 steps of
the truth, for ``block`` (the classical level a hybrid with ``start='classical'`` starts from, the shipped
``HYBRID_BLOCK_WEIGHTS``: block mode on 4 x 4 bins, its estimate extended over uncovered blocks as the hybrid does) and
``learned`` (:class:`~prismstereo.learned.sweep_start.SweepStart`, the default start: on 8 x 8 bins, carried to the
4 x 4 grid bilinearly, block centres kept). Then each one's exported graph in onnxruntime
(2 intra-op threads) against StereoSGBM in interleaved rounds (``benchmarks/_timing.py``).

Run: .venv/bin/python benchmarks/learned_start.py [--weights FILE] [--rounds 9]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import cv2
import onnxruntime as ort
import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import interleaved_ms, paired_ratio  # noqa: E402
from default_chain import more_captures  # noqa: E402
from dense_depth import captures  # noqa: E402
from onnx_speed import opencv_halves, pixel_sweep  # noqa: E402
from video_speed import disparities  # noqa: E402

from prismstereo import thesis_setup1  # noqa: E402
from prismstereo.conventions import to_grey  # noqa: E402
from prismstereo.depth.resample import upsample  # noqa: E402
from prismstereo.learned import HybridStereo  # noqa: E402
from prismstereo.learned.hybrid import HYBRID_BLOCK_WEIGHTS  # noqa: E402
from prismstereo.learned.hybrid_data import truth_sweep  # noqa: E402
from prismstereo.learned.network import normalise_image  # noqa: E402
from prismstereo.learned.start_train import block_truth  # noqa: E402
from prismstereo.learned.sweep_start import START_WEIGHTS, SweepStart, load_start  # noqa: E402
from prismstereo.threads import set_torch_threads  # noqa: E402

Z_RANGE = (228.0, 1374.0)
NAMES = ("Tsukuba 450-900 mm", "Venus 450-900 mm", "Motorcycle 450-900 mm", "weak surface 520-680 mm")
CACHE = Path(__file__).resolve().parents[1] / ".cache" / "dense_depth"


class StartGraph(nn.Module):
    """The first stage from the capture (B, 1, H, W): grey binned 2 x 2, normalised, then s and confidence."""

    def __init__(self, start: SweepStart) -> None:
        super().__init__()
        self.start = start

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.start(normalise_image(F.avg_pool2d(to_grey(image), 2)))
        return out.s, out.confidence


def truth_grid(capture: dict, step: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(truth, reliable) on the 4 x 4-binned reference grid: the mean true s of each block, and blocks whose 16 pixels
    are co-visible with true sweep coordinates within half a ``step``."""
    w_ref = capture["depth"].shape[-1]
    s = truth_sweep(capture["depth"][..., :w_ref].double(), Z_RANGE)
    seen = capture["covisible"][..., :w_ref] & torch.isfinite(s)
    return block_truth(s, seen, 4, step, (s.shape[-2] // 4, s.shape[-1] // 4))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default=str(START_WEIGHTS))
    parser.add_argument("--rounds", type=int, default=9)
    args = parser.parse_args()
    set_torch_threads(2)
    rig = thesis_setup1()
    caps = captures(rig, CACHE)
    caps["Motorcycle 450-900 mm"] = more_captures(rig, CACHE)["Motorcycle 450-900 mm"][1]
    hybrid = HybridStereo(rig, Z_RANGE, weights=HYBRID_BLOCK_WEIGHTS).eval()  # starts from the block level
    start = load_start(rig, Z_RANGE, args.weights).eval()
    graph = StartGraph(start).eval()
    step = hybrid.quarter_step
    print(f"start within k steps of the truth on the 4 x 4-binned grid (step {step:.4f} in s, D = "
          f"{round(2 / step) + 1} there; the learned stage's D = {start.num_hypotheses} at 1/8); share of reliable "
          "co-visible blocks, %")
    print(f"{'capture':26s} {'start':8s} {'<= 1':>6s} {'<= 2':>6s} {'<= 4':>6s} {'blocks':>7s}")
    for name in NAMES:
        image = caps[name]["image"][:, :1].float()
        truth, reliable = truth_grid(caps[name], step)
        with torch.inference_mode():
            block = hybrid.initial(image).s
            s8, _ = graph(image)
            learned = upsample(s8, 2, tuple(block.shape[-2:]), mode="bilinear")
        for label, s in (("block", block), ("learned", learned)):
            h, w = min(s.shape[-2], truth.shape[-2]), min(s.shape[-1], truth.shape[-1])
            error = (s[..., :h, :w].double() - truth[..., :h, :w]).abs() / step
            sel = reliable[..., :h, :w]
            shares = [100 * float((error[sel] <= k).double().mean()) for k in (1, 2, 4)]
            print(f"{name:26s} {label:8s} {shares[0]:6.1f} {shares[1]:6.1f} {shares[2]:6.1f} {int(sel.sum()):7d}")
    image = caps["Tsukuba 450-900 mm"]["image"][:, :1].float()
    left, right = opencv_halves(image, rig.reference_width, False)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=disparities(pixel_sweep(rig, Z_RANGE)), blockSize=5)
    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = 2, 1
    feed = image.numpy()
    runs = {"StereoSGBM": lambda: sgbm.compute(left, right)}
    with tempfile.TemporaryDirectory() as folder:
        for label, module in (("block", hybrid.classical), ("learned", graph)):
            path = Path(folder) / f"{label}.onnx"
            torch.onnx.export(module, (image,), str(path), opset_version=17, dynamo=False)
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
            name = session.get_inputs()[0].name
            runs[label] = (lambda s, n: lambda: s.run(None, {n: feed}))(session, name)
        measured = interleaved_ms(runs, rounds=args.rounds)
    print(f"\nexported graphs at 1024 x 768, onnxruntime 2 threads, {args.rounds} interleaved rounds")
    print(f"{'run':12s} {'median ms':>9s} {'x SGBM':>7s}")
    for label, values in measured.items():
        print(f"{label:12s} {statistics.median(values):9.1f} {paired_ratio(values, measured['StereoSGBM']):7.2f}")


if __name__ == "__main__":
    main()
