"""``prismstereo train``: train LearnedStereo's CNNs on renders of a rig and write a weights file (only calls the
library).

Contract::

    prismstereo train --rig RIG.json|PRESET --out WEIGHTS.pt [--steps N] [--seed S] [--z-range ZMIN ZMAX]
        [--cache DIR] [--batch-size B] [--captures N] [--downscale K] [--hypotheses D] [--quiet]

Renders ``--captures`` random scenes through the rig binned by ``--downscale`` (kept in ``--cache``), trains
(:func:`~prismstereo.learned.train.train`) and writes ``--out``; the shipped default weights are only replaced
when ``--out`` names them. Prints the loss at the start and end and the time. Errors exit with status 2 and a
message: an unknown preset or bad rig file, an output that is not a ``.pt`` file, a bad range or count.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from prismstereo.errors import OptionError

__all__ = ["add_train_parser"]


def _cmd_train(args: argparse.Namespace) -> int:
    import torch

    from prismstereo.geometry.presets import load_rig
    from prismstereo.learned.train import train

    out = Path(args.out)
    if out.suffix != ".pt" or out.is_dir():
        raise OptionError(f"--out must be a .pt file, got {out}")
    rig = load_rig(args.rig)
    z0, z1 = args.z_range
    if not 0 < z0 < z1:
        raise OptionError(f"--z-range must be two increasing depths in mm, got {z0:g} {z1:g}")
    torch.set_num_threads(min(2, torch.get_num_threads()))
    result = train(rig, out, steps=args.steps, seed=args.seed, batch_size=args.batch_size, z_range_mm=(z0, z1),
                   num_hypotheses=args.hypotheses, downscale=args.downscale, captures=args.captures,
                   rig_name=Path(args.rig).stem, progress=not args.quiet, cache=args.cache)
    k = min(20, len(result.losses))
    print(f"trained {args.steps} steps in {result.seconds:.0f} s: loss {float(result.losses[:k].mean()):.3f} "
          f"(first {k}) -> {float(result.losses[-k:].mean()):.3f} (last {k})")
    print(f"wrote {result.path}")
    return 0


def add_train_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``prismstereo train`` on the main parser's subcommands."""
    cmd = sub.add_parser("train", help="train the learned depth model's CNNs on renders of a rig",
                         description="Render random scenes with ground truth through the rig, train LearnedStereo's "
                                     "CNNs on them (CPU, minutes) and write a weights file for "
                                     "prismstereo.learned.LearnedStereo(weights=...).")
    cmd.add_argument("--rig", required=True, help="rig JSON file or preset name")
    cmd.add_argument("--out", required=True, help="weights file to write (.pt)")
    cmd.add_argument("--steps", type=int, default=900, help="optimiser steps (default 900)")
    cmd.add_argument("--seed", type=int, default=0, help="seed of the renders, the initialisation and the data order")
    cmd.add_argument("--z-range", type=float, nargs=2, default=(450.0, 1000.0), metavar=("ZMIN", "ZMAX"),
                     help="depths rendered and searched (mm, default 450 1000)")
    cmd.add_argument("--cache", default=None, metavar="DIR", help="keep the rendered captures here")
    cmd.add_argument("--batch-size", type=int, default=4, help="captures per step (default 4)")
    cmd.add_argument("--captures", type=int, default=80, help="captures rendered (default 80)")
    cmd.add_argument("--downscale", type=int, default=2, help="train on the sensor binned by this (default 2)")
    cmd.add_argument("--hypotheses", type=int, default=24, help="hypotheses of the training searches (default 24)")
    cmd.add_argument("--quiet", action="store_true", help="no progress bars")
    cmd.set_defaults(func=_cmd_train)
