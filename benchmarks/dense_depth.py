"""Dense depth on realistic surfaces: weak texture, defocus, Fresnel; the default, the dense output and the
thresholds of the earlier default, side by side.

Captures (``thesis_setup1``, 1024 x 768, 2 x 2 supersampling, read noise 2/255, Fresnel transmission of both
prism faces, 8 bits):

* the Middlebury photographs Tsukuba and Venus as height fields 450-900 mm in front of the prism
  (``middlebury_scene``): weakly textured walls, cloth, a plaster head, slanted and stepped surfaces;
* a textured plane at 400 mm behind a thin lens focused at 600 mm, at f/12.5 and f/6.25 (blur circles of
  ~9.5 and ~19 px on the plane, ``ImageFormation(f_number=...)``);
* a smooth weakly textured height field (the procedural surfaces of ``benchmarks/fit_confidence.py`` with a
  seed that training does not use).

None of them is used to fit the confidence (``benchmarks/fit_confidence.py``). Per capture and model:
coverage (co-visible reference pixels with a depth: valid ones, or for the dense output every pixel it gives a
depth), bad>1 % (share of those off by more than 1 %), mean relative error, time of one forward pass. Then the
reliability of the confidence over all captures (dense output): for each c, the share of co-visible pixels
with confidence >= c and how many of them are off by more than 1 %; per capture and dense model, the largest
share of the co-visible pixels a threshold on the confidence keeps at <= 5 % off by > 1 % (``threshold``), and what
a perfect ranking of the same depths would keep (``perfect``: the right ones plus wrong ones up to 5 %: the
ceiling of any validity rule on these estimates). Last, for the captures with depth jumps
(neighbouring true depths more than 1 % apart: the photographs), where the errors are: coverage and bad>1 % by
the distance of a pixel to the nearest jump, for the default, the dense output, the reference and the ``--model``
additions; whether the jumps show in the image (the percentile of the grey gradient at jump pixels among all
co-visible pixels'); and the share of pixels that neither the dense output nor the reference's estimates get
within 1 % (what a per-pixel choice between the two chains, made by an oracle, would leave wrong).

Models: ``thresholds`` = ``{'validity': 'thresholds', 'smoothing': 0}`` (NCC >= 0.5 and a coarse uniqueness
>= 0.3: the earlier default), ``unsmoothed`` = the calibrated confidence without the smoothing of the estimate
(``smoothing=0``), ``reject edges`` = the defaults with ``band_edges='reject'`` (the final band's edge pixels
invalid instead of refined from the inner neighbour and judged by the confidence: the previous default),
``default`` = the model's defaults (calibrated confidence >= 0.5, smoothing), ``fast`` = the
``'fast'`` preset (a full-resolution band of 3 with clamped edges, its own confidence weights), ``dense`` = the
``'dense'`` preset (``dense=True``, ``coarse_factor=2``, the coarse level matched by cost-volume filtering:
``cost='ad_gradient', aggregation='guided', box=1``; coverage counts every pixel with a depth, and its ``valid``
mask is reported as ``dense valid``), ``dense sgm`` = the previous 'dense' preset (the default's semi-global ZNCC
coarse level), ``dense cf1`` = the 'dense' preset with ``coarse_factor=1`` (in the pyramid: the binned model
filters the whole range at its own resolution, several times the work; not on sensors without a pyramid),
``reference`` =
the ``'reference'`` preset: no coarse-to-fine placement at all, one level that searches the whole range at full
resolution (semi-global ZNCC on the exact sweep; slow in torch), reported on its valid
pixels (NCC thresholds) and as ``reference all`` on every co-visible pixel with a finite depth, before its
validity rules.
``--model NAME=JSON`` adds a model by its options (``PrismStereo``'s config keywords; ``{"preset": "dense",
...}`` starts from a preset), e.g. ``--model 'no fill={"preset": "dense", "dense_fill": 0}'``; one without a
dense output gets a ``NAME all`` row too.

Run: .venv/bin/python benchmarks/dense_depth.py [--z-range ZMIN ZMAX] [--scale K] [--cache DIR] [--model NAME=JSON]
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from kornia.filters import sobel

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_confidence import procedural_surface  # noqa: E402

from prismstereo import thesis_setup1  # noqa: E402
from prismstereo.classical.config import preset  # noqa: E402
from prismstereo.classical.defaults import default_downsample  # noqa: E402
from prismstereo.classical.model import PrismStereo  # noqa: E402
from prismstereo.matching.confidence import confidence_threshold  # noqa: E402
from prismstereo.synthetic import (  # noqa: E402
    ImageFormation,
    fronto_parallel_plane,
    height_field_scene,
    middlebury_scene,
    render,
)
from prismstereo.threads import set_torch_threads  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"
MODELS = {"thresholds": {"validity": "thresholds", "smoothing": 0}, "unsmoothed": {"smoothing": 0},
          "reject edges": {"band_edges": "reject"}, "default": {},
          "fast": preset("fast").to_options(), "dense": preset("dense").to_options(),
          "dense sgm": {"dense": True, "coarse_factor": 2},
          "dense cf1": preset("dense").with_options(coarse_factor=1).to_options(),
          "reference": preset("reference").to_options()}
WHOLE = ("reference",)  # models also scored on every pixel with a finite depth (``NAME all``)
LEVELS = (0.1, 0.3, 0.5, 0.7, 0.8, 0.9, 0.95)
# the rows of the table by distance to a depth jump (and every --model's)
JUMP_ROWS = ("default", "dense", "dense valid", "reference", "reference all")
JUMP_BANDS = ((0, 2), (2, 4), (4, 8), (8, 16), (16, None))  # px


def captures(rig, cache: Path) -> dict[str, dict]:
    """The held-out captures (rendered once, kept in ``cache``)."""
    base = dict(supersample=2, noise_sigma=2 / 255, fresnel=True, seed=7)
    picture, bumps = procedural_surface(9001)
    specs = {
        "Tsukuba 450-900 mm": (lambda: middlebury_scene(DATA / "Tsukuba", 450.0, 900.0), {}),
        "Venus 450-900 mm": (lambda: middlebury_scene(DATA / "Venus", 450.0, 900.0), {}),
        "weak surface 520-680 mm": (
            lambda: height_field_scene(600.0 + 60.0 * bumps.clamp(-1.3, 1.3), picture, 126.0, name="weak"), {}),
        "plane 400 mm f/12.5 @600": (lambda: fronto_parallel_plane(rig, 400.0, seed=5), {"f_number": 12.5}),
        "plane 400 mm f/6.25 @600": (lambda: fronto_parallel_plane(rig, 400.0, seed=5), {"f_number": 6.25}),
    }
    out = {}
    cache.mkdir(parents=True, exist_ok=True)
    for name, (scene, extra) in specs.items():
        path = cache / f"{rig.image_width}_{name.replace(' ', '_').replace('/', '')}.pt"
        if not path.exists():
            torch.save(render(rig, scene(), ImageFormation(**base, **extra))._asdict(), path)
        out[name] = torch.load(path)
    return out


def scores(rel: torch.Tensor, has: torch.Tensor, covisible: torch.Tensor) -> tuple[float, float, float]:
    """(coverage %, bad>1 % share %, mean relative error %) of the co-visible pixels in ``has``, from the
    relative depth errors ``rel`` (NaN for bad and mean where none is covered)."""
    sel = has & covisible
    cover = 100 * float(sel.sum() / covisible.sum())
    bad = 100 * float((rel[sel] > 0.01).double().mean()) if sel.any() else float("nan")
    mean = 100 * float(rel[sel].mean()) if sel.any() else float("nan")
    return cover, bad, mean


def best_coverage(confidence: torch.Tensor, right: torch.Tensor, covisible: int, bad: float = 0.05
                  ) -> tuple[float, float, float]:
    """(coverage %, its threshold) of the largest set of pixels with confidence >= a threshold that is at most
    ``bad`` wrong, and the coverage % of a perfect ranking (every right pixel, then wrong ones up to ``bad``), from
    (N,) ``confidence`` and bool ``right`` of the pixels with a depth among ``covisible`` pixels."""
    threshold, k = confidence_threshold(confidence, right, bad)
    perfect = min(len(confidence), float(right.sum()) / (1 - bad))
    return 100 * k / covisible, threshold, 100 * perfect / covisible


def jump_distance(depth: torch.Tensor, jump: float = 0.01) -> torch.Tensor:
    """(H, W) distance in px from each pixel to the nearest one whose true depth differs from a 4-neighbour's by
    more than ``jump`` (relative to the nearer of the two), from (H, W) ``depth``; inf without any jump."""
    d = depth.double()
    edges = torch.zeros_like(d, dtype=torch.bool)
    for a, b, at_a, at_b in ((d[:, :-1], d[:, 1:], (slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                             (d[:-1], d[1:], (slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
        step = (a - b).abs() / torch.minimum(a, b) > jump
        edges[at_a] |= step
        edges[at_b] |= step
    if not edges.any():
        return torch.full_like(d, float("inf"))
    distance = cv2.distanceTransform((~edges).numpy().astype(np.uint8), cv2.DIST_L2, 5)
    return torch.from_numpy(distance).double()


def edge_strength(image: torch.Tensor, distance: torch.Tensor, covisible: torch.Tensor) -> tuple[float, float]:
    """Whether the depth jumps of a capture show in its image: the percentile of each jump pixel's grey gradient
    (Sobel magnitude, kornia's, its largest within 1 px) among the co-visible pixels', as (median %, share % of
    jump pixels below the median pixel's), from (C, H, W) ``image``, the (H, W) :func:`jump_distance` of its true
    depth (jump pixels: 0) and bool ``covisible``; (nan, nan) without jumps. A jump that an edge marks scores
    near 100; one with no trace in the image, like any pixel."""
    strength = torch.nn.functional.max_pool2d(sobel(image.double().mean(0)[None, None]), 3, 1, 1)[0, 0]
    jump = (distance < 1) & covisible
    if not jump.any():
        return float("nan"), float("nan")
    ranks = torch.searchsorted(strength[covisible].sort().values, strength[jump]).double() / int(covisible.sum())
    return 100 * float(ranks.median()), 100 * float((ranks < 0.5).double().mean())


def model_config(spec: str) -> tuple[str, dict]:
    """``NAME=JSON`` (``--model``; the name may contain ``=``, the JSON starts at the first ``={``): the name and
    the model's keyword options (``"preset"`` starts from one)."""
    found = re.match(r"(.+?)=\s*(\{.*)$", spec, re.S)
    name, sep, text = (found.group(1), "=", found.group(2)) if found else spec.partition("=")
    if not sep or not name:
        raise SystemExit(f"--model takes NAME=JSON, got {spec!r}")
    try:
        options = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SystemExit(f"--model {name}: not JSON ({exc})") from exc
    if not isinstance(options, dict):
        raise SystemExit(f"--model {name}: the options must be a JSON object, got {text!r}")
    if "preset" in options:
        options = dict(options)
        options = preset(options.pop("preset")).with_options(**options).to_options()
    return name, options


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--z-range", type=float, nargs=2, default=(205.0, 1511.0), metavar=("ZMIN", "ZMAX"))
    parser.add_argument("--scale", type=int, default=1, help="sensor downscale factor")
    parser.add_argument("--cache", type=Path, default=Path(".cache/dense_depth"))
    parser.add_argument("--model", action="append", default=[], metavar="NAME=JSON",
                        help="add a model by its options (see the module docstring)")
    args = parser.parse_args()
    extra = dict(model_config(spec) for spec in args.model)
    set_torch_threads(2)
    rig = thesis_setup1() if args.scale == 1 else thesis_setup1().downscaled(args.scale)
    caps = captures(rig, args.cache)
    pyramid = default_downsample(rig) > 1  # 'dense cf1' needs the binned model (a single level has
    models = {k: PrismStereo(rig, tuple(args.z_range), v) for k, v in MODELS.items()  # no band after a factor 1)
              if pyramid or k != "dense cf1"}
    models.update({k: PrismStereo(rig, tuple(args.z_range), v) for k, v in extra.items()})
    print(f"thesis_setup1 {rig.image_width}x{rig.image_height}, searched {args.z_range[0]:g}-{args.z_range[1]:g} mm; "
          f"{models['default'].summary()}")
    width = max(15, *(len(k) + 6 for k in models))  # the model column (a dense model's "NAME valid" rows)
    print(f"{'capture':26s} {'model':{width}s} {'cover %':>8s} {'bad>1% %':>9s} {'mean %':>8s} {'ms':>6s}")
    w = rig.reference_width
    pooled_p, pooled_ok = [], []
    jumps = {}  # capture -> (distance to a jump, [(label, relative errors, mask)]), the captures with jumps
    ceilings = []  # (capture, model, threshold's coverage, its threshold, a perfect ranking's coverage)
    for name, cap in caps.items():
        gt, covisible = cap["depth"][..., :w], cap["covisible"][..., :w]
        distance = jump_distance(gt[0, 0])
        for key, model in models.items():
            t0 = time.perf_counter()
            with torch.inference_mode():
                res = model(cap["image"])
            ms = 1e3 * (time.perf_counter() - t0)
            rel = (res.depth.double() - gt).abs() / gt
            dense = model.final.config.validity.dense  # coverage counts every pixel with a depth
            rows = [(key, res.valid)] if not dense else [(key, res.confidence > 0), (f"{key} valid", res.valid)]
            if (key in extra or key in WHOLE) and not dense:  # its estimate everywhere, before the validity rules
                rows.append((f"{key} all", torch.isfinite(res.depth)))
            for label, has in rows:
                cover, bad, mean = scores(rel, has, covisible)
                print(f"{name:26s} {label:{width}s} {cover:8.1f} {bad:9.2f} {mean:8.3f} {ms:6.0f}")
                if torch.isfinite(distance).any() and (label in JUMP_ROWS or key in extra):
                    jumps.setdefault(name, (distance, []))[1].append((label, rel, has))
            if dense:  # what a threshold on its confidence keeps at <= 5 % off
                sel = (res.confidence > 0) & covisible
                ceilings.append((name, key, *best_coverage(res.confidence[sel], rel[sel] <= 0.01,
                                                           int(covisible.sum()))))
            if key == "dense":  # every co-visible pixel with a depth
                sel = (res.confidence > 0) & covisible
                pooled_p.append(res.confidence[sel])
                pooled_ok.append(rel[sel] <= 0.01)
    p, ok = torch.cat(pooled_p), torch.cat(pooled_ok)
    print("\nreliability of the dense output's confidence, all captures pooled (co-visible pixels):")
    print(f"{'confidence >=':>14s} {'share %':>8s} {'bad>1% %':>9s} {'1 - mean conf %':>16s}")
    for c in LEVELS:
        sel = p >= c
        share = 100 * float(sel.double().mean())
        wrong = 100 * float((~ok[sel]).double().mean()) if sel.any() else float("nan")
        expected = 100 * float(1 - p[sel].double().mean()) if sel.any() else float("nan")
        print(f"{c:14.2f} {share:8.1f} {wrong:9.2f} {expected:16.2f}")
    print("\nthe most a threshold on a dense model's confidence keeps at <= 5 % off by > 1 % (co-visible pixels), "
          "and a perfect ranking of its depths")
    print(f"{'capture':26s} {'model':{width}s} {'threshold %':>11s} {'at conf':>8s} {'perfect %':>10s}")
    for name, key, cover, threshold, perfect in ceilings:
        print(f"{name:26s} {key:{width}s} {cover:11.1f} {threshold:8.3f} {perfect:10.1f}")
    if jumps:
        print("\nby distance to a depth jump (true depths of neighbours > 1 % apart), co-visible pixels: the band's "
              "share of them, then per model cover % / bad>1 % of the covered")
        bands = [f"{lo}-{hi} px" if hi else f">= {lo} px" for lo, hi in JUMP_BANDS]
        print(f"{'capture':26s} {'model':{width}s} " + " ".join(f"{b:>13s}" for b in bands))
    for name, (distance, entries) in jumps.items():
        covisible = caps[name]["covisible"][0, 0, :, :w]
        median, below = edge_strength(caps[name]["image"][0, :, :, :w], distance, covisible)
        print(f"{name:26s} image edges at the jumps: gradient percentile median {median:.0f}, {below:.0f} % of the "
              "jump pixels below the median pixel's")
        masks = [covisible & (distance >= lo) & (distance < (hi or float("inf"))) for lo, hi in JUMP_BANDS]
        shares = [100 * float(m.sum() / covisible.sum()) for m in masks]
        print(f"{name:26s} {'share %':{width}s} " + " ".join(f"{v:13.1f}" for v in shares))
        for label, rel, has in entries:
            cells = []
            for m in masks:
                cover, bad, _ = scores(rel[0, 0], has[0, 0], m)
                cells.append(f"{cover:5.1f} / {bad:5.1f}")
            print(f"{'':26s} {label:{width}s} " + " ".join(f"{c:>13s}" for c in cells))
        right = {label: (rel <= 0.01) & has for label, rel, has in entries}
        if "dense" in right and "reference all" in right:  # a per-pixel choice between the two, by an oracle
            either = (right["dense"] | right["reference all"])[0, 0] & covisible
            print(f"{'':26s} neither the dense output nor the reference's estimates within 1 %: "
                  f"{100 * (1 - float(either.sum() / covisible.sum())):.1f} % of the co-visible pixels")


if __name__ == "__main__":
    main()
