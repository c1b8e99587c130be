"""Fit the calibrated confidence of PrismStereo (``prismstereo.matching.confidence.DEFAULT_WEIGHTS`` and
``SMOOTHED_WEIGHTS``).

Renders training captures of ``thesis_setup1`` and ``thesis_setup2`` at full resolution with this package's
renderer: fronto-parallel planes (near ones included, where most of the reference half is not co-visible),
slanted planes, depth steps, and smooth procedural height fields whose texture is strong in some regions and
nearly absent in others (contrast 0.01-0.21, with slow shading), with read noise of 1-2 grey levels and some
blur. None of the held-out scenes of ``benchmarks/dense_depth.py`` (the Middlebury photographs, the defocus
captures) is used. Every pixel with an estimate is a sample: correct when it is co-visible and its depth is
within 1 % of the truth, wrong otherwise (pixels the other half does not see included). Prints the fitted
weights (paste them into ``DEFAULT_WEIGHTS``), the training log-loss and, per capture, the coverage and
wrong share at p >= 0.5. Then the second stage, the re-scoring after the model's smoothing
(``SMOOTHED_WEIGHTS``, on :data:`~prismstereo.matching.confidence.SMOOTHED_FEATURES` of the smoothed depth):
it is fitted on the model's current first stage, so after pasting new ``DEFAULT_WEIGHTS`` run the script
again for the second. ``--presets fast`` fits the weights of models whose final band clamps its edges
(``CLAMPED_WEIGHTS``: stage 1, then stage 2 the same way).

Run: .venv/bin/python benchmarks/fit_confidence.py [--cache DIR] [--scenes N] [--z-range ZMIN ZMAX]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import torch
import torch.nn.functional as F

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.learned.data import procedural_picture
from prismstereo.matching.confidence import FEATURES, SMOOTHED_FEATURES, ConfidenceModel, fit_confidence
from prismstereo.model import PrismStereo
from prismstereo.synthetic import (
    ImageFormation,
    Scene,
    fronto_parallel_plane,
    height_field_scene,
    render,
    slanted_plane,
    step_scene,
)

SETUPS = {"1": thesis_setup1, "2": thesis_setup2}
SAMPLES_PER_CAPTURE = 200_000


def procedural_surface(seed: int, h: int = 360, w: int = 480) -> tuple[torch.Tensor, torch.Tensor]:
    """(picture (h, w) in [0, 1], bumps (h, w) of unit scale) of seed ``seed``:
    :func:`~prismstereo.learned.data.procedural_picture` (texture strong in some regions, nearly absent in others,
    on smooth shading; the bumps a sum of four random Gaussians)."""
    return procedural_picture(torch.Generator().manual_seed(seed), h, w)


def training_scenes(rig: BiPrismRig, seed: int, count: int, z_range: tuple[float, float]) -> list[Scene]:
    """``count`` scenes cycling through plane, slanted plane, step, height field, near plane."""
    gen = torch.Generator().manual_seed(seed)
    lo, hi = z_range
    scenes = []
    for i in range(count):
        u = float(torch.rand(1, generator=gen))
        z = lo + 20 + (hi - lo - 200) * u
        texel = (2.0, 4.0, 8.0, 16.0)[int(torch.randint(4, (1,), generator=gen))]
        kind = i % 5
        if kind == 0:
            scenes.append(fronto_parallel_plane(rig, z, seed=seed * 100 + i, texel_px=texel))
        elif kind == 1:
            slant = float(40 * torch.rand(1, generator=gen) - 20)
            scenes.append(slanted_plane(rig, z, slant_deg=slant, seed=seed * 100 + i, texel_px=texel))
        elif kind == 2:
            scenes.append(step_scene(rig, z, z + 150, seed=seed * 100 + i, texel_px=texel))
        elif kind == 3:
            picture, bumps = procedural_surface(seed * 100 + i)
            depth = (z + 0.1 * z * bumps).clamp(lo + 10, hi - 10)
            scenes.append(height_field_scene(depth, picture, width_mm=z * 0.21, name=f"surface_{z:.0f}mm"))
        else:  # near: most of the reference half sees what the other half does not
            scenes.append(fronto_parallel_plane(rig, lo + 20 + 100 * u, seed=seed * 100 + i, texel_px=texel))
    return scenes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", type=Path, default=Path(".cache/fit_confidence"), help="renders kept here")
    parser.add_argument("--scenes", type=int, default=10, help="training scenes per setup and sensor size")
    parser.add_argument("--presets", nargs="+", default=("accurate",),
                        help="model presets whose estimates are the samples (one confidence is fitted to them all)")
    parser.add_argument("--scales", type=int, nargs="+", default=(1, 2),
                        help="sensor downscale factors (1: the 1024 x 768 pyramid; 2: 512 x 384, one level)")
    parser.add_argument("--z-range", type=float, nargs=2, default=(205.0, 1511.0), metavar=("ZMIN", "ZMAX"))
    args = parser.parse_args()
    torch.manual_seed(0)
    args.cache.mkdir(parents=True, exist_ok=True)
    xs, ys, per_capture = [], [], []
    xs2, ys2, per_capture2 = [], [], []
    for key, make, scale in ((k, m, s) for k, m in SETUPS.items() for s in args.scales):
        rig = make().downscaled(scale)
        models = {name: PrismStereo.from_config(rig, tuple(args.z_range), name) for name in args.presets}
        w = rig.reference_width
        prefix = f"setup{key}" if scale == 1 else f"setup{key}_x{scale}"
        for i, scene in enumerate(training_scenes(rig, int(key) + 10 * (scale - 1), args.scenes,
                                                  tuple(args.z_range))):
            path = args.cache / f"{prefix}_{i}_{scene.name}.pt"
            if path.exists():
                capture = torch.load(path)
            else:
                formation = ImageFormation(supersample=2, noise_sigma=(1 + i % 2) / 255,
                                           blur_sigma_px=(0.0, 0.0, 1.0, 2.0)[(i // 2) % 4], seed=i)
                capture = render(rig, scene, formation)._asdict()
                torch.save(capture, path)
            for preset_name, model in models.items():
                label = f"{prefix} {preset_name} {scene.name}"
                with torch.inference_mode():
                    inputs = model.confidence_inputs(capture["image"])
                gt, covisible = capture["depth"][..., :w], capture["covisible"][..., :w]
                correct = covisible & ((inputs.depth.double() - gt).abs() <= 0.01 * gt)
                sel = inputs.sampled[:, 0]
                x = inputs.features.permute(0, 2, 3, 1)[sel].double()
                y = correct[:, 0][sel]
                keep = torch.randperm(len(y))[:SAMPLES_PER_CAPTURE]
                xs.append(x[keep])
                ys.append(y[keep])
                per_capture.append((label, inputs.features, inputs.sampled, covisible, correct))
                correct2 = covisible & ((inputs.smoothed_depth.double() - gt).abs() <= 0.01 * gt)
                x2 = inputs.smoothed_features.permute(0, 2, 3, 1)[sel].double()
                xs2.append(x2[keep])
                ys2.append(correct2[:, 0][sel][keep])
                per_capture2.append((label, inputs.smoothed_features, inputs.sampled, covisible, correct2))
                print(f"{label}: {int(sel.sum())} pixels, {100 * float(y.double().mean()):.1f} % correct", flush=True)
    losses = []
    clamped = all(m.final.clamped_band for m in models.values())
    labels = ("CLAMPED_WEIGHTS[0]", "CLAMPED_WEIGHTS[1]") if clamped else ("DEFAULT_WEIGHTS", "SMOOTHED_WEIGHTS")
    for names, label, xs_, ys_, captures in ((FEATURES, labels[0], xs, ys, per_capture),
                                             (SMOOTHED_FEATURES, labels[1], xs2, ys2, per_capture2)):
        x, y = torch.cat(xs_), torch.cat(ys_)
        weights = fit_confidence(x, y)
        logit = x @ weights[:-1] + weights[-1]
        loss = float(F.binary_cross_entropy_with_logits(logit, y.double()))
        losses.append(loss)
        print(f"\nfeatures {', '.join(names)}, bias; {len(y)} samples, log-loss {loss:.4f}")
        print(f"{label} = (" + ", ".join(f"{v:.3f}" for v in weights.tolist()) + ")")
        calibration = ConfidenceModel(weights, names)
        print(f"\n{'capture':40s} {'cover %':>8s} {'wrong %':>8s}   (p >= 0.5, co-visible pixels)")
        for name, features, sampled, covisible, correct in captures:
            with torch.inference_mode():
                p = calibration(features.float())
            accepted = sampled & (p >= 0.5) & covisible
            cover = 100 * float(accepted.sum() / covisible.sum().clamp_min(1))
            wrong = 100 * float((accepted & ~correct).sum() / accepted.sum().clamp_min(1))
            print(f"{name:40s} {cover:8.1f} {wrong:8.2f}")
    if not all(math.isfinite(v) for v in losses):
        raise SystemExit("the fit diverged")


if __name__ == "__main__":
    main()
