"""Speed of the depth model in torch and onnxruntime against OpenCV's StereoSGBM / StereoBM on this machine,
with the accuracy each reaches on a rendered capture; batching, peak memory and an onnxruntime profile.

Everything runs on 2 threads (``set_torch_threads(2)``, ``cv2.setNumThreads(2)``, onnxruntime 2 intra-op
and 1 inter-op thread, all graph optimisations) with ``thesis_setup1`` at 1024 x 768 (``--scale K`` divides the
sensor by K for quick runs). Times: ``--repeats`` interleaved rounds after one warm-up call each
(``benchmarks/_timing.py``: every method once per round, in reversed order every other round, 0.1 s apart), the
median and fastest per method; the "x SGBM" column is the median over rounds of the method's time divided by
SGBM's time in the same round. (A shared host drifts between speed phases within minutes, and not equally for
every method: 2-thread onnxruntime and torch may slow down while single-threaded SGBM does not, so ratios of
medians timed block by block would compare different phases.)
Each table says how many cores other processes used meanwhile (/proc/stat minus this process): on a shared 2-core
machine torch's 2-thread eager mode slows down several-fold (and erratically) as soon as another process is busy,
onnxruntime and OpenCV much less, so only trust runs where that is ~0.

1. **Wide range** 228-1374 mm (the thesis working range): ``PrismStereo(rig, (228, 1374))`` (defaults: at
   1024 x 768 the pyramid, a 2 x 2-binned coarse-to-fine model with coarse factor 4 placing a full-resolution
   band of 5 hypotheses; printed) on one capture of ``slanted_plane(rig, 525, 30)`` (a noise-textured plane
   through 525 mm slanted 30 degrees about y; Z 514-536 mm over the co-visible pixels), 2 x 2 supersampling,
   read noise 1/255, 8 bits. Rows: torch eager (``inference_mode``); onnxruntime
   (:class:`~prismstereo.export.OnnxDepth`, graph exported once per run into a temporary directory); OpenCV
   ``StereoSGBM`` (minDisparity 0, numDisparities 368 / K rounded up to a multiple of 16, blockSize 5, all else
   default, i.e. P1 = P2 = 0, uniquenessRatio 0, no speckle filter, MODE_SGBM) and ``StereoBM`` (same
   numDisparities, blockSize 5, defaults). OpenCV's time is ``compute`` on the two pre-split 8-bit halves only
   (left = columns < split, right = the rest, zero-padded on the right to one width if they differ); splitting
   and its depth conversion are not timed. Columns: ms per frame (median, fastest), the same-round ratio to SGBM,
   the mean (and median) relative depth error % over the valid co-visible reference pixels, and the coverage,
   % of co-visible reference pixels that are valid, as in ``benchmarks/depth_targets.py``.
   ``--sampling`` adds torch and onnxruntime rows for the same model with the exact-sweep coarse level
   (``sampling='sweep'``; the default is the rectified shift volume). Both ranges also time the pyramid with
   ``full_band=1, band_edges='clamp'`` (the fast full-resolution setting: a band of 3, each pixel refined around its
   centre, at most half a step beyond it, instead of rejected when the best of the three is on an edge), the model
   with ``downsample=1`` (the full-resolution coarse level, coarse factor 4; an earlier default) and with
   ``downsample=2, full_band=0`` (matching on the 2 x 2-binned capture, each pixel its block's depth: the speed knob,
   half the lateral resolution; the narrow range also with coarse factor 4 on the binned image, where the default
   picks 2) and, for context, StereoSGBM on the same binned halves (numDisparities halved, depth converted with the
   binned rig's exact sweep and given to each pixel of the block as the model does); SGBM on the full-resolution
   halves stays the reference of the "x SGBM" column. Both ranges also time the ``'dense'`` preset (its error and
   coverage columns score its ``valid`` mask).
2. **Narrow range** 600-1450 mm: the same with ``PrismStereo(rig, (600, 1450))`` (its default coarse factor,
   printed; ``--narrow-coarse-factor F`` forces one, for the binned model of the pyramid and ``downsample=1``),
   numDisparities 96 / K and ``slanted_plane(rig, 900, 30)`` (Z 878-923 mm). (A single full-resolution level is
   not timed: it is far slower in torch and its unrolled ONNX graph takes minutes to export.) Both ranges print
   the correspondence over the range from the exact sweep: how far the match moves along u between z_min and
   z_max, the OpenCV disparity interval that means, the largest vertical offset of the match from the pixel's
   row, and the ground-truth disparities of the capture.
3. **Batching**: torch eager images/s at batch 8 (and 2) vs batch 1, wide model, the sizes timed alternately,
   with the CPU time split into user and system and the minor page faults per call (fresh large temporaries
   are page-faulted in on every call; that is system time). The ratio is printed from the medians and from the
   fastest runs: on a shared VM a single image's time swings between host phases, and the ratio with it.
4. **Peak RSS** of a fresh process (``subprocess`` + ``sys.executable``) that loads the exported wide graph
   with ``OnnxDepth`` and runs one frame, and of one that builds the torch model and runs one frame in eager
   mode: the high-water mark VmHWM of /proc/self/status after the imports, after loading / building, after
   the frame, and for a second frame after resetting the mark (``/proc/self/clear_refs``). ``ru_maxrss`` is
   printed too but is useless here: Linux carries the parent's peak across fork + exec into the child's.
5. **onnxruntime profile** of one frame of the wide graph (a second session with ``enable_profiling``, same
   threads and optimisation level; the frame after a warm-up run): the trace's Node events (kernel times) of
   that run summed per op type, top 8 with total ms, share of the frame, bytes moved (every input + output
   tensor from the recorded shapes and element types: 4 bytes per float, 1 per bool, 8 per int64) and GB/s.

OpenCV on bi-prism halves:
    The halves are **not rectified**: a reference pixel's match lies up to ~1.6 px above or below its row
    (printed per range), while OpenCV searches along the row only. OpenCV's convention: left pixel x matches
    right pixel x - d, d >= 0. The sign is read from the capture's ground truth (``match_uv``): with this rig a
    reference pixel at column x (of the left half) matches the right half at its own column x - d, d > 0 for
    near points, d ~ 0 at ~1.4 m (per pixel between 1374 and 1450 mm) and slightly negative beyond, so the
    halves are used as they are. (Had it been the other way, both halves would be mirrored horizontally, which
    restores the convention and keeps the reference half as OpenCV's left image; mirrored and swapped would
    undo it again.) OpenCV's disparity is converted to depth with the exact per-pixel correspondence curve, the
    most favourable conversion: the match's full-sensor column is ``split + x - d``; for every reference pixel
    the match column u(s) is tabulated at 128 sweep coordinates s in [-1, 1] (linear in 1/Z over the model's
    range) from the exact per-pixel sweep polynomials (``fit_sweep`` + ``sweep_coefficients`` of
    :mod:`prismstereo.epipolar.sweep`, ~1e-10 px), the monotonic u(s) is inverted by linear interpolation
    (clamped to [-1, 1], as the model clamps s), and s -> Z is exact (s is linear in 1/Z). On the ground-truth
    match columns this conversion reproduces the ground-truth depth (printed as a check). Pixels where OpenCV
    has no disparity (its invalid value, d < minDisparity) are invalid. OpenCV computes no disparity for the
    leftmost minDisparity + numDisparities columns of its left image, so with 368 disparities only the right
    144 of the 512 reference columns can be valid: that, not matching quality, bounds its wide-range coverage.

Run (from the repository root; the default run takes a few minutes on a quiet 2-core machine, most of it the
two full-resolution ONNX exports):
    .venv/bin/python benchmarks/onnx_speed.py [--scale 1] [--repeats 9] [--narrow-coarse-factor F] [--sampling]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import onnxruntime as ort
import torch
from _timing import interleaved_ms, paired_ratio  # benchmarks/_timing.py (scripts run from this folder)

from prismstereo import thesis_setup1
from prismstereo.classical.model import PrismStereo
from prismstereo.epipolar.sweep import chebyshev_basis, fit_sweep, sweep_coefficients, sweep_to_depth
from prismstereo.export import OnnxDepth, export_onnx
from prismstereo.geometry import trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.synthetic import ImageFormation, render, slanted_plane
from prismstereo.threads import set_torch_threads

F64 = torch.float64
FORMATION = ImageFormation(supersample=2, noise_sigma=1 / 255, bits=8)
SWEEP_SAMPLES = 128  # tabulated sweep coordinates per reference pixel for OpenCV's depth conversion
BYTES = {"float": 4, "bool": 1, "int64": 8, "int32": 4, "double": 8, "float16": 2, "uint8": 1, "int8": 1}


class Case(NamedTuple):
    name: str
    z_range: tuple[float, float]
    disparities: int  # OpenCV numDisparities at full resolution
    depth_mm: float  # slanted plane through this depth
    slant_deg: float


WIDE = Case("wide", (228.0, 1374.0), 368, 525.0, 30.0)
NARROW = Case("narrow", (600.0, 1450.0), 96, 900.0, 30.0)


class Row(NamedTuple):
    name: str
    ms: float  # median
    best: float  # fastest run
    ratio: float  # median of the same-round ratios to SGBM's time
    error: float  # mean relative depth error, %
    median: float  # median relative depth error, %
    coverage: float  # % of co-visible reference pixels that are valid


class OtherLoad:
    """CPU used by other processes while a block runs: busy time of /proc/stat minus this process's (and its
    children's) CPU time, in cores (0 on a quiet machine; the timings are inflated when it is not)."""

    def __enter__(self) -> OtherLoad:
        self.start = self._sample()
        return self

    def __exit__(self, *exc: object) -> None:
        end = self._sample()
        self.cores = max(0.0, ((end[0] - self.start[0]) - (end[1] - self.start[1])) / (end[2] - self.start[2]))

    @staticmethod
    def _sample() -> tuple[float, float, float]:
        try:
            with open("/proc/stat") as fh:
                f = [int(x) for x in fh.readline().split()[1:]]
            busy = (f[0] + f[1] + f[2] + f[5] + f[6] + f[7]) / os.sysconf("SC_CLK_TCK")  # without idle, iowait
        except (OSError, ValueError, IndexError):
            busy = float("nan")
        t = os.times()
        return busy, t.user + t.system + t.children_user + t.children_system, time.perf_counter()

    def __str__(self) -> str:
        return f"other processes used {self.cores:.1f} of {os.cpu_count()} cores meanwhile"


# ----------------------------------------------------------------------------------------------- accuracy
def score(depth: torch.Tensor, valid: torch.Tensor, capture, split: int) -> tuple[float, float, float]:
    """(mean, median relative depth error %, coverage %) over the co-visible reference pixels, as
    ``benchmarks/depth_targets.py``."""
    gt, cov = capture.depth[..., :split], capture.covisible[..., :split]
    ok = valid.view_as(cov) & cov
    rel = ((depth.double().view_as(gt) - gt).abs() / gt)[ok]
    if not rel.numel():
        return float("nan"), float("nan"), 0.0
    return 100 * float(rel.mean()), 100 * float(rel.median()), 100 * float(ok.sum() / cov.sum().clamp_min(1))


class PixelSweep(NamedTuple):
    """The exact sweep of every reference pixel over a depth range (public API, independent of the model)."""

    coefficients: torch.Tensor  # (N, H, W_ref, 2) float64: match (u, v) in full-sensor px, Chebyshev in s
    z_range: tuple[float, float]
    inside: torch.Tensor  # (H, W_ref) bool: reference pixels whose ray passes the prism (field of view)


def pixel_sweep(rig: BiPrismRig, z_range: tuple[float, float]) -> PixelSweep:
    fit = fit_sweep(rig, z_range)
    uv = torch.stack(torch.meshgrid(torch.arange(rig.reference_width, dtype=F64),
                                    torch.arange(rig.image_height, dtype=F64), indexing="xy"), -1)  # (H, W, 2)
    rays = trace_pixels(rig, uv.view(-1, 2))
    inside = (rays.valid & rays.left).view(uv.shape[:2])
    return PixelSweep(sweep_coefficients(fit, uv).permute(2, 0, 1, 3).contiguous(), z_range, inside)


def match_column_to_depth(sweep: PixelSweep, u_match: torch.Tensor) -> torch.Tensor:
    """Depth (H, W_ref) of reference pixels whose match in the other half is at full-sensor column
    ``u_match`` (H, W_ref), by inverting each pixel's exact u(s) (tabulated, linear interpolation)."""
    coef = sweep.coefficients[..., 0]  # (N, H, W_ref): u of the match, Chebyshev in s
    n, h, w = coef.shape
    s = torch.linspace(-1.0, 1.0, SWEEP_SAMPLES, dtype=F64)
    basis = chebyshev_basis(s, n)  # (S, N)
    out = torch.empty(h, w, dtype=F64)
    rows = max(1, 32768 // w)
    for r0 in range(0, h, rows):
        table = (basis @ coef[:, r0:r0 + rows].reshape(n, -1)).T.contiguous()  # (P, S)
        target = u_match[r0:r0 + rows].reshape(-1).to(F64)
        falling = table[:, :1] > table[:, -1:]  # u(s) falls with s here (nearer = larger disparity)
        table = torch.where(falling, -table, table)
        target = torch.where(falling[:, 0], -target, target)
        k = torch.searchsorted(table, target[:, None]).clamp(1, SWEEP_SAMPLES - 1)
        t0, t1 = table.gather(1, k - 1)[:, 0], table.gather(1, k)[:, 0]
        frac = ((target - t0) / (t1 - t0)).clamp(0.0, 1.0)
        s_hat = s[k[:, 0] - 1] + frac * (s[1] - s[0])
        out[r0:r0 + rows] = s_hat.view(-1, w)
    return sweep_to_depth(out, torch.tensor(sweep.z_range, dtype=F64))


# ----------------------------------------------------------------------------------------------- OpenCV
def opencv_halves(image: torch.Tensor, split: int, mirror: bool) -> tuple[np.ndarray, np.ndarray]:
    """The two 8-bit halves of (1, 1, H, W), padded on the right to one width, mirrored if asked."""
    img = np.clip(np.rint(image[0, 0].numpy() * 255.0), 0, 255).astype(np.uint8)
    left, right = img[:, :split], img[:, split:]
    width = max(left.shape[1], right.shape[1])
    left, right = (np.pad(x, ((0, 0), (0, width - x.shape[1]))) for x in (left, right))
    if mirror:
        left, right = left[:, ::-1], right[:, ::-1]
    return np.ascontiguousarray(left), np.ascontiguousarray(right)


def opencv_depth(sweep: PixelSweep, disparity: np.ndarray, mirror: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """OpenCV's fixed-point disparity (H, W_pad) of the halves -> (depth, valid) of the reference pixels."""
    split = sweep.inside.shape[1]
    d = disparity.astype(np.float64) / 16.0
    if mirror:  # column x' = W_pad - 1 - x; the match is at x + d in the original right half
        d = d[:, ::-1]
    d = torch.from_numpy(np.ascontiguousarray(d[:, :split]))
    valid = d >= 0.0  # minDisparity 0: OpenCV writes (minDisparity - 1) * 16 where it has no disparity
    u = torch.arange(split, dtype=F64)
    u_match = split + u + d if mirror else split + u - d
    return match_column_to_depth(sweep, u_match), valid


def upsampled(t: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """(H / 2, W / 2) values of 2 x 2 blocks -> (height, width), each pixel its block's (as the model's
    ``downsample``), zero beyond."""
    t = t.repeat_interleave(2, 0).repeat_interleave(2, 1)[:height, :width]
    return torch.nn.functional.pad(t, (0, width - t.shape[1], 0, height - t.shape[0]))


def disparity_count(full: int, scale: int) -> int:
    return 16 * math.ceil(full / scale / 16)


# ----------------------------------------------------------------------------------------------- reports
def spread_report(sweep: PixelSweep, capture) -> tuple[str, bool]:
    """Lines on the correspondence over the range and in the capture; whether to mirror the halves for OpenCV."""
    coef, mask = sweep.coefficients, sweep.inside  # (N, H, W_ref, 2), (H, W_ref)
    n, h, w, _ = coef.shape
    split = w
    ends = (chebyshev_basis(torch.tensor([-1.0, 1.0], dtype=F64), n) @ coef.reshape(n, -1)).view(2, h, w, 2)
    u = torch.arange(w, dtype=F64)
    d_near, d_far = (u - (ends[i, ..., 0] - split) for i in (0, 1))  # OpenCV disparity x_left - x_right
    spread = (ends[0, ..., 0] - ends[1, ..., 0]).abs()[mask]
    sub = coef[:, ::4, ::4]
    pos = (chebyshev_basis(torch.linspace(-1, 1, 33, dtype=F64), n) @ sub.reshape(n, -1)).view(33, *sub.shape[1:])
    v_off = (pos[..., 1] - torch.arange(0, h, 4, dtype=F64)[:, None]).abs()[:, mask[::4, ::4]].max()
    z0, z1 = sweep.z_range
    cov = capture.covisible[0, 0, :, :split]
    u_gt = capture.match_uv[0, 0, :, :split]
    d_gt = (u - (u_gt - split))[cov]
    mirror = bool(d_gt.median() < 0)
    lines = [
        f"correspondence over {z0:g}-{z1:g} mm (exact sweep, reference pixels in the field of view): the match "
        f"moves {float(spread.min()):.1f}-{float(spread.max()):.1f} px along u; OpenCV disparity x_L - x_R "
        f"{float(d_far[mask].min()):.1f}..{float(d_far[mask].max()):.1f} px at {z1:g} mm, "
        f"{float(d_near[mask].min()):.1f}..{float(d_near[mask].max()):.1f} px at {z0:g} mm; "
        f"|v offset| of the match up to {float(v_off):.2f} px (halves not rectified)",
        f"capture (ground truth, {int(cov.sum())} co-visible reference pixels, Z "
        f"{float(capture.depth[0, 0, :, :split][cov].min()):.0f}-{float(capture.depth[0, 0, :, :split][cov].max()):.0f}"
        f" mm): disparity x_L - x_R {float(d_gt.min()):.1f}..{float(d_gt.max()):.1f} px -> "
        + ("negative: halves mirrored for OpenCV" if mirror else "OpenCV's sign already: halves used as they are"),
    ]
    return "\n".join(lines), mirror


def table(title: str, rows: list[Row]) -> str:
    out = [title, f"{'method':50s} {'ms/frame':>9s} {'(min)':>9s} {'x SGBM':>7s} {'err %':>7s} {'(median)':>8s} "
                  f"{'cover %':>8s}"]
    out += [f"{r.name:50s} {r.ms:9.1f} {r.best:9.1f} {r.ratio:7.2f} {r.error:7.3f} {r.median:8.3f} "
            f"{r.coverage:8.1f}" for r in rows]
    return "\n".join(out)


def machine_line() -> str:
    cpu = platform.processor() or "?"
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    return (f"machine: {os.cpu_count()} cores ({usable} usable), {cpu}; load average {load}; python "
            f"{platform.python_version()}, torch {torch.__version__} ({torch.get_num_threads()} threads), "
            f"onnxruntime {ort.__version__}, opencv {cv2.__version__} ({cv2.getNumThreads()} threads), "
            f"numpy {np.__version__}")


# ----------------------------------------------------------------------------------------------- parts
def run_case(case: Case, rig: BiPrismRig, scale: int, repeats: int, coarse_factor: int | None, tmp: Path,
             sweep_too: bool = False):
    """Parts 1 / 2: the table of one range (with ``sweep_too`` also the model with the exact-sweep coarse
    level, in torch and onnxruntime). Returns (model, onnx path, capture)."""
    t0 = time.perf_counter()
    capture = render(rig, slanted_plane(rig, case.depth_mm, case.slant_deg), FORMATION)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = PrismStereo(rig, case.z_range, dict(coarse_factor=coarse_factor)).eval()
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    path = export_onnx(model, tmp / f"{case.name}.onnx")
    t_export = time.perf_counter() - t0
    runner = OnnxDepth(path, threads=2)
    split = model.rig.reference_width
    print(f"\n== {case.name} range {case.z_range[0]:g}-{case.z_range[1]:g} mm: thesis_setup1 "
          f"{rig.image_width}x{rig.image_height}, split {split}, default model: {model.summary()}; "
          f"scene slanted_plane({case.depth_mm:g} mm, {case.slant_deg:g} deg)")
    print(f"render {t_render:.1f} s, model build {t_build:.1f} s, ONNX export {t_export:.1f} s "
          f"({path.stat().st_size / 1e6:.0f} MB), onnxruntime session load {runner.load_seconds:.1f} s")
    sweep = pixel_sweep(rig, case.z_range)
    report, mirror = spread_report(sweep, capture)
    print(report)
    cov = capture.covisible[0, 0, :, :split]
    gt_depth = match_column_to_depth(sweep, capture.match_uv[0, 0, :, :split].nan_to_num(split))
    check = ((gt_depth - capture.depth[0, 0, :, :split]).abs() / capture.depth[0, 0, :, :split])[cov]
    print(f"depth conversion check (ground-truth match column -> depth): max relative error "
          f"{100 * float(check.max()):.1e} %")

    image = capture.image
    variants = [("torch eager (default)", "onnxruntime (default, 2 threads)", model, runner)]
    if sweep_too:  # the same model with the other coarse sampling (default: rectified), built and exported first
        sweep_model = PrismStereo(rig, case.z_range, dict(coarse_factor=coarse_factor, sampling="sweep")).eval()
        sweep_runner = OnnxDepth(export_onnx(sweep_model, tmp / f"{case.name}_sweep.onnx"), threads=2)
        variants.append(("torch eager, sweep coarse level", "onnxruntime, sweep coarse level", sweep_model,
                         sweep_runner))
    others = []
    if model.binned is not None:  # the fast full-resolution setting: a thinner band, its edge pixels kept
        fast = PrismStereo(rig, case.z_range, dict(coarse_factor=coarse_factor, downsample=model.downsample,
                                                   full_band=1, band_edges="clamp"))
        others.append(("full_band 1, band edges clamped", fast))
    # the 'dense' preset (a depth on every co-visible pixel; its coarse level by the guided filter): what it costs
    others.append(("'dense' preset", PrismStereo(rig, case.z_range, "dense")))
    if model.downsample != 1:  # the full-resolution coarse level (the default on smaller sensors)
        others.append(("downsample 1", PrismStereo(rig, case.z_range, dict(downsample=1, coarse_factor=coarse_factor))))
    # the speed knob: matching on the 2 x 2-binned capture, each pixel its block's depth (its default coarse factor,
    # and for the narrow range, whose binned search gets f = 2 by default, also f = 4)
    for factor in (None, 4) if case.name == "narrow" else (None,):
        blocks = PrismStereo(rig, case.z_range, dict(downsample=2, full_band=0, coarse_factor=factor))
        others.append((f"downsample 2 blocks (f = {blocks.final.factor})", blocks))
    for i, (label, other_model) in enumerate(others):
        other_runner = OnnxDepth(export_onnx(other_model.eval(), tmp / f"{case.name}_{i}.onnx"), threads=2)
        variants.append((f"torch eager, {label}", f"onnxruntime, {label}", other_model, other_runner))
    left, right = opencv_halves(image, split, mirror)
    nd = disparity_count(case.disparities, scale)
    sgbm_name = f"OpenCV StereoSGBM ({nd} disp, block 5)"
    matchers = {sgbm_name: cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd, blockSize=5),
                f"OpenCV StereoBM ({nd} disp, block 5)": cv2.StereoBM_create(numDisparities=nd, blockSize=5)}
    # SGBM on the same 2 x 2-binned capture as the downsample-2 model (context: not the reference row)
    binned_rig = rig.binned(2)
    split_b = binned_rig.reference_width
    left_b, right_b = opencv_halves(torch.nn.functional.avg_pool2d(image, 2), split_b, mirror)
    nd_b = disparity_count(case.disparities, 2 * scale)
    sgbm_b_name = f"OpenCV StereoSGBM, 2x2-binned ({nd_b} disp)"
    sgbm_b = cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd_b, blockSize=5)

    def eager(m: PrismStereo):
        with torch.inference_mode():
            return m(image)

    # every method's timed call and, run once afterwards, its (depth, valid) of the reference half
    methods, results = {}, {}
    for torch_name, ort_name, torch_model, ort_runner in variants:
        methods[torch_name] = lambda m=torch_model: eager(m)
        methods[ort_name] = lambda r=ort_runner: r(image)
        results[torch_name] = lambda m=torch_model: eager(m)[:2]
        results[ort_name] = lambda r=ort_runner: r(image)[:2]
    for name, matcher in matchers.items():
        methods[name] = lambda matcher=matcher: matcher.compute(left, right)
        results[name] = lambda matcher=matcher: opencv_depth(sweep, matcher.compute(left, right), mirror)

    def binned_sgbm() -> tuple[torch.Tensor, torch.Tensor]:
        depth_b, valid_b = opencv_depth(pixel_sweep(binned_rig, case.z_range), sgbm_b.compute(left_b, right_b), mirror)
        depth_b, valid_b = (upsampled(t, split, rig.image_height) for t in (depth_b, valid_b.double()))
        return depth_b, valid_b > 0.5

    methods[sgbm_b_name] = lambda: sgbm_b.compute(left_b, right_b)
    results[sgbm_b_name] = binned_sgbm
    with OtherLoad() as other:
        times = interleaved_ms(methods, rounds=repeats)
    rows = [Row(name, statistics.median(t), min(t), paired_ratio(t, times[sgbm_name]),
                *score(*results[name](), capture, split)) for name, t in times.items()]
    print(table(f"-- {case.name} range: median (and fastest) of {repeats} interleaved rounds (every method once per "
                f"round, 0.1 s apart) after a warm-up, x SGBM = median of the same-round ratios; {other}", rows))
    return model, path, capture


def batching(model: PrismStereo, image: torch.Tensor, repeats: int, sizes: tuple[int, ...] = (1, 2, 8)) -> None:
    """Part 3: torch images/s at batch 8 (and 2) vs batch 1, timed alternately; with the CPU time split into user
    and system (page faults of fresh large temporaries show up as system time) and the minor page faults."""
    batches = {b: image.expand(b, -1, -1, -1).contiguous() for b in sizes}
    times: dict[int, list[tuple[float, float, float, int]]] = {b: [] for b in sizes}
    with torch.inference_mode(), OtherLoad() as other:
        for x in batches.values():
            model(x)
        for _ in range(repeats):
            for b, x in batches.items():
                c0, f0, t0 = os.times(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt, time.perf_counter()
                model(x)
                t1, c1, f1 = time.perf_counter(), os.times(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                times[b].append((t1 - t0, c1.user - c0.user, c1.system - c0.system, f1 - f0))
    print(f"\n== batching (torch eager, wide model, median of {repeats} alternating runs; {other})")
    ips = {}
    for b in sizes:
        wall, user, system, faults = (statistics.median(v) for v in zip(*times[b], strict=True))
        ips[b] = b / wall
        print(f"batch {b}: {1e3 * wall:9.1f} ms/batch {ips[b]:6.2f} images/s {ips[b] / ips[sizes[0]]:5.2f}x  (CPU "
              f"user {user:.2f} s, system {system:.2f} s, {faults / 1e3:.0f} k minor page faults per batch)")
    fastest = {b: b / min(t[0] for t in times[b]) for b in sizes}  # noise only ever slows a run down
    print(f"batch 8 / batch 1 throughput: {ips[8] / ips[1]:.2f}x from the medians, {fastest[8] / fastest[1]:.2f}x "
          f"from the fastest runs (target >= 1.3x)")


RSS_HELPERS = """
import json, resource, sys

def hwm():  # peak RSS of this process image (VmHWM, MB); ru_maxrss also carries the parent's peak across exec
    return next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM:")) / 1024

def rss():
    return next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmRSS:")) / 1024

def reset():  # restart the high-water mark at the current RSS (Linux >= 4.0); None if not allowed
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return rss()
    except OSError:
        return None

def two_frames(out, frame):  # after loading: one frame, reset the mark, a second frame; prints the marks
    out["loaded"] = hwm()
    frame()
    out["peak"] = hwm()
    out["reset"] = reset()
    frame()
    out["frame"] = hwm()
    out["ru_maxrss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(out))
"""

ORT_RSS = RSS_HELPERS + """
import numpy as np
from prismstereo.export import OnnxDepth
out = {"imports": hwm()}
image = np.load(sys.argv[2])
runner = OnnxDepth(sys.argv[1], threads=2)
two_frames(out, lambda: runner(image))
"""

TORCH_RSS = RSS_HELPERS + """
import numpy as np
import torch
from prismstereo import thesis_setup1
from prismstereo.classical.model import PrismStereo
from prismstereo.threads import set_torch_threads
out = {"imports": hwm()}
set_torch_threads(2)
image = torch.from_numpy(np.load(sys.argv[2]))
config = json.loads(sys.argv[1])
model = PrismStereo(thesis_setup1().downscaled(config["scale"]), tuple(config["z_range"])).eval()
with torch.inference_mode():
    two_frames(out, lambda: model(image))
"""


def peak_rss(path: Path, image: torch.Tensor, scale: int, tmp: Path) -> None:
    """Part 4: peak RSS of one frame in fresh processes (onnxruntime, torch eager)."""
    frame = tmp / "frame.npy"
    np.save(frame, image.numpy())
    config = json.dumps({"scale": scale, "z_range": list(WIDE.z_range)})
    parent = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print("\n== peak RSS of a fresh process running one frame (wide model; VmHWM of /proc/self/status, MB)")
    maxrss = []
    for name, code, arg, loading in (("onnxruntime", ORT_RSS, str(path), "loading the .onnx"),
                                     ("torch eager", TORCH_RSS, config, "building the model")):
        proc = subprocess.run([sys.executable, "-c", code, arg, str(frame)], capture_output=True, text=True)
        if proc.returncode != 0:
            print(f"{name}: failed: {proc.stderr.strip().splitlines()[-1:]}")
            continue
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        maxrss.append(f"{r['ru_maxrss']:.0f}")
        target = " (target <= 1536 MB)" if name == "onnxruntime" else ""
        second = (f"; a second frame, high-water mark reset: RSS {r['reset']:.0f} -> peak {r['frame']:.0f}"
                  if r["reset"] is not None else "")
        peak = max(r["peak"], r["frame"])
        print(f"{name:12s} peak {peak:6.0f}{target}: {r['imports']:.0f} after the imports, {r['loaded']:.0f} after "
              f"{loading}, {r['peak']:.0f} after one frame{second}")
    print(f"(their ru_maxrss, {' and '.join(maxrss)} MB, is no use here: Linux carries the parent's peak, "
          f"{parent:.0f} MB, across fork + exec)")


def _tensor_bytes(shapes: list[dict[str, list[int]]]) -> int:
    total = 0
    for entry in shapes:
        for dtype, dims in entry.items():
            total += BYTES.get(dtype, 4) * math.prod(dims)
    return total


def profile(path: Path, image: torch.Tensor, tmp: Path, top: int = 8) -> None:
    """Part 5: onnxruntime profile of one frame: time, bytes and GB/s per op type."""
    opts = ort.SessionOptions()
    opts.enable_profiling = True
    opts.profile_file_prefix = str(tmp / "ort_profile")
    opts.intra_op_num_threads, opts.inter_op_num_threads = 2, 1
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3
    session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    feed = {"image": image.numpy()}
    session.run(None, feed)  # warm-up (arena growth); the second run is the one analysed
    session.run(None, feed)
    with open(session.end_profiling()) as fh:
        events = json.load(fh)
    run = [e for e in events if e.get("cat") == "Session" and e.get("name") == "model_run"][-1]
    start, end = run["ts"], run["ts"] + run["dur"]
    per_op: dict[str, list[float]] = {}
    nodes = 0
    for e in events:
        if e.get("cat") != "Node" or not e.get("name", "").endswith("_kernel_time") or not start <= e["ts"] <= end:
            continue
        args = e.get("args", {})
        moved = _tensor_bytes(args.get("input_type_shape", [])) + _tensor_bytes(args.get("output_type_shape", []))
        acc = per_op.setdefault(args.get("op_name", "?"), [0, 0.0, 0])
        acc[0] += 1
        acc[1] += e["dur"]
        acc[2] += moved
        nodes += 1
    frame_us = run["dur"]
    kernels_us = sum(v[1] for v in per_op.values())
    print(f"\n== onnxruntime profile of one frame (wide graph, 2 intra-op threads, ORT_ENABLE_ALL): frame "
          f"{frame_us / 1e3:.1f} ms, {nodes} kernel runs of {len(per_op)} op types, {kernels_us / 1e3:.1f} ms in "
          f"kernels")
    print(f"{'op type':22s} {'calls':>6s} {'total ms':>9s} {'share %':>8s} {'MB moved':>9s} {'GB/s':>7s}")
    for op, (calls, us, moved) in sorted(per_op.items(), key=lambda kv: -kv[1][1])[:top]:
        gbs = moved / (us * 1e-6) / 1e9 if us > 0 else float("nan")
        print(f"{op:22s} {calls:6d} {us / 1e3:9.1f} {100 * us / frame_us:8.1f} {moved / 1e6:9.1f} {gbs:7.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=int, default=1, help="sensor downscale factor (1 = 1024 x 768)")
    parser.add_argument("--repeats", type=int, default=9,
                        help="interleaved timing rounds (every method once per round; median), >= 5 recommended")
    parser.add_argument("--sampling", action="store_true",
                        help="wide range: also the model with the exact-sweep coarse level (torch and onnxruntime)")
    parser.add_argument("--narrow-coarse-factor", type=int, default=0,
                        help="coarse_factor of the narrow-range model (0 = the model's default)")
    args = parser.parse_args()
    set_torch_threads(2)
    cv2.setNumThreads(2)
    t_start = time.perf_counter()
    print(machine_line())
    rig = thesis_setup1().downscaled(args.scale)
    with tempfile.TemporaryDirectory(prefix="onnx_speed_") as tmp_name:
        tmp = Path(tmp_name)
        model, path, capture = run_case(WIDE, rig, args.scale, args.repeats, None, tmp, args.sampling)
        run_case(NARROW, rig, args.scale, args.repeats, args.narrow_coarse_factor or None, tmp)
        batching(model, capture.image, args.repeats)
        peak_rss(path, capture.image, args.scale, tmp)
        profile(path, capture.image, tmp)
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s; load average now {load}")


if __name__ == "__main__":
    main()
