"""Fit the calibrated confidence of PrismStereo (``prismstereo.matching.confidence.DEFAULT_WEIGHTS`` and
``SMOOTHED_WEIGHTS``).

Renders training captures of ``thesis_setup1`` and ``thesis_setup2`` at full resolution with this package's
renderer: fronto-parallel planes (near ones included, where most of the reference half is not co-visible),
slanted planes, depth steps, and smooth procedural height fields whose texture is strong in some regions and
nearly absent in others (contrast 0.01-0.21, with slow shading), with read noise of 1-2 grey levels and some
blur. ``--photos skimage`` (scikit-image's installed sample data, ``pip install -e .[fit]``) or ``--photos DIR``
(a folder with its files) adds photographs per setup and sensor size: its sample of the Middlebury 2014
*Motorcycle* pair with its true disparity (:func:`~prismstereo.synthetic.disparity_scene`, three depth ranges, one
mirrored) and two of its other sample photographs on procedural bumps; the shipped weights were fitted without
them (what they changed: ``docs/design.md``, *How the model picks its defaults*, confidence weights). None of the
held-out scenes of ``benchmarks/dense_depth.py`` (the Middlebury photographs Tsukuba and Venus, the defocus
captures) is used.
Every pixel with an estimate is a sample: correct when it is co-visible and its depth is within 1 % of the truth,
wrong otherwise (pixels the other half does not see included). Prints the fitted weights (paste them into
``DEFAULT_WEIGHTS``), the training log-loss and, per capture, the coverage and wrong share at p >= 0.5. Then the
second stage, the re-scoring after the model's smoothing (``SMOOTHED_WEIGHTS``, on
:data:`~prismstereo.matching.confidence.SMOOTHED_FEATURES` of the smoothed depth), fitted on the smoothing that the
new first stage weights (the models are run again with it). ``--presets fast`` fits the weights of models whose
final band clamps its edges (``CLAMPED_WEIGHTS``).

``--band-edges`` (default ``reject``) sets the final band's edge rule of the presets that leave it to the model
(``band_edges=None``; not dense ones): the shipped ``DEFAULT_WEIGHTS`` and ``SMOOTHED_WEIGHTS`` were fitted on
bands that reject their edges and are kept for the default's clamped final band (``docs/design.md``, *How the
model picks its defaults*, confidence weights: refitted on its estimates they were more conservative on the held-out
captures without a better trade-off); ``--band-edges preset`` fits each preset as it is.

Run: .venv/bin/python benchmarks/fit_confidence.py [--cache DIR] [--scenes N] [--photos skimage | DIR]
[--presets NAME ...] [--band-edges reject | clamp | preset] [--z-range ZMIN ZMAX]
"""

from __future__ import annotations

import argparse
import importlib.util
import math
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.classical.config import preset
from prismstereo.classical.model import PrismStereo
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.learned.data import procedural_picture
from prismstereo.matching.confidence import FEATURES, SMOOTHED_FEATURES, ConfidenceModel, fit_confidence
from prismstereo.synthetic import (
    ImageFormation,
    Scene,
    disparity_scene,
    fronto_parallel_plane,
    height_field_scene,
    render,
    slanted_plane,
    step_scene,
)

SETUPS = {"1": thesis_setup1, "2": thesis_setup2}
SAMPLES_PER_CAPTURE = 200_000
PHOTOS = ("astronaut.png", "coffee.png", "chelsea.png", "rocket.jpg", "camera.png", "brick.png", "grass.png",
          "gravel.png")
MOTORCYCLE_RANGES = ((450.0, 900.0), (300.0, 600.0), (700.0, 1300.0))


def fit_options(name: str, band_edges: str = "reject") -> dict:
    """The options of the model whose estimates are fitted for preset ``name``: the preset, with
    ``band_edges`` (``'reject'`` or ``'clamp'``) where it leaves the final band's edge rule to the model (not a
    dense preset, whose bands always clamp); ``'preset'``: the preset as it is."""
    config = preset(name)
    if band_edges == "preset" or config.search.band_edges is not None or config.validity.dense:
        return config.to_options()
    return config.with_options(band_edges=band_edges).to_options()


def procedural_surface(seed: int, h: int = 360, w: int = 480) -> tuple[torch.Tensor, torch.Tensor]:
    """(picture (h, w) in [0, 1], bumps (h, w) of unit scale) of seed ``seed``:
    :func:`~prismstereo.learned.data.procedural_picture` (texture strong in some regions, nearly absent in others,
    on smooth shading; the bumps a sum of four random Gaussians)."""
    return procedural_picture(torch.Generator().manual_seed(seed), h, w)


def bumpy_surface(picture: torch.Tensor, bumps: torch.Tensor, z: float, z_range: tuple[float, float],
                  name: str) -> Scene:
    """``picture`` on a height field at ``z`` mm bent by 10 % of z times ``bumps``, inside ``z_range`` (10 mm margins),
    0.21 z wide."""
    depth = (z + 0.1 * z * bumps).clamp(z_range[0] + 10, z_range[1] - 10)
    return height_field_scene(depth, picture, width_mm=z * 0.21, name=name)


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
            scenes.append(bumpy_surface(picture, bumps, z, z_range, f"surface_{z:.0f}mm"))
        else:  # near: most of the reference half sees what the other half does not
            scenes.append(fronto_parallel_plane(rig, lo + 20 + 100 * u, seed=seed * 100 + i, texel_px=texel))
    return scenes


def photo_folder(choice: str | None) -> Path | None:
    """The folder of the training photographs: None (none), scikit-image's installed sample data ('skimage') or
    the folder ``choice``."""
    if choice is None:
        return None
    if choice != "skimage":
        return Path(choice)
    spec = importlib.util.find_spec("skimage")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("--photos skimage needs scikit-image: pip install -e .[fit] (or --photos DIR with its "
                         "sample files)")
    return Path(next(iter(spec.submodule_search_locations))) / "data"


def grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise SystemExit(f"cannot read {path}")
    return img


def photo_scenes(folder: Path, seed: int, z_range: tuple[float, float]) -> list[Scene]:
    """The Motorcycle pair's left photograph with its true depth over three ranges (the second mirrored), then two
    sample photographs (picked by ``seed``) on procedural bumps."""
    gen = torch.Generator().manual_seed(seed)
    picture = torch.from_numpy(grey(folder / "motorcycle_left.png")).float() / 255.0
    disparity = torch.from_numpy(np.load(folder / "motorcycle_disp.npz")["arr_0"])
    scenes = []
    for j, (near, far) in enumerate(MOTORCYCLE_RANGES):
        pic, disp = (picture.flip(-1), disparity.flip(-1)) if j == 1 else (picture, disparity)
        scenes.append(disparity_scene(pic, disp, near, far, name=f"motorcycle_{near:.0f}-{far:.0f}"))
    lo, hi = z_range
    for j in range(2):
        name = PHOTOS[int(torch.randint(len(PHOTOS), (1,), generator=gen))]
        img = grey(folder / name)
        _, bumps = procedural_surface(seed * 100 + 50 + j, img.shape[0], img.shape[1])
        z = lo + 100 + (hi - lo - 400) * float(torch.rand(1, generator=gen))
        scenes.append(bumpy_surface(torch.from_numpy(img).float() / 255.0, bumps, z, z_range,
                                    f"photo_{Path(name).stem}_{z:.0f}mm"))
    return scenes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", type=Path, default=Path(".cache/fit_confidence"), help="renders kept here")
    parser.add_argument("--scenes", type=int, default=10, help="training scenes per setup and sensor size")
    parser.add_argument("--photos", default=None,
                        help="add photographs: 'skimage' (the installed package's sample data) or its folder")
    parser.add_argument("--presets", nargs="+", default=("accurate",),
                        help="model presets whose estimates are the samples (one confidence is fitted to them all)")
    parser.add_argument("--band-edges", choices=("reject", "clamp", "preset"), default="reject",
                        help="the final band's edge rule of presets that leave it to the model (see the docstring)")
    parser.add_argument("--scales", type=int, nargs="+", default=(1, 2),
                        help="sensor downscale factors (1: the 1024 x 768 pyramid; 2: 512 x 384, one level)")
    parser.add_argument("--z-range", type=float, nargs=2, default=(205.0, 1511.0), metavar=("ZMIN", "ZMAX"))
    args = parser.parse_args()
    photos = photo_folder(args.photos)
    args.cache.mkdir(parents=True, exist_ok=True)
    captures = []  # (rig, label prefix, scene name, cache path)
    for key, make, scale in ((k, m, s) for k, m in SETUPS.items() for s in args.scales):
        rig = make().downscaled(scale)
        prefix = f"setup{key}" if scale == 1 else f"setup{key}_x{scale}"
        seed = int(key) + 10 * (scale - 1)
        scenes = training_scenes(rig, seed, args.scenes, tuple(args.z_range))
        if photos is not None:
            scenes += photo_scenes(photos, seed, tuple(args.z_range))
        for i, scene in enumerate(scenes):
            path = args.cache / f"{prefix}_{i}_{scene.name}.pt"
            if not path.exists():
                formation = ImageFormation(supersample=2, noise_sigma=(1 + i % 2) / 255,
                                           blur_sigma_px=(0.0, 0.0, 1.0, 2.0)[(i // 2) % 4], seed=i)
                torch.save(render(rig, scene, formation)._asdict(), path)
            captures.append((rig, prefix, scene.name, path))
    models = {}  # per rig: the presets' models
    for stage, names in ((1, FEATURES), (2, SMOOTHED_FEATURES)):
        torch.manual_seed(0)  # the same samples in both stages
        xs, ys, per_capture = [], [], []
        for rig, prefix, scene_name, path in captures:
            if rig not in models:
                models[rig] = {n: PrismStereo(rig, tuple(args.z_range), fit_options(n, args.band_edges))
                               for n in args.presets}
            capture = torch.load(path)
            w = rig.reference_width
            for preset_name, model in models[rig].items():
                label = f"{prefix} {preset_name} {scene_name}"
                with torch.inference_mode():
                    inputs = model.confidence_inputs(capture["image"])
                gt, covisible = capture["depth"][..., :w], capture["covisible"][..., :w]
                depth = inputs.depth if stage == 1 else inputs.smoothed_depth
                features = inputs.features if stage == 1 else inputs.smoothed_features
                correct = covisible & ((depth.double() - gt).abs() <= 0.01 * gt)
                sel = inputs.sampled[:, 0]
                y = correct[:, 0][sel]
                keep = torch.randperm(len(y))[:SAMPLES_PER_CAPTURE]
                xs.append(features.permute(0, 2, 3, 1)[sel].double()[keep])
                ys.append(y[keep])
                per_capture.append((label, features, inputs.sampled, covisible, correct))
                if stage == 1:
                    print(f"{label}: {int(sel.sum())} pixels, {100 * float(y.double().mean()):.1f} % correct",
                          flush=True)
        clamped = all(m.final.config.validity.confidence_weights == "clamped"
                      for ms in models.values() for m in ms.values())
        label = f"CLAMPED_WEIGHTS[{stage - 1}]" if clamped else ("DEFAULT_WEIGHTS", "SMOOTHED_WEIGHTS")[stage - 1]
        x, y = torch.cat(xs), torch.cat(ys)
        # the second stage's own-confidence weight is kept >= 0: collinear with the window's mean confidence, it comes
        # out negative on the current chain (-1.6 with --photos), which would make a pixel with more evidence of its
        # own less trusted than its neighbour
        weights = fit_confidence(x, y, nonnegative=[SMOOTHED_FEATURES.index("confidence")] if stage == 2 else [])
        logit = x @ weights[:-1] + weights[-1]
        loss = float(F.binary_cross_entropy_with_logits(logit, y.double()))
        print(f"\nfeatures {', '.join(names)}, bias; {len(y)} samples, log-loss {loss:.4f}")
        print(f"{label} = (" + ", ".join(f"{v:.3f}" for v in weights.tolist()) + ")")
        if not math.isfinite(loss):
            raise SystemExit("the fit diverged")
        if stage == 1:  # stage 2 re-scores the smoothing that the new first stage weights (as printed and pasted)
            for model in (m for ms in models.values() for m in ms.values()):
                model.final.calibration = ConfidenceModel([round(v, 3) for v in weights.tolist()])
        calibration = ConfidenceModel(weights, names)
        print(f"\n{'capture':40s} {'cover %':>8s} {'wrong %':>8s}   (p >= 0.5, co-visible pixels)")
        for name, features, sampled, covisible, correct in per_capture:
            with torch.inference_mode():
                p = calibration(features.float())
            accepted = sampled & (p >= 0.5) & covisible
            cover = 100 * float(accepted.sum() / covisible.sum().clamp_min(1))
            wrong = 100 * float((accepted & ~correct).sum() / accepted.sum().clamp_min(1))
            print(f"{name:40s} {cover:8.1f} {wrong:8.2f}")


if __name__ == "__main__":
    main()
