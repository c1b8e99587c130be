"""Depth targets of the depth issue: PrismStereo on rendered captures at the thesis depths.

For ``thesis_setup1`` and ``thesis_setup2`` at full resolution (1024 x 768): fronto-parallel textured planes
at the thesis depths (228 ... 1374 mm), 8-bit, read noise sigma = 1/255, 2 x 2 supersampling; then a slanted
plane and a step scene. Prints, per capture, the mean / median relative depth error over co-visible pixels
that are valid, the share of co-visible pixels that are valid (coverage), the share of valid pixels that are
not co-visible (false positives) and the time of one forward pass. Targets: mean <= 0.25 %, coverage >= 95 %.

The searched range is the thesis working range with 10 % margins, 205-1511 mm, so no plane sits on a range
end (where clamping would make the error artificially zero).

``--sampling`` runs every capture through both coarse samplings of the model (the default 'rectified': a 1-D
shift volume on row-rectified halves; 'sweep': the exact per-pixel plane sweep), same fine band.
``--compare`` also runs single-level full searches (``coarse_factor=1``, sweep and rectified) at half
resolution on three planes, to measure what the coarse-to-fine default gives up or gains and how exact the
rectified volume is as a final level.

Captures come from this package's renderer (:mod:`prismstereo.synthetic`): exact ray tracing checked against
an independent closed form (``tests/geometry/test_optics.py``), textures on the surfaces, not in the image.

The models are ``PrismStereo``'s defaults: at 1024 x 768 the pyramid (the 2 x 2-binned model places a final
band of 5 full-resolution hypotheses). ``--downsample K`` evaluates the models that match on K x K-binned
captures (``--downsample 1``: the full-resolution coarse level, an earlier default); with an explicit
``--downsample`` each pixel gets its block's value unless ``--full-band R`` adds the final band of 2 R + 1
hypotheses.

``--band-edges clamp`` refines pixels whose best hypothesis is on the edge of their band from that edge's inner
neighbour instead of rejecting them, in every band (``band_edges='clamp'``; with ``--downsample 2 --full-band 1``
the fast full-resolution setting); ``--band-edges reject`` rejects them in every band. By default a band clamps
where the calibrated confidence judges its pixels (the final band) and rejects where thresholds do (a pyramid's
binned level, ``--validity thresholds``).

``--coarse-factor F`` and ``--band R`` set the coarse level's factor and the half width of the band after it (the
binned model's in a pyramid).

``--directions 2`` limits the coarse level's semi-global aggregation to the horizontal scans.

``--validity thresholds`` decides validity by the NCC and uniqueness thresholds instead of the calibrated
confidence; ``--dense`` evaluates the dense output (coverage, errors and "false" over every pixel with a depth).

``--z-range ZMIN ZMAX`` searches another range (the planes: the thesis depths inside it, each with its seed of the
full list), ``--slanted Z`` and ``--step NEAR FAR`` move the slanted plane and the step scene (defaults 500 mm and
450 / 650 mm, inside the default range). The narrow range of ``benchmarks/onnx_speed.py``:
``--z-range 600 1450 --slanted 900 --step 700 1000``.

Run: .venv/bin/python benchmarks/depth_targets.py [--setups 1 2] [--scale 1] [--sampling] [--compare]
[--downsample K [--full-band R]] [--band-edges clamp] [--coarse-factor F] [--band R] [--directions N]
[--z-range ZMIN ZMAX] [--slanted Z] [--step NEAR FAR] [--validity thresholds] [--dense]
"""

from __future__ import annotations

import argparse
import time

import torch

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.classical.config import PRESETS
from prismstereo.classical.model import PrismStereo
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render, slanted_plane, step_scene
from prismstereo.threads import set_torch_threads

THESIS_DEPTHS = (228.0, 312.0, 353.0, 418.0, 525.0, 625.0, 780.0, 936.0, 1192.0, 1374.0)
Z_RANGE = (205.0, 1511.0)
SETUPS = {"1": thesis_setup1, "2": thesis_setup2}


def evaluate(model: PrismStereo, capture) -> dict[str, float]:
    """Error and coverage of one capture (reference half, co-visible pixels)."""
    t0 = time.perf_counter()
    with torch.inference_mode():
        res = model(capture.image)
    ms = (time.perf_counter() - t0) * 1e3
    w = model.rig.reference_width
    gt, cov = capture.depth[..., :w], capture.covisible[..., :w]
    dense = model.final.config.validity.dense
    has = (res.confidence > 0) if dense else res.valid  # a dense model: every pixel with a depth
    ok = has & cov
    rel = ((res.depth.double() - gt).abs() / gt)[ok]
    return {
        "mean": 100 * float(rel.mean()) if rel.numel() else float("nan"),
        "median": 100 * float(rel.median()) if rel.numel() else float("nan"),
        "bad2": 100 * float((rel > 0.02).double().mean()) if rel.numel() else float("nan"),
        "coverage": 100 * float(ok.sum() / cov.sum().clamp_min(1)),
        "false": 100 * float((has & ~cov).sum() / has.sum().clamp_min(1)),
        "ms": ms,
    }


def row(name: str, r: dict[str, float]) -> str:
    return (f"{name:28s} {r['mean']:8.3f} {r['median']:8.3f} {r['bad2']:7.2f} {r['coverage']:8.1f} "
            f"{r['false']:7.2f} {r['ms']:9.0f}")


HEADER = f"{'capture':28s} {'mean %':>8s} {'median %':>8s} {'>2% %':>7s} {'cover %':>8s} {'false %':>7s} {'ms':>9s}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--setups", nargs="+", default=["1", "2"], choices=sorted(SETUPS))
    parser.add_argument("--scale", type=int, default=1, help="sensor downscale factor (1 = full resolution)")
    parser.add_argument("--sampling", action="store_true", help="also the coarse level as the exact sweep")
    parser.add_argument("--compare", action="store_true", help="also single-level full searches (half res)")
    parser.add_argument("--downsample", type=int, default=None, metavar="K",
                        help="the models match on KxK-binned captures (option downsample=K; default: the "
                             "model's)")
    parser.add_argument("--full-band", type=int, default=None, metavar="R",
                        help="with --downsample: a final full-resolution band of 2R+1 hypotheses (full_band=R)")
    parser.add_argument("--band-edges", choices=("reject", "clamp"), default=None,
                        help="option band_edges=...: pixels whose best hypothesis is on a band's edge (default: "
                             "the model's)")
    parser.add_argument("--coarse-factor", type=int, default=None, metavar="F",
                        help="option coarse_factor=F (of the binned model with --downsample); default: the "
                             "model's")
    parser.add_argument("--band", type=int, default=None, metavar="R",
                        help="option band=R: the coarse level's fine band (the binned model's in a pyramid)")
    parser.add_argument("--directions", type=int, default=None, choices=(2, 4, 8),
                        help="option directions=...: SGM scan directions of the coarse level (default: the model's)")
    parser.add_argument("--validity", choices=("calibrated", "thresholds"), default=None,
                        help="option validity=...: the calibrated confidence (default) or the NCC thresholds")
    parser.add_argument("--dense", action="store_true", default=None,
                        help="option dense=True: coverage and errors of every pixel with a depth")
    parser.add_argument("--preset", choices=tuple(PRESETS), default=None,
                        help="a named preset under the options above (e.g. 'dense': its own coarse cost and "
                             "aggregation)")
    parser.add_argument("--smoothing", type=int, default=None, metavar="N",
                        help="option smoothing=N: the robust mean's window (0: off; default: the model's)")
    parser.add_argument("--z-range", type=float, nargs=2, default=Z_RANGE, metavar=("ZMIN", "ZMAX"),
                        help="searched depth range, mm (default: the thesis range with 10 %% margins)")
    parser.add_argument("--slanted", type=float, default=500.0, metavar="Z",
                        help="the slanted plane passes through this depth, mm")
    parser.add_argument("--step", type=float, nargs=2, default=(450.0, 650.0), metavar=("NEAR", "FAR"),
                        help="depths of the step scene, mm")
    args = parser.parse_args()
    z_range = tuple(args.z_range)
    if not (0 < z_range[0] < z_range[1] and all(z_range[0] <= z <= z_range[1] for z in (args.slanted, *args.step))):
        parser.error(f"need 0 < ZMIN < ZMAX around --slanted and --step, got {z_range}, {args.slanted}, {args.step}")
    set_torch_threads(2)
    form = ImageFormation(supersample=2, noise_sigma=1 / 255, bits=8)
    for key in args.setups:
        rig = SETUPS[key]().downscaled(args.scale)
        models = {}
        for sampling in ("rectified", "sweep") if args.sampling else ("rectified",):
            t0 = time.perf_counter()
            # the options given explicitly (the rest: the preset's, or the model's defaults)
            options = dict(sampling=sampling if args.sampling else None, downsample=args.downsample,
                           full_band=args.full_band, band_edges=args.band_edges, coarse_factor=args.coarse_factor,
                           band=args.band, directions=args.directions, validity=args.validity, dense=args.dense,
                           smoothing=args.smoothing)
            options = {k: v for k, v in options.items() if v is not None}
            config = PRESETS[args.preset or "accurate"].with_options(**options)
            model = models[sampling] = PrismStereo(rig, z_range, config)
            print(f"\nthesis_setup{key} {rig.image_width}x{rig.image_height}: {model.summary()}; model built in "
                  f"{time.perf_counter() - t0:.1f} s")
        print(HEADER)
        results: dict[str, list[dict[str, float]]] = {name: [] for name in models}
        tag = (lambda name: f" [{name}]") if len(models) > 1 else (lambda name: "")
        for i, z in enumerate(THESIS_DEPTHS):
            if not z_range[0] <= z <= z_range[1]:
                continue
            capture = render(rig, fronto_parallel_plane(rig, z, seed=i), form)
            for name, model in models.items():
                r = evaluate(model, capture)
                results[name].append(r)
                print(row(f"plane {z:g} mm{tag(name)}", r), flush=True)
        for name, rs in results.items():
            if not rs:  # no thesis depth inside the range
                continue
            worst_mean = max(r["mean"] for r in rs)
            worst_cov = min(r["coverage"] for r in rs)
            print(f"{('planes: worst' + tag(name)):28s} {worst_mean:8.3f} {'':8s} {'':7s} {worst_cov:8.1f}   "
                  f"(targets: mean <= 0.25 %, coverage >= 95 %)")
        near, far = args.step
        scenes = ((f"slanted 30 deg @ {args.slanted:g} mm", slanted_plane(rig, args.slanted, 30.0, seed=11)),
                  (f"step {near:g} / {far:g} mm", step_scene(rig, near, far, seed=12)))
        for label, scene in scenes:
            capture = render(rig, scene, form)
            for name, model in models.items():
                print(row(f"{label}{tag(name)}", evaluate(model, capture)), flush=True)
        if args.compare:
            half = rig.downscaled(2)
            print(f"\nthesis_setup{key} at half resolution: coarse-to-fine (default) vs single-level full search")
            print(HEADER)
            models = {"coarse-to-fine": PrismStereo(half, z_range),
                      "single sweep": PrismStereo(half, z_range, dict(coarse_factor=1)),
                      "single rectified": PrismStereo(half, z_range, dict(coarse_factor=1, sampling="rectified"))}
            for z in (z for z in (312.0, 625.0, 1192.0) if z_range[0] <= z <= z_range[1]):
                cap = render(half, fronto_parallel_plane(half, z, seed=3), form)
                for name, m in models.items():
                    print(row(f"{name} {z:g} mm", evaluate(m, cap)), flush=True)


if __name__ == "__main__":
    main()
