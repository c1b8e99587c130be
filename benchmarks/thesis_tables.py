"""The thesis' calibration comparison (Tables 4.3 / 4.4) regenerated on exact synthetic captures.

For thesis setups 1 and 2 (512 x 384 by default, ``--scale 1`` for the full 1024 x 768 sensor):

1. ``--views`` (12, the thesis' number, sec. 3.3.1) checkerboards (5 x 8 squares of 6 mm, 4 x 7 inner corners)
   rendered through the true rig at seeded tilted poses (``calibration_views``: 550-850 mm for setup 1, 300-500
   mm for setup 2, where the board fits both halves' common view; 8-bit, noise 1/255), found in both halves
   (``detect_board``), with each corner's true real-frame position (``baselines.targets``).
2. Calibrations, one column each: the thesis' geometric two-point virtual cameras (``virtual_camera``'s default
   pixels of the full sensor, see :func:`two_point`) and our all-pixel least-squares ones (``virtual_cameras``),
   both of the true rig, as distortion-free pinholes; Zhang (``calibrate_zhang``: per-half
   ``calibrateCamera`` then ``stereoCalibrate``, registered to the real frame by the boards' known corners); Tsai
   (``calibrate_tsai``: the same boards at their known poses as one 3-D target); the exact optics of the true rig;
   the exact optics of the rig calibrated from the same board images (``calibrate_board``, started from the true
   rig as the nominal one; ``--no-board-fit`` skips it).
3. Fronto-parallel textured planes at the thesis' ten depths 228-1374 mm (2 x 2 supersampling, noise 1/255),
   matched by ``PrismStereo`` of the true rig (205-1511 mm searched). The same matched pairs (reference pixel,
   right-half pixel) are triangulated with every column's calibration by the mid-point theorem, as the thesis did,
   so the table isolates calibration and geometry from matching. Per plane, ``--points`` (50, the thesis' group
   size) valid, co-visible pixels drawn (seeded) from a box around the centre of the co-visible region. "depth" is
   the mean over the group, "err %" = |mean - actual| / actual (the thesis' definition: 221 vs 228 mm is 3.07 %).
   ``--truth-matches`` uses the renderer's exact correspondences (``Capture.match_uv``) instead of the matcher's.
4. The conventional pipeline end to end on the same captures: Zhang -> ``cv2.stereoRectify`` -> ``StereoSGBM``
   -> ``cv2.reprojectImageTo3D``, against ``PrismStereo`` (dense, over every co-visible reference pixel). The
   halves are crops of different widths and Zhang's matrices are in full-sensor pixels, so each virtual camera's
   image is the full sensor with the other half set to black (no crop: K applies unchanged); both are remapped to
   the rectified pair (``initUndistortRectifyMap``, the sensor's size) and padded on the left by minDisparity +
   numDisparities black columns (SGBM gives the left image's first that many columns no disparity; the disparity
   map is cropped back), SGBM searches the disparities of 205-1511 mm, and each co-visible reference pixel takes
   the 3-D point of its rectified position (``undistortPoints`` with R1, P1; nearest pixel), moved to the real
   frame. "depth" there is the median over
   the valid pixels, "|err| %" the mean relative error, "cover %" the share of co-visible pixels with a depth.

Printed per setup: the recovered depth and its error per group and calibration column with their average (the
thesis' own averages on real captures beside them), the matched pairs' distance from the exact correspondences,
and the conventional pipeline against PrismStereo per group. The current tables: ``docs/benchmarks.md``, *The
thesis' tables* (``benchmarks/report.py --only thesis_tables``). ``--seed N`` draws other board sets (the Zhang and
Tsai columns move with them, the geometric and all-pixel ones only with the sampled pixels), ``--native-two-point``
puts the thesis' two pixels twice as far from the apex (the two-point camera depends on them), ``--truth-matches``
isolates calibration from matching.

What the columns show, and why. The thesis' ordering (geometric better than Zhang) need not hold on exact
captures: it depends on the setup and the resolution. The geometric camera is exact in its inputs (the rig) but is
a pinhole through the rays of two pixels next to the apex line, and the prism's rays share no centre: its error is
fixed by the geometry and the two pixels, the same at every resolution. Zhang's error is calibration noise, which
shrinks with the corner precision, in a narrow half field of view where the principal point trades against the
rotation and the centre's distance against the focal length, plus a fitted model whose distortion polynomial
absorbs part of the prism's anamorphic distortion where the boards were: its error is smallest at the
calibration distances and grows away from them, as the thesis' errors grow with depth (its Zhang boards stood at
2 m). A least-squares pinhole fitted to every pixel without distortion terms (all-pixel) sits in between. So the
thesis' 3.65 against 10.24 % on setup 1's real captures came from its data (a board at 2 m, real corners, bench
misalignment, matching), not from a limit of Zhang's model; the only calibration below every pinhole on every
setup and resolution is the exact model (down to the matcher's error). Tsai's known 3-D target is exact here, so
on setup 1 it is a good pinhole, unlike on the thesis' bench; on setup 2 its fit extrapolates like Zhang's.
``calibrate_board`` starts at the true rig and moves it by what 12 noisy views support. (Setup 2's rig is the
thesis' prism with a consistent thickness, T = 20 mm instead of its 5.6 mm, ``thesis_setup2``: its thesis numbers
compare less directly.)

Rendering dominates the run; ``--threads`` (default 1) sets torch's intra-op threads: two threads on two cores
that another process also uses oversubscribe them and slow the renders down many times. ``--scale 1`` renders
and matches on the full sensor.

Run: .venv/bin/python benchmarks/thesis_tables.py [--setups 1 2] [--scale 1] [--views 12] [--seed 0]
[--points 50] [--truth-matches] [--native-two-point] [--zhang-stereo refine|fix_intrinsic] [--no-board-fit]
[--no-sgbm] [--threads 1]
"""

from __future__ import annotations

import argparse
import math
import time

import cv2
import numpy as np
import torch

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.baselines import (
    PinholePair,
    ZhangResult,
    calibrate_tsai,
    calibrate_zhang,
    checkerboard_corners,
    pinhole_from_virtual,
    reference_points,
    triangulate_exact,
    triangulate_pinholes,
)
from prismstereo.calibration import calibrate_board, detect_board, parse_target
from prismstereo.classical.model import PrismStereo
from prismstereo.geometry import virtual_camera, virtual_cameras
from prismstereo.synthetic import ImageFormation, calibration_views, fronto_parallel_plane, render
from prismstereo.threads import set_torch_threads

THESIS_DEPTHS = (228.0, 312.0, 353.0, 418.0, 525.0, 625.0, 780.0, 936.0, 1192.0, 1374.0)
# the thesis' recovered-depth errors (%), geometric / Zhang / Tsai: Table 4.3 (setup 1) and 4.4 (setup 2)
THESIS_AVG = {1: (3.65, 10.24, 8.48), 2: (1.98, 8.29, 7.63)}
Z_RANGE = (205.0, 1511.0)
SETUPS = {1: thesis_setup1, 2: thesis_setup2}
BOARD_DEPTHS = {1: (550.0, 850.0), 2: (300.0, 500.0)}
BOARD = "checkerboard:4x7:6"
F64 = torch.float64


def two_point(rig, half: str, scale: int):
    """The thesis' two-point virtual camera with ``virtual_camera``'s full-sensor default pixels (50 and 100 px from
    the apex column, 50 px above and below the centre row) at their place on a ``scale`` times coarser sensor, so
    every ``--scale`` builds the same camera (the defaults are counted in the sensor's own pixels)."""
    sign = -1.0 if half == "left" else 1.0
    ac, cy = rig.apex_column, rig.cy
    a, b = 50.0 / scale, 100.0 / scale
    pixels = torch.tensor([[ac + sign * a, cy - a], [ac + sign * b, cy + a]], dtype=F64)
    return virtual_camera(rig, half, "two_point", pixels=pixels)


def calibrations(rig, setup: int, args) -> tuple[dict, ZhangResult, str]:
    """Every column's triangulation function, Zhang's result (for the SGBM pipeline) and a summary line."""
    board = parse_target(BOARD)
    scenes = calibration_views(args.views, args.seed, BOARD_DEPTHS[setup])
    caps = render(rig, scenes, ImageFormation(supersample=3, noise_sigma=1 / 255, seed=args.seed))
    dets = [detect_board(image, rig, board) for image in caps.image]
    found = sum(d.left is not None and d.right is not None for d in dets)
    refs = [reference_points(rig, checkerboard_corners(s), d, board) if (d.left or d.right) else None
            for s, d in zip(scenes, dets, strict=True)]
    size = (rig.image_width, rig.image_height)
    zhang = calibrate_zhang(dets, board, size, stereo=args.zhang_stereo, reference_points=refs)
    tsai = calibrate_tsai(dets, refs, size)
    scale = 1 if args.native_two_point else args.scale
    pairs = {"geometric": PinholePair(*(pinhole_from_virtual(two_point(rig, half, scale))
                                        for half in ("left", "right")))}
    pair = virtual_cameras(rig, "least_squares")
    pairs["all-pixel"] = PinholePair(pinhole_from_virtual(pair.left), pinhole_from_virtual(pair.right))
    pairs["Zhang"], pairs["Tsai"] = zhang.cameras, tsai.cameras
    columns = {name: (lambda ul, ur, p=p: triangulate_pinholes(p, ul, ur)) for name, p in pairs.items()}
    columns["exact"] = lambda ul, ur: triangulate_exact(rig, ul, ur)
    note = (f"boards found in both halves: {found} / {len(dets)}; Zhang RMS {zhang.rms_px[0]:.3f} / "
            f"{zhang.rms_px[1]:.3f} / stereo {zhang.rms_px[2]:.3f} px, registration {zhang.registration_rms_mm:.3f} "
            f"mm; Tsai RMS {tsai.rms_px[0]:.3f} / {tsai.rms_px[1]:.3f} px")
    if not args.no_board_fit:
        t0 = time.perf_counter()
        fit = calibrate_board(rig, dets, board)
        columns["exact cal."] = lambda ul, ur, r=fit.rig: triangulate_exact(r, ul, ur)
        note += f"; calibrate_board RMS {fit.rms_px:.3f} px ({time.perf_counter() - t0:.0f} s)"
    centres = "; ".join(f"{n} C_L = ({', '.join(f'{float(c):.2f}' for c in p.left.centre)})" for n, p in pairs.items())
    return columns, zhang, note + "\n  " + centres


def sample(cap, res, width: int, n: int, seed: int, truth: bool):
    """``n`` valid co-visible reference pixels around the co-visible region's centre, their right-half pixels and
    how far the matcher's are from the exact correspondences (px)."""
    ok = (res.valid[0, 0] & cap.covisible[0, 0, :, :width]).nonzero()  # (M, 2) rows, cols
    cov = cap.covisible[0, 0, :, :width].nonzero().to(F64)
    centre, extent = cov.median(0).values, (cov.max(0).values - cov.min(0).values)
    near = ((ok.to(F64) - centre).abs() <= extent / 4).all(dim=1)
    pool = ok[near] if int(near.sum()) >= n else ok
    g = torch.Generator().manual_seed(seed)
    pick = pool[torch.randperm(pool.shape[0], generator=g)[:n]]
    v, u = pick[:, 0], pick[:, 1]
    uv_left = torch.stack([u, v], dim=1).to(F64)
    match = cap.match_uv if truth else res.match.to(F64)
    uv_right = match[0, :, v, u].T.contiguous()
    match_err = (res.match.to(F64)[0, :, v, u] - cap.match_uv[0, :, v, u]).norm(dim=0)
    return uv_left, uv_right, match_err


class Sgbm:
    """Zhang's cameras -> stereoRectify -> StereoSGBM -> reprojectImageTo3D, for one rig (module docstring)."""

    def __init__(self, rig, zhang: ZhangResult) -> None:
        left, right = zhang.cameras
        size = (rig.image_width, rig.image_height)
        k1, d1, k2, d2 = (x.numpy() for x in (left.matrix, left.distortion, right.matrix, right.distortion))
        r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(k1, d1, k2, d2, size, zhang.rotation.numpy(),
                                                    zhang.translation.numpy().reshape(3, 1),
                                                    flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
        self.maps = [cv2.initUndistortRectifyMap(k, d, r, p, size, cv2.CV_32FC1)
                     for k, d, r, p in ((k1, d1, r1, p1), (k2, d2, r2, p2))]
        self.k1, self.d1, self.r1, self.p1, self.q = k1, d1, r1, p1, q
        # rectified left frame -> real frame: X_real = R_L R1^T X_rect + C_L
        self.to_real = (left.rotation.numpy() @ r1.T, left.centre.numpy())
        f, baseline = p1[0, 0], 1.0 / abs(q[3, 2])
        d_lo, d_hi = f * baseline / Z_RANGE[1], f * baseline / Z_RANGE[0]
        self.min_disp = int(math.floor(d_lo)) - 2
        num = int(math.ceil((d_hi - self.min_disp + 2) / 16.0)) * 16
        block = 5
        self.sgbm = cv2.StereoSGBM_create(minDisparity=self.min_disp, numDisparities=num, blockSize=block,
                                          P1=8 * block * block, P2=32 * block * block, disp12MaxDiff=1,
                                          uniquenessRatio=10, speckleWindowSize=100, speckleRange=2)
        self.split = rig.reference_width
        # SGBM leaves the left image's first minDisparity + numDisparities columns without a disparity: pad both
        # rectified images on the left by that much (and crop the disparity back) so every pixel can be matched
        self.pad = self.min_disp + num

    def depth(self, image: torch.Tensor, uv: np.ndarray) -> tuple[np.ndarray, float]:
        """Real-frame Z (NaN where SGBM gave none) of reference pixels ``uv`` (N, 2); and the run time (ms)."""
        gray = (image[0].numpy() * 255.0).round().astype(np.uint8)
        left, right = gray.copy(), gray.copy()
        left[:, self.split:] = 0
        right[:, : self.split] = 0
        t0 = time.perf_counter()
        rect = [cv2.copyMakeBorder(cv2.remap(img, mx, my, cv2.INTER_LINEAR), 0, 0, self.pad, 0, cv2.BORDER_CONSTANT)
                for img, (mx, my) in zip((left, right), self.maps, strict=True)]
        disp = self.sgbm.compute(rect[0], rect[1])[:, self.pad:].astype(np.float32) / 16.0
        xyz = cv2.reprojectImageTo3D(disp, self.q)
        ms = (time.perf_counter() - t0) * 1e3
        at = cv2.undistortPoints(uv.reshape(-1, 1, 2).astype(np.float64), self.k1, self.d1, R=self.r1, P=self.p1)
        col, row = np.round(at.reshape(-1, 2)).astype(int).T
        h, w = disp.shape
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        z = np.full(len(uv), np.nan)
        ok = inside.copy()
        ok[inside] = disp[row[inside], col[inside]] > self.min_disp - 0.5
        rot, centre = self.to_real
        pts = xyz[row[ok], col[ok]].astype(np.float64) @ rot.T + centre
        z[ok] = pts[:, 2]
        return z, ms


def run_setup(setup: int, args) -> dict:
    base = SETUPS[setup]()
    rig = base.downscaled(args.scale) if args.scale > 1 else base
    t0 = time.perf_counter()
    columns, zhang, note = calibrations(rig, setup, args)
    t_cal = time.perf_counter() - t0
    planes = [fronto_parallel_plane(rig, z, seed=100 + i) for i, z in enumerate(THESIS_DEPTHS)]
    caps = render(rig, planes, ImageFormation(supersample=2, noise_sigma=1 / 255, seed=args.seed))
    model = PrismStereo(rig, Z_RANGE)
    sgbm = None if args.no_sgbm else Sgbm(rig, zhang)
    width = rig.reference_width
    rows, dense = [], []
    for i, z in enumerate(THESIS_DEPTHS):
        cap = type(caps)(*(t[i : i + 1] for t in caps))
        t1 = time.perf_counter()
        with torch.inference_mode():
            res = model(cap.image)
        ms_ours = (time.perf_counter() - t1) * 1e3
        ul, ur, merr = sample(cap, res, width, args.points, args.seed + i, args.truth_matches)
        depths = {}
        for name, fn in columns.items():
            tri = fn(ul, ur)
            depths[name] = float(tri.depth[tri.valid].mean()) if bool(tri.valid.any()) else float("nan")
        rows.append((z, depths, float(merr.median())))
        if sgbm is not None:
            cov = cap.covisible[0, 0, :, :width]
            vv, uu = cov.nonzero().unbind(1)
            gt = cap.depth[0, 0, vv, uu].numpy()
            ours_ok = res.valid[0, 0, vv, uu].numpy()
            ours = res.depth[0, 0, vv, uu].double().numpy()
            z_sgbm, ms_sgbm = sgbm.depth(cap.image[0], torch.stack([uu, vv], 1).double().numpy())
            dense.append((z, _dense(ours, ours_ok, gt), _dense(z_sgbm, np.isfinite(z_sgbm), gt), ms_ours, ms_sgbm))
    return {"rig": rig, "rows": rows, "dense": dense, "note": note, "t_cal": t_cal}


def _dense(z: np.ndarray, ok: np.ndarray, gt: np.ndarray) -> tuple[float, float, float]:
    if not ok.any():
        return float("nan"), float("nan"), 0.0
    return float(np.median(z[ok])), 100 * float(np.mean(np.abs(z[ok] - gt[ok]) / gt[ok])), 100 * float(ok.mean())


def print_setup(setup: int, out: dict, args) -> None:
    rig, rows = out["rig"], out["rows"]
    names = list(rows[0][1])
    src = "exact correspondences (match_uv)" if args.truth_matches else "PrismStereo's matches (true rig)"
    print(f"\nTable 4.{2 + setup} regenerated: setup {setup}, {rig.image_width} x {rig.image_height} px, "
          f"{args.points} points per group, {src}")
    print(f"  {out['note']}")
    head = " ".join(f"{n[:10]:>10}" for n in names)
    print(f"{'grp':>3} {'actual':>7} | recovered depth (mm): {head} | error (%): {head}")
    sums = dict.fromkeys(names, 0.0)
    for g, (z, depths, _) in enumerate(rows, 1):
        errs = {n: 100 * abs(d - z) / z for n, d in depths.items()}
        for n in names:
            sums[n] += errs[n]
        print(f"{g:>3} {z:>7.0f} | {'':>21} {' '.join(f'{depths[n]:>10.2f}' for n in names)} | {'':>10} "
              f"{' '.join(f'{errs[n]:>10.3f}' for n in names)}")
    avg = " ".join(f"{sums[n] / len(rows):>10.3f}" for n in names)
    print(f"{'Avg':>3} {'':>7} | {'':>21} {' ' * 11 * len(names)}| {'':>10} {avg}")
    geo, zh, ts = THESIS_AVG[setup]
    used = "the exact ones; the matcher's are" if args.truth_matches else "the matcher's,"
    print(f"  thesis' averages (real captures): geometric {geo} %, Zhang {zh} %, Tsai {ts} %; matches used: {used} "
          f"{max(r[2] for r in rows):.3f} px (median per group, worst group) from the exact correspondences")
    if out["dense"]:
        print(f"\nConventional pipeline vs PrismStereo, setup {setup} (dense, co-visible reference pixels)")
        print(f"{'grp':>3} {'actual':>7} | {'PrismStereo: depth':>18} {'|err| %':>8} {'cover %':>8} {'ms':>6} | "
              f"{'Zhang+SGBM: depth':>17} {'|err| %':>8} {'cover %':>8} {'ms':>6}")
        for g, (z, ours, conv, ms_o, ms_s) in enumerate(out["dense"], 1):
            print(f"{g:>3} {z:>7.0f} | {ours[0]:>18.2f} {ours[1]:>8.3f} {ours[2]:>8.1f} {ms_o:>6.0f} | "
                  f"{conv[0]:>17.2f} {conv[1]:>8.3f} {conv[2]:>8.1f} {ms_s:>6.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--setups", type=int, nargs="+", default=[1, 2], choices=(1, 2))
    parser.add_argument("--scale", type=int, default=2, help="sensor downscaling (1 = 1024 x 768)")
    parser.add_argument("--views", type=int, default=12)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--points", type=int, default=50)
    parser.add_argument("--truth-matches", action="store_true")
    parser.add_argument("--zhang-stereo", default="refine", choices=("refine", "fix_intrinsic"))
    parser.add_argument("--native-two-point", action="store_true",
                        help="two-point pixels 50 / 100 px of the run's own sensor from the apex (not the full one's)")
    parser.add_argument("--no-board-fit", action="store_true")
    parser.add_argument("--no-sgbm", action="store_true")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (0: torch's default)")
    args = parser.parse_args()
    if args.threads:
        set_torch_threads(args.threads)
    t0 = time.perf_counter()
    for setup in args.setups:
        out = run_setup(setup, args)
        print_setup(setup, out, args)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
