"""One dense, exact and fast default: every candidate chain on photographs as surfaces, textured planes and defocus,
on three sensors, with each exported graph's time against OpenCV's StereoSGBM in the same run (228-1374 mm).

Sensors (:data:`SENSORS`): ``thesis_setup1`` at 1024 x 768 and binned to 512 x 384, and a rig no training saw
(:func:`other_rig`: 1920 x 1080, 3.45 um pixels, 16 mm lens, a 9 degree N-BK7 prism 150 mm away). Captures per
sensor (held out from every training and fit; 2 x 2 supersampling, read noise 2/255, Fresnel, 8 bits): the
Middlebury photographs Tsukuba and Venus and scikit-image's stereo Motorcycle (sub-pixel truth) as height fields
450-900 mm in front of the prism; a weakly textured height field; a textured plane at 525 mm (at 1024 x 768 through
each thesis setup); a plane at 400 mm behind a thin lens focused at 600 mm at f/12.5 and f/6.25. The Middlebury and
defocus renders are ``benchmarks/dense_depth.py``'s (shared cache).

Chains: ``accurate`` (:class:`~prismstereo.PrismStereo`'s defaults: the pyramid with the calibrated confidence),
``dense`` (its 'dense' preset), ``learned`` (:class:`~prismstereo.learned.LearnedStereo`, hypotheses by range;
only when asked for by ``--chains``: seconds a capture), ``block`` (the hybrid's classical level alone: block
mode on 4 x 4-binned pixels, 2 x 2 where the hybrid's stages run at full resolution (512 x 384), dense),
``hybrid-block`` (the hybrid started from that level: the stages' weights ``HYBRID_BLOCK_WEIGHTS``, trained on its
estimates), ``hybrid`` (:class:`~prismstereo.learned.HybridStereo`, the default: the learned first stage, learned
stages, the exact last stage and its confidence head) and ``hybrid-learned`` (the same without the last two,
``last_stage='learned'``); the default hybrids with the shipped weights or ``--hybrid-weights FILE``. Per capture
and chain: ``valid`` (co-visible pixels the chain calls valid, and
the share of them off by more than 1 %), ``dense`` (every co-visible pixel it gives a depth, same), mean relative error
of the valid ones, ``@3 %``: the largest share of co-visible pixels a threshold on the confidence keeps with
<= 3 % of them off by more than 1 %, and ``hidden``: the valid pixels whose point the other half cannot see (occluded
or outside the common field of view; right or invalid is the aim) and the share of them off by more than 1 %. Then
each chain's reliability per confidence band (:data:`BANDS`), the photographs and the other captures pooled over the
sensors: the band's share of the co-visible pixels with a depth,
their share off by more than 1 %, and 1 - their mean confidence (what a calibrated confidence predicts for that
share). Then per sensor the speed: each chain's exported graph in onnxruntime (2 intra-op threads) and StereoSGBM
(``cv2.setNumThreads(2)``) on that sensor's plane in interleaved rounds (``benchmarks/_timing.py``; the learned graph
in 3 rounds of its own with StereoSGBM, since among the others it slows every graph timed after it), median ms and
the paired ratio; and the peak resident memory of a fresh process building the hybrid at 1024 x 768 and during one
torch forward (``/proc/self/status`` VmHWM). ``--plot FILE`` draws the frontier at 1024 x 768: time / SGBM against
the photographs' mean ``@3 %`` share, one point per chain.

Run: .venv/bin/python benchmarks/default_chain.py [--rounds 7] [--plot docs/frontier.png] [--chains a,b,...]
     [--sensors 512,1024,1920] [--hybrid-weights FILE] [--accuracy-only]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import interleaved_ms, paired_ratio  # noqa: E402
from dense_depth import best_coverage, captures  # noqa: E402
from onnx_speed import opencv_halves, pixel_sweep  # noqa: E402
from video_speed import disparities  # noqa: E402

from prismstereo import BiPrismRig, PrismStereo, thesis_setup1, thesis_setup2  # noqa: E402
from prismstereo.export import OnnxDepth, export_onnx  # noqa: E402
from prismstereo.learned import HybridStereo, LearnedStereo  # noqa: E402
from prismstereo.learned.hybrid import HYBRID_BLOCK_WEIGHTS  # noqa: E402
from prismstereo.synthetic import ImageFormation, disparity_scene, fronto_parallel_plane, render  # noqa: E402
from prismstereo.threads import set_torch_threads  # noqa: E402

Z_RANGE = (228.0, 1374.0)
CHAINS = ("accurate", "dense", "learned", "block", "hybrid-block", "hybrid", "hybrid-learned")
DEFAULT_CHAINS = ("accurate", "dense", "block", "hybrid-block", "hybrid", "hybrid-learned")  # not learned: slow
SLOW = ("learned",)  # timed in rounds of their own (see main)
PHOTOS = ("Tsukuba 450-900 mm", "Venus 450-900 mm", "Motorcycle 450-900 mm")
BANDS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.85, 0.95, 1.0)  # confidence bands of the reliability table (the last closed)
MEMORY = """
import sys, torch
from pathlib import Path
from prismstereo import thesis_setup1
from prismstereo.learned import HybridStereo
from prismstereo.threads import set_torch_threads

def peak():  # this process's own high-water mark (ru_maxrss would include the parent's at the fork)
    line = next(x for x in Path("/proc/self/status").read_text().splitlines() if x.startswith("VmHWM"))
    return int(line.split()[1]) / 1024

set_torch_threads(2)
model = HybridStereo(thesis_setup1(), (228.0, 1374.0), weights=sys.argv[1] if len(sys.argv) > 1 else "default").eval()
built = peak()
Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current resident size
with torch.inference_mode():
    model(torch.rand(1, 1, 768, 1024))
print(built, peak())
"""

def other_rig() -> BiPrismRig:
    """The held-out rig of another sensor: 1920 x 1080, 3.45 um pixels, a 16 mm lens, a 9 degree N-BK7 prism 8 mm
    thick with its apex 150 mm away (no training rig has any of these)."""
    return thesis_setup1().replace(alpha_deg=9.0, refractive_index=1.517, focal_length_mm=16.0,
                                   prism_thickness_mm=8.0, apex_distance_mm=150.0, pixel_size_mm=0.00345,
                                   image_width=1920, image_height=1080, principal_point=(959.5, 539.5))


SENSORS = {"512": lambda: thesis_setup1().downscaled(2), "1024": thesis_setup1, "1920": other_rig}
"""The sensors by their width: the rig of each (``--sensors``)."""


def more_captures(rig: BiPrismRig, cache: Path) -> dict[str, tuple[BiPrismRig, dict]]:
    """Motorcycle and a plane at 525 mm through ``rig`` (at 1024 x 768 also through thesis setup 2; rendered once into
    ``cache``): name -> (rig, capture)."""
    import skimage.data

    base = dict(supersample=2, noise_sigma=2 / 255, fresnel=True, seed=7)

    def motorcycle():
        left, _, disparity = skimage.data.stereo_motorcycle()
        picture = torch.from_numpy(left.astype(np.float32).mean(-1) / 255.0)
        return disparity_scene(picture, torch.from_numpy(disparity.astype(np.float32)), 450.0, 900.0,
                               name="motorcycle")

    if rig == thesis_setup1():  # the names (and cached files) of the 1024 x 768 captures
        s2 = thesis_setup2()
        specs = {"Motorcycle 450-900 mm": (rig, motorcycle), "plane 525 mm setup 1": (
            rig, lambda: fronto_parallel_plane(rig, 525.0, seed=11)), "plane 525 mm setup 2": (
            s2, lambda: fronto_parallel_plane(s2, 525.0, seed=12))}
        files = {name: name.replace(" ", "_") for name in specs}
    else:
        specs = {"Motorcycle 450-900 mm": (rig, motorcycle), "plane 525 mm": (
            rig, lambda: fronto_parallel_plane(rig, 525.0, seed=11))}
        files = {name: f"{rig.image_width}_{name.replace(' ', '_')}" for name in specs}
    out = {}
    cache.mkdir(parents=True, exist_ok=True)
    for name, (capture_rig, scene) in specs.items():
        path = cache / f"{files[name]}.pt"
        if not path.exists():
            torch.save(render(capture_rig, scene(), ImageFormation(**base))._asdict(), path)
        out[name] = (capture_rig, torch.load(path))
    return out


def build(chain: str, rig, hybrid_weights: str) -> torch.nn.Module:
    """The chain's model of ``rig`` over :data:`Z_RANGE`."""
    if chain == "accurate":
        return PrismStereo(rig, Z_RANGE).eval()
    if chain == "dense":
        return PrismStereo(rig, Z_RANGE, "dense").eval()
    if chain == "learned":
        return LearnedStereo(rig, Z_RANGE).eval()
    if chain == "hybrid-block":
        return HybridStereo(rig, Z_RANGE, weights=HYBRID_BLOCK_WEIGHTS).eval()
    hybrid = HybridStereo(rig, Z_RANGE, weights=hybrid_weights,
                          last_stage="learned" if chain in ("block", "hybrid-learned") else "exact").eval()
    return hybrid.classical if chain == "block" else hybrid


def score(res, rel: torch.Tensor, covisible: torch.Tensor) -> dict[str, float]:
    """valid / dense coverage and bad shares, mean error, and the @3 % share (module docstring), from the result and
    its relative error ``rel``."""
    total = int(covisible.sum())
    out = {}
    for key, has in (("valid", res.valid), ("dense", res.confidence > 0)):
        sel = has & covisible & torch.isfinite(rel)
        out[key] = 100 * int(sel.sum()) / total
        out[f"{key} bad"] = 100 * float((rel[sel] > 0.01).double().mean()) if sel.any() else float("nan")
    sel = res.valid & covisible
    out["mean"] = 100 * float(rel[sel].mean()) if sel.any() else float("nan")
    sel = (res.confidence > 0) & covisible & torch.isfinite(rel)
    out["@3"] = best_coverage(res.confidence[sel], rel[sel] <= 0.01, total, bad=0.03)[0]
    hidden = res.valid & ~covisible & torch.isfinite(rel)  # valid where the other half cannot see the point
    out["hidden"] = int(hidden.sum())
    out["hidden bad"] = 100 * float((rel[hidden] > 0.01).double().mean()) if hidden.any() else float("nan")
    return out


def band_counts(confidence: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
    """(len(BANDS) - 1, 3) per confidence band: pixels, pixels off by > 1 %, sum of confidence; from (N,) tensors."""
    band = (torch.bucketize(confidence.double(), torch.tensor(BANDS[1:-1], dtype=torch.float64), right=True))
    out = torch.zeros(len(BANDS) - 1, 3, dtype=torch.float64)
    out[:, 0].index_add_(0, band, torch.ones_like(confidence, dtype=torch.float64))
    out[:, 1].index_add_(0, band, (~right).double())
    out[:, 2].index_add_(0, band, confidence.double())
    return out


def print_reliability(counts: dict[tuple[str, str], torch.Tensor]) -> None:
    """The reliability table of every (chain, group) in ``counts`` (:func:`band_counts` summed)."""
    print("\nreliability per confidence band, co-visible pixels with a depth: share % / bad>1 % / 1 - mean conf %")
    names = [f"{lo:g}-{hi:g}" for lo, hi in zip(BANDS[:-1], BANDS[1:], strict=True)]
    print(f"{'chain':9s} {'captures':11s} " + " ".join(f"{n:>19s}" for n in names))
    for (chain, group), c in counts.items():
        cells = []
        for n, bad, conf in c.tolist():
            share = 100 * n / float(c[:, 0].sum())
            cells.append(f"{share:5.1f} / {100 * bad / n:5.1f} / {100 - 100 * conf / n:5.1f}" if n else f"{'-':>19s}")
        print(f"{chain:9s} {group:11s} " + " ".join(f"{x:>19s}" for x in cells))


def accuracy(rig: BiPrismRig, caps: dict[str, tuple[BiPrismRig, dict]], chains: list[str], args: argparse.Namespace,
             models: dict, counts: dict) -> dict[str, list[float]]:
    """Print every chain's scores on ``rig``'s captures ``caps`` (name -> (rig, capture)); add to the reliability
    ``counts``; return each chain's @3 % shares of the photographs."""
    photo_share: dict[str, list[float]] = {c: [] for c in chains}
    print(f"\n{rig.image_width} x {rig.image_height}:")
    print(f"{'capture':26s} {'chain':14s} {'valid %':>8s} {'bad %':>6s} {'dense %':>8s} {'bad %':>6s} "
          f"{'mean %':>7s} {'@3 %':>6s} {'hidden px':>9s} {'bad %':>6s}")
    for name, (capture_rig, cap) in caps.items():
        w = capture_rig.reference_width
        gt, covisible = cap["depth"][..., :w].double(), cap["covisible"][..., :w]
        for chain in chains:
            key = (chain, capture_rig)
            if key not in models:
                models[key] = build(chain, capture_rig, args.hybrid_weights)
            with torch.inference_mode():
                res = models[key](cap["image"][:, :1].float())
            rel = (res.depth.double() - gt).abs() / gt
            r = score(res, rel, covisible)
            sel = (res.confidence > 0) & covisible & torch.isfinite(rel)
            group = (chain, "photographs" if name in PHOTOS else "others")
            counts[group] = counts.get(group, 0) + band_counts(res.confidence[sel], rel[sel] <= 0.01)
            if name in PHOTOS:
                photo_share[chain].append(r["@3"])
            print(f"{name:26s} {chain:14s} {r['valid']:8.1f} {r['valid bad']:6.2f} {r['dense']:8.1f} "
                  f"{r['dense bad']:6.2f} {r['mean']:7.3f} {r['@3']:6.1f} {r['hidden']:9d} {r['hidden bad']:6.1f}")
    return photo_share


def speed(rig: BiPrismRig, plane: dict, chains: list[str], args: argparse.Namespace, models: dict,
          photo_share: dict[str, list[float]]) -> dict[str, float]:
    """Time each chain's exported graph and StereoSGBM on ``rig``'s capture ``plane`` in interleaved rounds; print and
    return the paired ratios."""
    image = plane["image"][:, :1].float()
    left, right = opencv_halves(image, rig.reference_width, False)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=disparities(pixel_sweep(rig, Z_RANGE)), blockSize=5)
    ratios: dict[str, float] = {}
    times: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as folder:
        graphs = {c: OnnxDepth(export_onnx(models[(c, rig)], Path(folder) / f"{c}.onnx")) for c in chains}
        # the learned graph (seconds a run) in rounds of its own: among the others it slowed every graph timed after
        # it (the accurate chain 78 -> 142 ms)
        for group in ([c for c in chains if c not in SLOW], [c for c in chains if c in SLOW]):
            if not group:
                continue
            runs = {"StereoSGBM": lambda: sgbm.compute(left, right)}
            runs.update({c: (lambda g: lambda: g(image.numpy()))(graphs[c]) for c in group})
            measured = interleaved_ms(runs, rounds=args.rounds if group[0] not in SLOW else 3)
            ratios.update({c: paired_ratio(measured[c], measured["StereoSGBM"]) for c in measured})
            times.setdefault("StereoSGBM", measured["StereoSGBM"])
            times.update({c: measured[c] for c in group})
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), "unknown CPU")
    print(f"\n{rig.image_width} x {rig.image_height}: exported graphs, onnxruntime 2 threads, {args.rounds} "
          f"interleaved rounds on {cpu}")
    print(f"{'run':14s} {'median ms':>9s} {'x SGBM':>7s} {'photos @3 %':>12s}")
    for run, values in times.items():
        share = f"{statistics.mean(photo_share[run]):12.1f}" if photo_share.get(run) else ""
        print(f"{run:14s} {statistics.median(values):9.1f} {ratios[run]:7.2f} {share}")
    return ratios


def plot(path: Path, chains: list[str], ratios: dict[str, float], photo_share: dict[str, list[float]]) -> None:
    """The frontier at 1024 x 768: time / SGBM against the photographs' mean @3 % share, one point per chain."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for chain, marker in zip(chains, "osD^vP*X", strict=False):
        if photo_share[chain]:  # a legend, not labels: the hybrids lie close together
            ax.scatter([ratios[chain]], [statistics.mean(photo_share[chain])], marker=marker, label=chain)
    ax.axvline(0.6, color="grey", linestyle=":", label="speed target 0.6x SGBM")
    ax.axhline(95.0, color="grey", linestyle="--", label="accuracy target 95 %")
    ax.set_xscale("log")
    ax.set_xlabel("exported graph time / StereoSGBM at 1024 x 768 (same run, log scale)")
    ax.set_ylabel("photographs: share kept at <= 3 % bad (%)")
    ax.legend(loc="lower left", bbox_to_anchor=(0.22, 0.0), fontsize=7, ncol=2)  # clear of the points
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=7, help="interleaved timing rounds")
    parser.add_argument("--cache", type=Path, default=Path(".cache/dense_depth"))
    parser.add_argument("--hybrid-weights", default="default", help="the hybrids' weights file")
    parser.add_argument("--chains", default=",".join(DEFAULT_CHAINS),
                        help="comma-separated subset of " + ",".join(CHAINS) + " (default: all but learned)")
    parser.add_argument("--sensors", default=",".join(SENSORS), help="comma-separated subset of " + ",".join(SENSORS))
    parser.add_argument("--plot", type=Path, default=None, help="write the frontier plot (1024 x 768) here")
    parser.add_argument("--accuracy-only", action="store_true", help="no timing and no memory measurement")
    args = parser.parse_args()
    chains = [c for c in args.chains.split(",") if c]
    sensors = [s for s in args.sensors.split(",") if s]
    for given, known, what in ((chains, CHAINS, "chains"), (sensors, tuple(SENSORS), "sensors")):
        if set(given) - set(known):
            raise SystemExit(f"unknown {what} {sorted(set(given) - set(known))}; choose from {', '.join(known)}")
    set_torch_threads(2)
    cv2.setNumThreads(2)
    print(f"searched {Z_RANGE[0]:g}-{Z_RANGE[1]:g} mm; valid / dense: % of co-visible pixels and % of those off by "
          "> 1 %; @3 %: the most a confidence threshold keeps at <= 3 % off")
    counts: dict[tuple[str, str], torch.Tensor] = {}
    shares, ratios = {}, {}
    for sensor in sensors:
        rig = SENSORS[sensor]()
        models: dict[tuple[str, BiPrismRig], torch.nn.Module] = {}
        caps = {name: (rig, cap) for name, cap in captures(rig, args.cache).items()}
        caps.update(more_captures(rig, args.cache))
        shares[sensor] = accuracy(rig, caps, chains, args, models, counts)
        if not args.accuracy_only:
            plane = caps["plane 525 mm setup 1" if rig == thesis_setup1() else "plane 525 mm"][1]
            ratios[sensor] = speed(rig, plane, chains, args, models, shares[sensor])
    print_reliability(dict(sorted(counts.items())))
    if args.accuracy_only:
        return
    if any(c.startswith("hybrid") for c in chains):
        extra = [] if args.hybrid_weights == "default" else [args.hybrid_weights]
        run = subprocess.run([sys.executable, "-c", MEMORY, *extra], capture_output=True, text=True, check=True)
        built, forward = (float(x) for x in run.stdout.split())
        print(f"\nhybrid at 1024 x 768, peak resident memory of a fresh process: {built:.0f} MB building the model, "
              f"{forward:.0f} MB during one torch forward")
    if args.plot is not None and "1024" in ratios:
        plot(args.plot, chains, ratios["1024"], shares["1024"])
    print(json.dumps({"ratios": {s: {k: round(v, 3) for k, v in r.items()} for s, r in ratios.items()}}))


if __name__ == "__main__":
    main()
