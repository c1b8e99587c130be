"""The learned model (``prismstereo.learned.LearnedStereo``, shipped weights) against the classical
``PrismStereo`` on full-resolution captures that training never saw.

Captures (``thesis_setup1``, 1024 x 768, 2 x 2 supersampling, read noise 2/255, Fresnel transmission, 8 bits;
the captures of ``benchmarks/dense_depth.py``, same cache names, plus a textured plane):

* a textured fronto-parallel plane at 600 mm (noise features 3 px, seed 5);
* the smooth weakly textured surface 520-680 mm (``procedural_surface(9001)`` of
  ``benchmarks/fit_confidence.py``; training draws its seeds below 9000);
* the Middlebury photographs Tsukuba and Venus as height fields 450-900 mm (never used in training);
* a textured plane at 400 mm behind a thin lens focused at 600 mm, f/12.5 and f/6.25 (skipped, like any
  capture whose depths leave ``--z-range``, unless the range is widened).

Both models search ``--z-range`` (default 450-1000 mm); the learned one with ``--hypotheses`` (48 by default,
the spacing it was trained for at this resolution). Per capture and model: coverage (co-visible reference
pixels that are valid), bad>1 % (share of those off by more than 1 %), mean relative error on them, and the
median time of ``--repeat`` forward passes in torch (after one warm-up); first, both models' median frame time in
torch and in onnxruntime (their exported graphs, ``--threads`` threads). ``learned (all)`` counts every
co-visible pixel with the learned model's depth, valid or not.

Run: .venv/bin/python benchmarks/learned.py [--z-range ZMIN ZMAX] [--hypotheses D] [--cache DIR] [--repeat N]
     [--threads T]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import median_ms  # noqa: E402
from dense_depth import captures as dense_captures  # noqa: E402
from dense_depth import scores  # noqa: E402

from prismstereo import thesis_setup1  # noqa: E402
from prismstereo.classical.model import PrismStereo  # noqa: E402
from prismstereo.export import OnnxDepth, export_onnx  # noqa: E402
from prismstereo.learned import LearnedStereo  # noqa: E402
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render  # noqa: E402
from prismstereo.threads import set_torch_threads  # noqa: E402


def captures(rig, cache: Path) -> dict[str, dict]:
    """The held-out captures of ``benchmarks/dense_depth.py`` (same cache) and a textured plane at 600 mm."""
    out = dense_captures(rig, cache)
    path = cache / f"{rig.image_width}_plane_600_mm.pt"
    if not path.exists():
        image = ImageFormation(supersample=2, noise_sigma=2 / 255, fresnel=True, seed=7)
        torch.save(render(rig, fronto_parallel_plane(rig, 600.0, seed=5), image)._asdict(), path)
    return {"plane 600 mm": torch.load(path), **out}


def onnx_ms(model: torch.nn.Module, image: torch.Tensor, repeat: int, threads: int, folder: Path) -> float:
    """Median onnxruntime time (ms) of the model's exported graph over ``repeat`` runs after a warm-up."""
    runner = OnnxDepth(export_onnx(model, folder / f"{type(model).__name__}.onnx"), threads=threads)
    return median_ms(lambda: runner(image), repeat)


def run(model: torch.nn.Module, image: torch.Tensor, repeat: int) -> tuple[object, float]:
    """The model's result and its median forward time (ms) over ``repeat`` runs after a warm-up."""
    last = {}

    def forward() -> None:
        last["result"] = model(image)

    with torch.inference_mode():
        ms = median_ms(forward, repeat)
    return last["result"], ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--z-range", type=float, nargs=2, default=(450.0, 1000.0), metavar=("ZMIN", "ZMAX"))
    parser.add_argument("--hypotheses", type=int, default=48, help="the learned model's D")
    parser.add_argument("--cache", type=Path, default=Path(".cache/dense_depth"))
    parser.add_argument("--repeat", type=int, default=3, help="timed forward passes per capture and model")
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads (use 1 on a shared CPU)")
    args = parser.parse_args()
    set_torch_threads(args.threads)
    rig = thesis_setup1()
    z_range = tuple(args.z_range)
    caps = captures(rig, args.cache)
    models = {"classical": PrismStereo(rig, z_range),
              "learned": LearnedStereo(rig, z_range, num_hypotheses=args.hypotheses).eval()}
    print(f"thesis_setup1 {rig.image_width}x{rig.image_height}, searched {z_range[0]:g}-{z_range[1]:g} mm; "
          f"learned: D={args.hypotheses}, {sum(p.numel() for p in models['learned'].parameters())} parameters; "
          f"{args.threads} torch thread(s)")
    print(f"{'capture':26s} {'model':15s} {'cover %':>8s} {'bad>1% %':>9s} {'mean %':>8s} {'ms':>7s}")
    w = rig.reference_width
    with tempfile.TemporaryDirectory() as folder:
        image = caps["plane 600 mm"]["image"]
        for key, model in models.items():
            torch_ms = run(model, image, args.repeat)[1]
            ort_ms = onnx_ms(model, image, args.repeat, args.threads, Path(folder))
            print(f"time of one 1024 x 768 frame, {key}: torch {torch_ms:.0f} ms, onnxruntime {ort_ms:.0f} ms")
    for name, cap in caps.items():
        gt, covisible = cap["depth"][..., :w], cap["covisible"][..., :w]
        seen = gt[covisible]
        if float(seen.min()) < z_range[0] or float(seen.max()) > z_range[1]:
            print(f"{name:26s} skipped: depths {float(seen.min()):.0f}-{float(seen.max()):.0f} mm leave the range")
            continue
        for key, model in models.items():
            res, ms = run(model, cap["image"], args.repeat)
            rel = (res.depth.double() - gt).abs() / gt
            rows = [(key, res.valid)] + ([("learned (all)", torch.ones_like(res.valid))] if key == "learned" else [])
            for label, has in rows:
                cover, bad, mean = scores(rel, has, covisible)
                print(f"{name:26s} {label:15s} {cover:8.1f} {bad:9.2f} {mean:8.3f} {ms:7.0f}")


if __name__ == "__main__":
    main()
