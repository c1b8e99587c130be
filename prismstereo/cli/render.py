"""``prismstereo render``: synthetic captures with their ground truth (.png + .npz): textured scenes, and calibration
boards (``--scene board --target SPEC``, the spec ``prismstereo calibrate`` takes) at one pose or at ``--views`` random
ones."""

from __future__ import annotations

import argparse
from pathlib import Path

from prismstereo.errors import PrismStereoError
from prismstereo.geometry.presets import load_rig
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["add_parser"]


SCENES = ("plane", "slanted", "step", "sphere", "checkerboard", "circlegrid", "board", "middlebury")


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
    if args.scene == "board":
        return _boards(args, [depth], 1)[0]
    if args.scene == "circlegrid":
        return syn.circle_grid_target((0.0, 0.0, depth), args.pose_deg)
    if args.middlebury is None:
        raise syn.SceneError("--scene middlebury needs --middlebury DIR (a folder with img_left.png and disp_gt)")
    return syn.middlebury_scene(args.middlebury, near_mm=depth, far_mm=args.far_mm or depth + 250.0,
                                channels=channels)


def _boards(args: argparse.Namespace, depths: list[float], views: int):
    """The ``--target`` board: at ``--pose-deg`` on the axis at each depth (``views`` 1), else at ``views`` seeded
    random poses (tilts within ``--max-tilt-deg``) between the depths."""
    from prismstereo import synthetic as syn
    from prismstereo.calibration import parse_target

    if args.target is None:
        raise PrismStereoError("--scene board needs --target SPEC (checkerboard:COLSxROWS:SQUARE_MM or "
                               "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT, as prismstereo calibrate takes)")
    board = parse_target(args.target)
    checker = board.kind == "checkerboard"  # its spec counts inner corners: one square more each way
    size = {"rows": board.rows + checker, "cols": board.cols + checker, "square_mm": board.square_mm}
    if views == 1:
        if checker:
            return [syn.checkerboard_target((0.0, 0.0, d), args.pose_deg, **size) for d in depths]
        return [syn.charuco_target((0.0, 0.0, d), args.pose_deg, marker_mm=board.marker_mm,
                                   dictionary=board.dictionary, **size) for d in depths]
    scenes = syn.calibration_views(views, seed=args.seed, depth_range_mm=(min(depths), max(depths)),
                                   max_tilt_deg=args.max_tilt_deg, kind=board.kind, marker_mm=board.marker_mm,
                                   dictionary=board.dictionary or "DICT_4X4_250", **size)
    for k, scene in enumerate(scenes):
        scene.name = f"board_{k:03d}"
    return scenes


def _cmd_render(args: argparse.Namespace) -> int:
    from prismstereo import synthetic as syn
    from prismstereo.io import save_capture

    rig = load_rig(args.rig)
    if args.views < 1:
        raise PrismStereoError(f"--views must be >= 1, got {args.views}")
    if args.views > 1 and args.scene != "board":
        raise PrismStereoError("--views renders boards at random poses: --scene board")
    if args.views > 1:
        scenes = _boards(args, list(args.depth_mm), args.views)
    else:
        scenes = [_make_scene(args, rig, depth, args.seed + i) for i, depth in enumerate(args.depth_mm)]
    formation = syn.ImageFormation(
        supersample=args.supersample, channels=3 if args.rgb else 1, noise_sigma=args.noise,
        blur_sigma_px=args.blur_px, vignetting=args.vignetting, poisson_photons=args.photons, bits=args.bits,
        seed=args.seed,
    )
    out = Path(args.out)
    if len(scenes) > 1 and out.suffix:
        raise PrismStereoError(f"several --depth-mm values or --views render a batch: --out must be a directory, got "
                               f"{out}")
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


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command on the main parser's subcommands."""
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
    render.add_argument("--target", default=None, metavar="SPEC",
                        help="board: checkerboard:COLSxROWS:SQUARE_MM (inner corners) or "
                             "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT (squares), as prismstereo calibrate takes")
    render.add_argument("--views", type=int, default=1, metavar="N",
                        help="board: N views at seeded random poses, depths between the --depth-mm values (written "
                             "as OUT/board_000.png, ...)")
    render.add_argument("--max-tilt-deg", type=float, default=45.0,
                        help="board with --views: tilts about x and y up to this (30-45 deg make the focal length "
                             "observable)")
    render.add_argument("--middlebury", default=None, help="folder of a Middlebury pair (scene middlebury)")
    render.set_defaults(func=_cmd_render)
