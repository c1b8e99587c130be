"""``prismstereo rig show`` and ``prismstereo rig preset``: a rig file and its derived virtual cameras."""

from __future__ import annotations

import argparse

from prismstereo.geometry.presets import RIG_PRESETS, load_rig
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.virtual_camera import VirtualCamera, virtual_cameras

__all__ = ["add_parser", "show"]


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


def show(rig: BiPrismRig) -> str:
    parts = [_format_rig(rig), "Virtual cameras (thesis ch. 3; camera frame x right, y down, z forward)"]
    for method in ("two_point", "least_squares"):
        pair = virtual_cameras(rig, method)
        parts += [_format_camera(vc, rig.pixel_size_mm) for vc in pair]
    return "\n".join(parts)


def _cmd_rig_show(args: argparse.Namespace) -> int:
    print(show(load_rig(args.rig)))
    return 0


def _cmd_rig_preset(args: argparse.Namespace) -> int:
    rig = RIG_PRESETS[args.name]()
    text = rig.to_json(args.out)
    if args.out is None:
        print(text, end="")
    else:
        print(f"wrote {args.out}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command on the main parser's subcommands."""
    rig = sub.add_parser("rig", help="inspect rig files")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="RIG_COMMAND")
    show = rig_sub.add_parser("show", help="print a rig and its derived virtual cameras")
    show.add_argument("rig", metavar="RIG", help="rig JSON file or preset name (thesis_setup1, thesis_setup2)")
    show.set_defaults(func=_cmd_rig_show)
    preset = rig_sub.add_parser("preset", help="write a preset rig as JSON")
    preset.add_argument("name", choices=sorted(RIG_PRESETS))
    preset.add_argument("--out", help="output JSON path (default: print)")
    preset.set_defaults(func=_cmd_rig_preset)
