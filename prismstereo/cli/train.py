"""``prismstereo train``: train LearnedStereo's CNNs on renders of a rig and write a weights file (only calls the
library).

Contract::

    prismstereo train --rig RIG.json|PRESET --out WEIGHTS.pt [--steps N] [--seed S] [--z-range ZMIN ZMAX]
        [--cache DIR] [--batch-size B] [--captures N] [--downscale K] [--hypotheses D] [--quiet]
    prismstereo train --model hybrid --out WEIGHTS.pt [--start classical|learned] [--steps N] [--seed S]
        [--cache DIR] [--batch-size B] [--captures N] [--quiet]
    prismstereo train --model start --out WEIGHTS.pt [--steps N] [--seed S] [--cache DIR] [--batch-size B]
        [--captures N] [--quiet]
    prismstereo train --model head --out WEIGHTS.pt [--weights HYBRID.pt] [--steps N] [--seed S] [--cache DIR]
        [--batch-size B] [--captures N] [--quiet]

``--model learned`` (the default) renders ``--captures`` random scenes through the rig binned by ``--downscale`` (kept
in ``--cache``), trains :class:`~prismstereo.learned.LearnedStereo` (:func:`~prismstereo.learned.train.train`) and
writes ``--out``. ``--model hybrid`` renders ``--captures`` scenes through each of the training rig variants
(:func:`~prismstereo.learned.hybrid_data.training_rigs`), trains the refinement of
:class:`~prismstereo.learned.hybrid.HybridStereo` (:func:`~prismstereo.learned.hybrid_train.train_hybrid`), then its
exact chain's confidence head (:func:`~prismstereo.learned.confidence_train.train_exact_confidence`, on those renders
and two 512 x 384 sensors') and writes ``--out``; the refinement keeps a checkpoint beside ``--out`` and the same
command resumes from it; the refinement starts from the shipped learned first stage's estimates (``--start learned``,
the default) or from the classical block level's (``--start classical``). ``--model head`` trains only that confidence
head, of the hybrid weights ``--weights`` (default: the shipped ones), and writes them with it to ``--out``. ``--model
start`` trains that first stage (:func:`~prismstereo.learned.start_train.train_start`) on the same renders, resumable
too. The shipped default weights are only replaced when ``--out`` names them. Prints the loss at the start and end and
the time. Errors exit with status 2 and a message: an unknown preset or bad rig file, an output that is not a ``.pt``
file, a bad range or count, a missing ``--rig`` for the learned model, ``--rig`` / ``--z-range`` / ``--downscale`` /
``--hypotheses`` with the hybrid, the head or the start, ``--start`` with another model than the hybrid, ``--weights``
with another model than the head.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from prismstereo.errors import OptionError

__all__ = ["add_parser"]


def _or(value: int | None, default: int) -> int:
    return default if value is None else value


def _cmd_train(args: argparse.Namespace) -> int:
    from prismstereo.threads import thread_plan, torch_threads

    out = Path(args.out)
    if out.suffix != ".pt" or out.is_dir():
        raise OptionError(f"--out must be a .pt file, got {out}")
    with torch_threads(min(2, thread_plan().torch)):  # the trainers' batches keep two threads busy, not more
        result = _train(args, out)
    k = min(20, len(result.losses))
    print(f"trained {len(result.losses)} steps in {result.seconds:.0f} s: loss {float(result.losses[:k].mean()):.3f} "
          f"(first {k}) -> {float(result.losses[-k:].mean()):.3f} (last {k})")
    print(f"wrote {result.path}")
    return 0


def _train(args: argparse.Namespace, out: Path):
    """The model's trainer with the flags' options (its TrainResult)."""
    if args.start is not None and args.model != "hybrid":
        raise OptionError("--start applies to --model hybrid only")
    if args.weights is not None and args.model != "head":
        raise OptionError("--weights applies to --model head only")
    if args.model in ("hybrid", "start", "head"):
        learned_only = [flag for flag, value in (("--rig", args.rig), ("--z-range", args.z_range),
                                                 ("--downscale", args.downscale), ("--hypotheses", args.hypotheses))
                        if value is not None]
        if learned_only:
            raise OptionError(f"{', '.join(learned_only)} apply to --model learned only (the {args.model} trains on "
                              "the rig variants of prismstereo.learned.hybrid_data.training_rigs"
                              f"{' and two 512 x 384 sensors' if args.model == 'head' else ''})")
    if args.model == "start":
        from prismstereo.learned.start_train import train_start

        return train_start(out, steps=_or(args.steps, 3000), seed=args.seed, batch_size=_or(args.batch_size, 2),
                           captures=_or(args.captures, 24), cache=args.cache, progress=not args.quiet)
    if args.model == "head":
        from prismstereo.learned import confidence_train
        from prismstereo.learned.hybrid import HYBRID_WEIGHTS

        return confidence_train.train_exact_confidence(
            args.weights or HYBRID_WEIGHTS, out, steps=_or(args.steps, 1500), seed=args.seed,
            batch_size=_or(args.batch_size, 4), captures=_or(args.captures, 24), cache=args.cache,
            progress=not args.quiet)
    if args.model == "hybrid":
        from prismstereo.learned import confidence_train, hybrid_train
        from prismstereo.learned.refinement import HybridArchitecture

        result = hybrid_train.train_hybrid(out, steps=_or(args.steps, 6000), seed=args.seed,
                                           batch_size=_or(args.batch_size, 8), captures=_or(args.captures, 24),
                                           cache=args.cache, progress=not args.quiet,
                                           architecture=HybridArchitecture(start=args.start or "learned"))
        head = confidence_train.train_exact_confidence(result.path, seed=args.seed, captures=_or(args.captures, 24),
                                                       cache=args.cache, progress=not args.quiet)
        print(f"confidence head: {len(head.losses)} steps in {head.seconds:.0f} s, loss "
              f"{float(head.losses[-min(50, len(head.losses)):].mean()):.3f} (last steps)")
        return result
    from prismstereo.geometry.presets import load_rig
    from prismstereo.learned.train import train

    if args.rig is None:
        raise OptionError("--rig is required for --model learned (a rig JSON file or preset name)")
    rig = load_rig(args.rig)
    z0, z1 = args.z_range or (450.0, 1000.0)
    if not 0 < z0 < z1:
        raise OptionError(f"--z-range must be two increasing depths in mm, got {z0:g} {z1:g}")
    return train(rig, out, steps=_or(args.steps, 900), seed=args.seed, batch_size=_or(args.batch_size, 4),
                 z_range_mm=(z0, z1), num_hypotheses=_or(args.hypotheses, 24), downscale=_or(args.downscale, 2),
                 captures=_or(args.captures, 80), rig_name=Path(args.rig).stem, progress=not args.quiet,
                 cache=args.cache)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``prismstereo train`` on the main parser's subcommands."""
    cmd = sub.add_parser("train", help="train a learned depth model's CNNs on renders",
                         description="Render random scenes with ground truth, train the CNNs of LearnedStereo (through "
                                     "--rig) or of HybridStereo (--model hybrid: through the training rig variants, "
                                     "resumable) on them on the CPU and write a weights file for "
                                     "prismstereo.learned.LearnedStereo / HybridStereo(weights=...).")
    cmd.add_argument("--model", choices=("learned", "hybrid", "start", "head"), default="learned",
                     help="learned: LearnedStereo on one rig (default); hybrid: HybridStereo's refinement on the "
                          "training rig variants, resumable, then its confidence head; start: the hybrid's learned "
                          "first stage, same renders; head: only the confidence head of --weights")
    cmd.add_argument("--weights", default=None, help="the hybrid weights whose confidence head --model head trains "
                                                     "(default: the shipped ones)")
    cmd.add_argument("--start", choices=("classical", "learned"), default=None,
                     help="what the hybrid's refinement starts from (default learned: the shipped first stage; "
                          "--model hybrid)")
    cmd.add_argument("--rig", default=None, help="rig JSON file or preset name (--model learned)")
    cmd.add_argument("--out", required=True, help="weights file to write (.pt)")
    cmd.add_argument("--steps", type=int, default=None,
                     help="optimiser steps (default 900; hybrid 6000; start 3000; head 1500)")
    cmd.add_argument("--seed", type=int, default=0, help="seed of the renders, the initialisation and the data order")
    cmd.add_argument("--z-range", type=float, nargs=2, default=None, metavar=("ZMIN", "ZMAX"),
                     help="depths rendered and searched (mm, default 450 1000; --model learned)")
    cmd.add_argument("--cache", default=None, metavar="DIR", help="keep the rendered captures here")
    cmd.add_argument("--batch-size", type=int, default=None,
                     help="captures per step (default 4; hybrid 8; start 2)")
    cmd.add_argument("--captures", type=int, default=None,
                     help="captures rendered (default 80; hybrid: per rig variant, 24)")
    cmd.add_argument("--downscale", type=int, default=None,
                     help="train on the sensor binned by this (default 2; --model learned)")
    cmd.add_argument("--hypotheses", type=int, default=None,
                     help="hypotheses of the training searches (default 24; --model learned)")
    cmd.add_argument("--quiet", action="store_true", help="no progress bars")
    cmd.set_defaults(func=_cmd_train)
