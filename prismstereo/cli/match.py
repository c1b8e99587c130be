"""``prismstereo match``: dense matching of a conventional rectified pair (no prism) on the depth model's matching."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from prismstereo.errors import PrismStereoError

__all__ = ["add_parser"]


def _cmd_match(args: argparse.Namespace) -> int:
    import numpy as np

    from prismstereo.classical.rectified import MatchOptions, match_rectified
    from prismstereo.io import read_image

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


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command on the main parser's subcommands."""
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
