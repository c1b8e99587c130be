"""``prismstereo calibrate``: a calibrated rig file from board captures through the prism (only calls the library).

Contract (other tools drive it)::

    prismstereo calibrate --rig NOMINAL.json IMAGE... --out CALIBRATED.json
        --target checkerboard:COLSxROWS:SQUARE_MM | charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT
        [--scenes CAPTURE ...] [--fix NAME ...] [--free NAME ...] [--plot RESIDUALS.png] [--quiet]

Without ``--target`` it self-calibrates from the captures' texture
(:func:`~prismstereo.calibration.selfcal.calibrate_self`); with ``--target`` and ``--scenes`` it solves one bundle
adjustment over the boards and the scenes' matches (:func:`~prismstereo.calibration.joint.calibrate_joint`). The
report goes to stdout, progress bars to stderr; the output is a normal rig file. Errors exit with status 2 and a
message: board not found in enough views, too few views, scenes without texture, images of the wrong size, a fit
that diverged, an output path equal to the nominal rig file.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from prismstereo.errors import CalibrationError

__all__ = ["add_parser"]


def _read(paths, rig) -> list:
    """The captures at ``paths``, each checked to be of the rig's size."""
    from prismstereo.io import read_image

    images = []
    for path in paths:
        image = read_image(Path(path))
        h, w = image.shape[-2:]
        if (w, h) != (rig.image_width, rig.image_height):
            raise CalibrationError(f"image {path} is {w}x{h} px but the rig's sensor is "
                                   f"{rig.image_width}x{rig.image_height} px")
        images.append(image)
    return images


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from prismstereo.calibration import calibrate_board, calibrate_joint, calibrate_self, parse_target
    from prismstereo.calibration.parameters import check_names
    from prismstereo.calibration.report import format_report, plot_residuals
    from prismstereo.geometry.presets import load_rig

    out = Path(args.out)
    if Path(args.rig).exists() and out.resolve() == Path(args.rig).resolve():
        raise CalibrationError(f"--out {out} is the nominal rig file: it is never overwritten, choose another path")
    rig = load_rig(args.rig)
    board = parse_target(args.target) if args.target is not None else None
    if args.scenes and board is None:
        raise CalibrationError("--scenes go beside the board captures of --target; without a target the captures "
                               "themselves are the scenes (self-calibration)")
    fix = check_names(args.fix or ())
    free = check_names(args.free or ())
    images, scenes = _read(args.images, rig), _read(args.scenes or (), rig)
    if board is None:  # no target: self-calibration from the scenes' texture
        result = calibrate_self(rig, images, fix=fix, free=free, progress=not args.quiet)
    elif scenes:  # boards and scenes in one bundle adjustment
        result = calibrate_joint(rig, images, board, scenes, fix=fix, free=free, corners=args.corners,
                                 progress=not args.quiet)
    else:
        result = calibrate_board(rig, images, board, fix=fix, free=free, corners=args.corners,
                                 progress=not args.quiet)
    names = [Path(p).name for p in args.images]
    print(format_report(result, names, [Path(p).name for p in args.scenes or ()]))
    result.rig.to_json(out)
    print(f"\nwrote {out}")
    if args.plot:
        plot_residuals(result, args.plot, names)
        print(f"wrote {args.plot}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``prismstereo calibrate`` on the main parser's subcommands."""
    from prismstereo.calibration import DEFAULT_FIXED, NAMES

    cal = sub.add_parser("calibrate", help="calibrate a rig from board captures (or textured scenes) through the prism",
                         description="Bundle-adjust the rig (intrinsics, distortion, prism pose, alpha, n) to the "
                                     "board corners found in both halves of every capture, starting from the nominal "
                                     "rig; writes the calibrated rig file and prints the report.")
    cal.add_argument("images", nargs="+", metavar="IMAGE", help="captures of the board through the prism")
    cal.add_argument("--rig", required=True, help="the nominal rig (JSON file or preset name); never overwritten")
    cal.add_argument("--out", required=True, help="the calibrated rig file to write")
    cal.add_argument("--target", default=None,
                     help="checkerboard:COLSxROWS:SQUARE_MM (inner corners) or "
                          "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT (squares), e.g. checkerboard:9x6:25; without "
                          "it, self-calibration from the scenes' texture (1-3 captures: it fixes the epipolar geometry "
                          "- roll, tilt, offset, distortion - but no metric scale, see the report)")
    cal.add_argument("--scenes", nargs="+", metavar="CAPTURE", default=None,
                     help="with --target: captures of textured scenes (any objects both halves see) solved together "
                          "with the boards in one bundle adjustment: the boards fix the metric scale, the scenes' "
                          "matches the epipolar geometry a small board leaves weak (the report says what each "
                          "contributed)")
    cal.add_argument("--fix", nargs="+", metavar="NAME", default=None,
                     help=f"hold these at their nominal values (besides {', '.join(DEFAULT_FIXED)}); "
                          f"names: {', '.join(NAMES)}")
    cal.add_argument("--free", nargs="+", metavar="NAME", default=None,
                     help=f"estimate these default-fixed parameters too ({', '.join(DEFAULT_FIXED)})")
    cal.add_argument("--corners", choices=("symmetric", "opencv"), default="symmetric",
                     help="sub-pixel corners: refined to their centre of point symmetry (default; closer on "
                          "rendered boards, benchmarks/corners.py) or OpenCV's detector positions as they are")
    cal.add_argument("--plot", default=None, metavar="PNG", help="save a plot of the residuals per view")
    cal.add_argument("--quiet", action="store_true", help="no progress bars")
    cal.set_defaults(func=_cmd_calibrate)

