"""The ``prismstereo`` command line. It only parses arguments, calls the library and prints.

Subcommands (this release): ``rig show``, ``rig preset``, ``render``, ``fov``, ``design``, ``match``, ``depth``,
``export``, ``demo``; ``--version``. The ``depth`` subcommand lives in :mod:`prismstereo.cli_depth`.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from prismstereo import __version__
from prismstereo.cli_calibrate import add_calibrate_parser
from prismstereo.cli_depth import add_depth_parser, add_export_parser
from prismstereo.errors import PrismStereoError
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.presets import RIG_PRESETS, load_rig
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import VirtualCamera, virtual_cameras


def _format_rig(rig: BiPrismRig) -> str:
    lines = ["Rig"]
    for key, value in rig.to_dict().items():
        lines.append(f"  {key:<20} {value}")
    lines.append(f"  {'(apex column)':<20} {rig.apex_column:.3f} px")
    lines.append(f"  {'(prism width)':<20} {rig.prism_width_mm:.3f} mm")
    return "\n".join(lines)


def _format_camera(vc: VirtualCamera, pixel_size: float) -> str:
    c = vc.centre.tolist()
    k = vc.camera
    return "\n".join(
        [
            f"  {vc.half} virtual camera ({vc.method.replace('_', '-')})",
            f"    centre C (mm)           [{c[0]:+.4f}, {c[1]:+.4f}, {c[2]:+.4f}]",
            f"    beta (rad)              {float(vc.beta):+.5f}",
            f"    focal length (mm)       {float(vc.focal_length_mm):.4f}"
            f"  (fx {float(k.fx[0]) * pixel_size:.4f}, fy {float(k.fy[0]) * pixel_size:.4f})",
            f"    principal point (px)    ({float(k.cx[0]):.3f}, {float(k.cy[0]):.3f})",
            f"    non-centrality (mm)     max {float(vc.noncentrality_max_mm):.4f},"
            f" rms {float(vc.noncentrality_rms_mm):.4f}",
            f"    pinhole error (px)      mean {float(vc.reprojection_error_mean_px):.3f},"
            f" max {float(vc.reprojection_error_max_px):.3f}  (250-1500 mm)",
        ]
    )


def _show(rig: BiPrismRig) -> str:
    parts = [_format_rig(rig), "Virtual cameras (thesis ch. 3; camera frame x right, y down, z forward)"]
    for method in ("two_point", "least_squares"):
        pair = virtual_cameras(rig, method)
        parts += [_format_camera(vc, rig.pixel_size_mm) for vc in pair]
    return "\n".join(parts)


def _cmd_rig_show(args: argparse.Namespace) -> int:
    print(_show(load_rig(args.rig)))
    return 0


def _cmd_rig_preset(args: argparse.Namespace) -> int:
    rig = RIG_PRESETS[args.name]()
    text = rig.to_json(args.out)
    if args.out is None:
        print(text, end="")
    else:
        print(f"wrote {args.out}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    rig = load_rig(args.rig)
    print(_show(rig))
    # Exactness check of the optics on the default rig: trace pixels, then project them back.
    gen = torch.Generator().manual_seed(0)
    uv = torch.rand(4096, 2, generator=gen, dtype=torch.float64)
    uv = uv * torch.tensor([rig.image_width - 1.0, rig.image_height - 1.0], dtype=torch.float64)
    rays = trace_pixels(rig, uv)
    print("Exact optics round trip (4096 random pixels, trace -> point at depth -> project_points)")
    for depth in (250.0, 525.0, 1374.0, 5000.0):
        pts = points_at_depth(rays, depth)
        worst = 0.0
        for half, mask in (("left", rays.left & rays.valid), ("right", ~rays.left & rays.valid)):
            proj = project_points(rig, pts[mask], half)
            worst = max(worst, float((proj.uv - uv[mask]).norm(dim=-1).max()))
        print(f"  depth {depth:6.0f} mm: max error {worst:.2e} px")
    if args.scale > 0:
        _demo_depth(rig, args.scale, Path(args.out))
    return 0


def _demo_depth(rig: BiPrismRig, scale: int, out: Path) -> None:
    """Render a step scene, run the hybrid and the classical depth model, print their errors, write the depth of
    the sensor's default (:func:`~prismstereo.defaults.default_model`), its preview, the capture and its point
    cloud."""
    import numpy as np

    from prismstereo.defaults import default_model
    from prismstereo.depth.points import depth_to_points, write_ply
    from prismstereo.io import write_image
    from prismstereo.learned import HybridStereo
    from prismstereo.model import PrismStereo
    from prismstereo.preview import write_depth_preview
    from prismstereo.synthetic import ImageFormation, render, step_scene

    small = rig.downscaled(scale)
    near, far = 450.0, 650.0
    print(f"Depth from one capture (step scene {near:g}/{far:g} mm, sensor {small.image_width}x{small.image_height}"
          f" = 1/{scale} resolution, noise 1/255)")
    cap = render(small, step_scene(small, near, far), ImageFormation(supersample=2, noise_sigma=1 / 255))
    w = small.reference_width
    gt, cov = cap.depth[..., :w], cap.covisible[..., :w]
    results = {}
    default = default_model(small)
    z_range = (400.0, 700.0)
    for name, model in (("hybrid", HybridStereo(small, z_range)), ("classical", PrismStereo(small, z_range))):
        with torch.inference_mode():
            res = results[name] = model.eval()(cap.image)
        ok = res.valid & cov
        rel = ((res.depth - gt).abs() / gt)[ok]
        line = model.summary() if name == "hybrid" else f"classical: {model.summary()}"  # the hybrid's names itself
        print(f"  {line}{' (the default on this sensor)' if name == default else ''}")
        print(f"    {ok.float().sum() / cov.float().sum():.1%} of co-visible pixels valid; relative depth error mean "
              f"{rel.mean():.3%}, median {rel.median():.3%}")
    res = results[default]
    out.mkdir(parents=True, exist_ok=True)
    depth = torch.where(res.valid, res.depth, torch.full_like(res.depth, float("nan")))
    np.save(out / "depth.npy", depth[0, 0].numpy().astype(np.float32))
    write_image(out / "capture.png", cap.image[0])
    write_depth_preview(out / "depth_preview.png", depth[0, 0])
    points = depth_to_points(small, depth.double(), res.valid)
    count = write_ply(out / "points.ply", points[0], res.valid[0, 0], colors=cap.image[0, :, :, :w])
    print(f"  wrote the default's {out}/depth.npy (mm, NaN invalid), depth_preview.png, capture.png, points.ply "
          f"({count} points)")


SCENES = ("plane", "slanted", "step", "sphere", "checkerboard", "circlegrid", "middlebury")


def _make_scene(args: argparse.Namespace, rig: BiPrismRig, depth: float, seed: int):
    from prismstereo import synthetic as syn

    channels = 3 if args.rgb else 1
    if args.scene == "plane":
        return syn.fronto_parallel_plane(rig, depth, seed=seed, channels=channels)
    if args.scene == "slanted":
        return syn.slanted_plane(rig, depth, slant_deg=args.slant_deg, seed=seed, channels=channels)
    if args.scene == "step":
        return syn.step_scene(rig, depth, args.far_mm or depth + 200.0, seed=seed, channels=channels)
    if args.scene == "sphere":
        radius = args.radius_mm or 0.08 * depth
        far = args.far_mm or depth + 2 * radius + 100.0
        return syn.sphere_scene(rig, depth, radius, far, seed=seed, channels=channels)
    if args.scene == "checkerboard":
        return syn.checkerboard_target((0.0, 0.0, depth), args.pose_deg)
    if args.scene == "circlegrid":
        return syn.circle_grid_target((0.0, 0.0, depth), args.pose_deg)
    if args.middlebury is None:
        raise syn.SceneError("--scene middlebury needs --middlebury DIR (a folder with img_left.png and disp_gt)")
    return syn.middlebury_scene(args.middlebury, near_mm=depth, far_mm=args.far_mm or depth + 250.0,
                                channels=channels)


def _cmd_render(args: argparse.Namespace) -> int:
    from prismstereo import synthetic as syn
    from prismstereo.io import save_capture

    rig = load_rig(args.rig)
    scenes = [_make_scene(args, rig, depth, args.seed + i) for i, depth in enumerate(args.depth_mm)]
    formation = syn.ImageFormation(
        supersample=args.supersample, channels=3 if args.rgb else 1, noise_sigma=args.noise,
        blur_sigma_px=args.blur_px, vignetting=args.vignetting, poisson_photons=args.photons, bits=args.bits,
        seed=args.seed,
    )
    out = Path(args.out)
    if len(scenes) > 1 and out.suffix:
        raise PrismStereoError(f"several --depth-mm values render a batch: --out must be a directory, got {out}")
    capture = syn.render(rig, scenes, formation, progress=len(scenes) > 1)
    for i, scene in enumerate(scenes):
        path = out if len(scenes) == 1 else out / f"{scene.name}.png"
        if path.suffix.lower() not in (".png", ".tif", ".tiff"):
            raise PrismStereoError(f"--out must end in .png or .tif (lossless), got {path}")
        meta = {"rig": rig.to_json(), "scene": scene.name, "formation": formation}
        npz = save_capture(capture, i, path, args.bits, meta)
        valid = capture.valid[i].float().mean().item()
        covis = capture.covisible[i].float().sum().item() / max(1.0, capture.left[i].float().sum().item())
        print(f"wrote {path} and {npz.name}: {valid:.1%} valid pixels, {covis:.1%} of the left half co-visible")
    return 0


def _cmd_fov(args: argparse.Namespace) -> int:
    from prismstereo import analysis as an

    rig = load_rig(args.rig)
    fov = an.fov_closed_form(rig)
    z_b = float(fov.left_ray1.back_plane_z)
    deg = math.degrees
    cross, far = float(fov.crossing_depth), float(fov.far_depth)
    lines = [
        "Field of view (thesis ch. 5; top view, camera frame: x right, z forward, mm)",
        f"  type                      {fov.fov_type}  (epsilon = phi4/phi2 = {float(fov.epsilon):.4f}, eq. 5.12)",
        f"  alpha                     {rig.alpha_deg:.3f} deg  (alpha1 {deg(fov.boundary.alpha1):.3f} deg: phi4 = phi2,"
        f" alpha2 {deg(fov.boundary.alpha2):.3f} deg: phi4 = 0)",
        f"  phi2  Ray 1 angle         {float(fov.phi2):.5f} rad  ({deg(float(fov.phi2)):.3f} deg, eq. 5.5)",
        f"  phi4  Ray 2 angle         {float(fov.phi4):+.5f} rad  ({deg(float(fov.phi4)):+.3f} deg, eq. 5.9)",
        f"  gamma common FOV angle    {float(fov.gamma):.5f} rad  ({deg(float(fov.gamma)):.3f} deg, eq. 5.10)",
        f"  h     Ray 1 intercept     {float(fov.h):.5f} mm  (eq. 5.16)",
        f"  v     Ray 2 intercept     {float(fov.v):.5f} mm  (eq. 5.25)",
        f"  Ray 2 crosses Ray 1 at    {f'Z = {cross:.1f} mm' if math.isfinite(cross) else 'never'}",
        f"  common FOV closes at      {f'Z = {far:.1f} mm' if math.isfinite(far) else 'never (open FOV)'}",
    ]
    if not fov.edge_rays_on_prism:
        lines.append("  warning: a sensor-edge ray misses the prism; the exact outer border is the prism's edge")
    lines.append(f"Border rays: x = x0 + (z - {z_b:.3f}) tan(theta), theta > 0 toward +x (eq. 5.17, 5.36-5.37)")
    for half in ("left", "right"):
        for k, role in ((1, "inner, apex"), (2, "outer, edge")):
            ray = getattr(fov, f"{half}_ray{k}")
            lines.append(f"  {half:<5} half  Ray {k} ({role})   x = {float(ray.intercept):+.5f} + (z - {z_b:.3f})"
                         f" * {math.tan(float(ray.angle)):+.6f}   (theta {float(ray.angle):+.5f} rad)")
    depths = [z for z in args.depth_mm if z > z_b]
    if not depths:
        raise PrismStereoError(f"--depth-mm values must be beyond the back plane ({z_b:.1f} mm)")
    cmp = an.compare_fov(rig, depths)
    lines.append("Common FOV (closed form vs exact ray trace of the principal row)")
    lines.append("  depth (mm)   width closed (mm)   width exact (mm)   worst border |diff| (mm)   exact x range (mm)")
    for i, z in enumerate(depths):
        lo, hi = cmp.exact.common[i].tolist()
        rng = f"[{lo:+.2f}, {hi:+.2f}]" if bool(cmp.exact.overlap[i]) else "none"
        lines.append(f"  {z:10.1f}   {float(cmp.closed_form.width[i]):17.3f}   {float(cmp.exact.width[i]):16.3f}"
                     f"   {float(cmp.difference[i]):24.2e}   {rng}")
    print("\n".join(lines))
    if args.plot:
        from prismstereo.analysis.plots import plot_fov_top_view

        ax = plot_fov_top_view(rig, args.plot_depth_mm)
        ax.figure.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")
    return 0


def _cmd_design(args: argparse.Namespace) -> int:
    from prismstereo import analysis as an

    rig = load_rig(args.rig)
    varies = [args.vary] if args.vary else list(an.VARY)
    z, target, px = args.depth_mm, args.target_error_mm, args.disparity_px
    names = {"f": "focal length f", "alpha": "prism angle alpha", "T_o": "prism distance T_o",
             "T": "prism thickness T"}
    eqs = {"f": "6.39", "alpha": "6.42 + 6.46", "T_o": "6.47", "T": "6.46"}
    lines = [f"Design for a depth error of {target:g} mm at Z = {z:g} mm from a disparity error of {px:g} px "
             f"({px * rig.pixel_size_mm:g} mm) (thesis sec. 6.3)"]
    rigs = {"current": rig}
    for vary in varies:
        d = an.design(rig, target_error_mm=target, depth_mm=z, vary=vary, disparity_px=px)
        if vary == varies[0]:
            lines.append(f"  current rig: error {d.current_error[0]:.3f} mm (eq. 6.36), {d.current_error[1]:.3f} mm"
                         " (exact model)")
        u = d.unit
        lines += [
            f"  vary {names[vary]}" + ("  (back-plane half-width t_b kept)" if vary in ("alpha", "T") else ""),
            f"    current {d.current:.4f} {u}; closed form (eq. {eqs[vary]}) {d.closed_form:.4f} {u};"
            f" exact {d.exact:.4f} {u}",
            f"    closed form - exact = {d.difference:+.4f} {u} ({d.difference / d.exact:+.2%});"
            f" the closed-form design's exact error is {d.closed_form_error_exact:.3f} mm",
        ]
        if d.pixels is not None:
            p = d.pixels
            lines.append(f"    or keep the FOV (theta_vc {p.theta_vc:.4f} rad): sensor {p.width_px:.0f} x "
                         f"{p.height_px:.0f} px, {p.pixels:.0f} px per half-image (eq. 6.41)")
        if vary == "T":
            t = an.required_thickness(rig, z, target, px)
            lines.append(f"    rejected root T+ = {t.rejected:.1f} mm (> n Z / (n - 1) = "
                         f"{z * rig.refractive_index / (rig.refractive_index - 1):.1f} mm: past the object)")
        if d.exact_rig is not None:
            rigs[f"{vary} = {d.exact:.3f} {u}"] = d.exact_rig
    back = max(r.apex_distance_mm + r.prism_thickness_mm for r in rigs.values())
    depths = [v for v in args.curve_depths_mm if v > back] if args.curve_depths_mm else [
        v for v in (250.0, 500.0, 750.0, 1000.0, 1500.0, 2000.0, 3000.0) if v > back]
    curves = an.error_curves_of(rigs, depths, px)
    lines.append("Absolute depth error (mm) against depth: closed form (eq. 6.22) / exact model")
    lines.append("  " + f"{'depth (mm)':>10}" + "".join(f"  {name:>24}" for name in curves))
    for i, depth in enumerate(depths):
        cells = "".join(f"  {float(c.closed_form[i]):>11.3f} / {float(c.exact[i]):>10.3f}" for c in curves.values())
        lines.append(f"  {depth:10.1f}{cells}")
    print("\n".join(lines))
    if args.plot:
        from prismstereo.analysis.plots import plot_curves

        dense = torch.linspace(depths[0], depths[-1], 30, dtype=torch.float64)
        series, styles = {}, {}
        for name, c in an.error_curves_of(rigs, dense, px).items():
            series[f"{name} (exact)"], styles[f"{name} (exact)"] = (c.depth, c.exact), "-"
            series[f"{name} (eq. 6.22)"], styles[f"{name} (eq. 6.22)"] = (c.depth, c.closed_form), "--"
        ax = plot_curves(series, styles=styles, title=f"depth error of a {px:g} px disparity error")
        ax.axhline(target, color="k", lw=0.8, ls=":")
        ax.axvline(z, color="k", lw=0.8, ls=":")
        ax.figure.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")
    return 0


def _cmd_match(args: argparse.Namespace) -> int:
    import numpy as np

    from prismstereo.io import read_image
    from prismstereo.matching.rectified import MatchOptions, match_rectified

    out = Path(args.out)
    if out.suffix != ".npy":
        raise PrismStereoError(f"--out must end in .npy, got {out}")
    if out.resolve() in (Path(args.left).resolve(), Path(args.right).resolve()):
        raise PrismStereoError("--out would overwrite an input image")
    left, right = read_image(args.left), read_image(args.right)
    if left.shape != right.shape:
        raise PrismStereoError(f"left {tuple(left.shape)} and right {tuple(right.shape)} images differ in size")
    chosen = {k: v for k, v in (("cost", args.cost), ("aggregation", args.aggregation)) if v is not None}
    options = MatchOptions().with_options(fill=not args.no_fill, **chosen)  # MatchOptions' defaults unless asked
    res = match_rectified(left[None], right[None], args.disparities, options)
    written = res.valid | res.filled  # the dense map benchmarks/middlebury.py scores
    disparity = torch.where(written, res.disparity, torch.full_like(res.disparity, float("nan")))[0, 0]
    out.parent.mkdir(parents=True, exist_ok=True)
    np.save(out, disparity.numpy().astype(np.float32))
    print(f"wrote {out}: {written.float().mean():.1%} of pixels have a disparity ({res.valid.float().mean():.1%} "
          f"passed the checks, {res.filled.float().mean():.1%} filled from their background)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``prismstereo`` command."""
    parser = argparse.ArgumentParser(prog="prismstereo", description="Single-lens bi-prism stereo.")
    parser.add_argument("--version", action="version", version=f"prismstereo {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    rig = sub.add_parser("rig", help="inspect rig files")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="RIG_COMMAND")
    show = rig_sub.add_parser("show", help="print a rig and its derived virtual cameras")
    show.add_argument("rig", metavar="RIG", help="rig JSON file or preset name (thesis_setup1, thesis_setup2)")
    show.set_defaults(func=_cmd_rig_show)
    preset = rig_sub.add_parser("preset", help="write a preset rig as JSON")
    preset.add_argument("name", choices=sorted(RIG_PRESETS))
    preset.add_argument("--out", help="output JSON path (default: print)")
    preset.set_defaults(func=_cmd_rig_preset)

    render = sub.add_parser("render", help="render a synthetic capture with ground truth (.png + .npz)")
    render.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
    render.add_argument("--scene", choices=SCENES, default="plane")
    render.add_argument("--depth-mm", type=float, nargs="+", required=True,
                        help="scene depth(s): plane depth, step near plane, sphere centre, target centre, "
                             "middlebury near depth; several values render a batch")
    render.add_argument("--out", required=True, help="output .png (one depth) or directory (several)")
    render.add_argument("--seed", type=int, default=0, help="texture and noise seed")
    render.add_argument("--noise", type=float, default=0.0,
                        help="Gaussian noise sigma in [0, 1] units (1/255: one level)")
    render.add_argument("--supersample", type=int, default=3, help="s x s samples per pixel")
    render.add_argument("--bits", type=int, choices=(8, 16), default=8)
    render.add_argument("--rgb", action="store_true", help="render RGB instead of grey")
    render.add_argument("--blur-px", type=float, default=0.0, help="Gaussian defocus sigma (px)")
    render.add_argument("--vignetting", type=float, default=0.0, help="cos^4 vignetting strength in [0, 1]")
    render.add_argument("--photons", type=float, default=None, help="photons at full scale (shot noise)")
    render.add_argument("--slant-deg", type=float, default=30.0, help="slanted: rotation about y")
    render.add_argument("--far-mm", type=float, default=None, help="step/sphere background or middlebury far depth")
    render.add_argument("--radius-mm", type=float, default=None, help="sphere radius (default 8%% of its depth)")
    render.add_argument("--pose-deg", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("RX", "RY", "RZ"),
                        help="target rotation about x, y, z")
    render.add_argument("--middlebury", default=None, help="folder of a Middlebury pair (scene middlebury)")
    render.set_defaults(func=_cmd_render)

    fov = sub.add_parser("fov", help="field of view: type, angles, border rays, common-FOV width (thesis ch. 5)")
    fov.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
    fov.add_argument("--depth-mm", type=float, nargs="+", default=[500.0, 1000.0, 2000.0, 5000.0],
                     help="depths at which the common-FOV width is printed")
    fov.add_argument("--plot", default=None, help="write the top view (both FOVs, common region) to this image")
    fov.add_argument("--plot-depth-mm", type=float, default=None, help="last depth drawn in the plot")
    fov.set_defaults(func=_cmd_fov)

    design = sub.add_parser("design", help="parameter needed for a target depth error (thesis sec. 6.3)")
    design.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
    design.add_argument("--target-error-mm", type=float, required=True, help="wanted absolute depth error")
    design.add_argument("--depth-mm", type=float, required=True, help="depth at which the target must hold")
    design.add_argument("--vary", choices=("f", "alpha", "T_o", "T"), default=None,
                        help="the parameter to change (default: each in turn)")
    design.add_argument("--disparity-px", type=float, default=1.0, help="disparity error in pixels")
    design.add_argument("--curve-depths-mm", type=float, nargs="+", default=None,
                        help="depths of the printed error curves")
    design.add_argument("--plot", default=None, help="write the error-vs-depth curves to this image")
    design.set_defaults(func=_cmd_design)

    match = sub.add_parser("match", help="match an already rectified conventional pair (no prism)")
    match.add_argument("left", metavar="LEFT", help="left image (8/16-bit PNG/TIFF/JPEG)")
    match.add_argument("right", metavar="RIGHT", help="right image")
    match.add_argument("--disparities", type=int, required=True, help="search disparities 0..N-1")
    match.add_argument("--out", required=True, help="output .npy: float32 left-view disparity, NaN where invalid "
                       "(pixels rejected by the checks get the background fill unless --no-fill)")
    match.add_argument("--no-fill", action="store_true", help="NaN for every pixel that failed the left-right / "
                       "uniqueness checks instead of the background fill")
    match.add_argument("--cost", choices=("ad_gradient", "census", "sad", "zncc"), default=None,
                       help="matching cost (default: MATCH_CONFIG's, ad_gradient)")
    match.add_argument("--aggregation", choices=("guided", "sgm", "box"), default=None,
                       help="cost aggregation (default: MATCH_CONFIG's, guided)")
    match.set_defaults(func=_cmd_match)

    add_depth_parser(sub)
    add_export_parser(sub)
    add_calibrate_parser(sub)
    from prismstereo.cli_train import add_train_parser  # the learned model's trainer
    add_train_parser(sub)

    demo = sub.add_parser("demo", help="run the main job on a built-in default")
    demo.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
    demo.add_argument("--scale", type=int, default=2,
                      help="run the depth part on a sensor this many times coarser (0 skips it)")
    demo.add_argument("--out", default="demo_output", help="output folder of the depth part")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``prismstereo`` console script. Returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help(sys.stderr)
        return 2
    try:
        return args.func(args)
    except PrismStereoError as exc:
        print(f"prismstereo: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
