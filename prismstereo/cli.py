"""The ``prismstereo`` command line. It only parses arguments, calls the library and prints.

Subcommands (this release): ``rig show``, ``rig preset``, ``demo``; ``--version``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

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
