"""The ``prismstereo`` command line. It only parses arguments, calls the library and prints.

Subcommands (this release): ``rig show``, ``rig preset``, ``render``, ``demo``; ``--version``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from prismstereo import __version__
from prismstereo.errors import PrismStereoError
from prismstereo.geometry.optics import points_at_depth, project_points, trace_pixels
from prismstereo.geometry.rig import BiPrismRig, thesis_setup1, thesis_setup2
from prismstereo.geometry.virtual_camera import VirtualCamera, virtual_cameras

PRESETS = {"thesis_setup1": thesis_setup1, "thesis_setup2": thesis_setup2}


def load_rig(source: str) -> BiPrismRig:
    """A rig from a JSON file path or a preset name (``thesis_setup1``, ``thesis_setup2``)."""
    if source in PRESETS:
        return PRESETS[source]()
    return BiPrismRig.from_json(source)


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
    rig = PRESETS[args.name]()
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
    return 0


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
    preset.add_argument("name", choices=sorted(PRESETS))
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

    demo = sub.add_parser("demo", help="run the main job on a built-in default")
    demo.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
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
