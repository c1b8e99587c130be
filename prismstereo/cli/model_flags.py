"""The model flags ``prismstereo depth`` and ``prismstereo export`` share, and what they ask for: a
:class:`~prismstereo.models.ModelSpec` (``--model``, ``--weights``, the hybrid's ``--last-stage``, the classical
model's ``--preset`` / ``--config`` with the search options on top, ``--z-range``). Errors of the library about an
option set by a flag name the flag.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import re
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from prismstereo.errors import PrismStereoError
from prismstereo.names import LAST_STAGES, MODEL_KINDS

if TYPE_CHECKING:  # imported where a model is asked for: parsing the flags needs no torch
    from prismstereo.geometry.rig import BiPrismRig
    from prismstereo.models import ModelSpec

__all__ = ["add_model_arguments", "flag_error", "flag_errors", "model_spec", "range_note", "request_flags"]

# the config options that have a flag of their own: errors about them name the flag
FLAGS = {"num_hypotheses": "--hypotheses", "downsample": "--downsample", "full_band": "--full-band",
         "band_edges": "--band-edges"}


def flag_error(exc: PrismStereoError, given: dict[str, object]) -> PrismStereoError:
    """The library's error about options set by flags (``given``), naming the flags (a flag is never None)."""
    message = str(exc)
    for option in given:
        if option in FLAGS:
            message = re.sub(rf"\b{option}\b", FLAGS[option], message).replace(" or None,", ",")
    return PrismStereoError(message)


@contextlib.contextmanager
def flag_errors(args: argparse.Namespace) -> Iterator[None]:
    """Around building the model the flags ask for: an error about an option set by a flag names the flag."""
    try:
        yield
    except PrismStereoError as exc:
        raise flag_error(exc, _search_flags(args)) from exc


def _search_flags(args: argparse.Namespace) -> dict[str, object]:
    """The classical search options set by flags."""
    return {k: v for k, v in (("num_hypotheses", args.hypotheses), ("downsample", args.downsample),
                              ("full_band", args.full_band), ("band_edges", args.band_edges)) if v is not None}


def _classical_config(args: argparse.Namespace):
    """The classical model's :class:`~prismstereo.classical.StereoConfig` as asked: ``--preset`` (default
    'accurate') or ``--config``, the search options and ``--dense`` on top. The model resolves the rest."""
    from prismstereo.classical import StereoConfig, preset

    base = StereoConfig.from_json(args.config) if args.config is not None else preset(args.preset or "accurate")
    search = _search_flags(args)
    try:
        return base.replace(search=search, validity={"dense": True} if args.dense else {})
    except PrismStereoError as exc:
        raise flag_error(exc, search) from exc


def model_spec(args: argparse.Namespace, rig: BiPrismRig) -> ModelSpec:
    """What the flags ask for: ``--model``, else the classical model with ``--preset``, ``--config`` or a search
    option, the hybrid with ``--weights`` or ``--last-stage``, else the rig's default
    (:func:`~prismstereo.models.default_kind`). Sets ``args.dense`` to the written maps' rule (the classical config's
    ``dense``).

    Raises:
        PrismStereoError: options of another model, ``--preset`` with ``--config``, a bad config or flag.
    """
    from prismstereo.models import ModelSpec

    if args.preset is not None and args.config is not None:
        raise PrismStereoError("--preset and --config exclude each other")
    classical = [name for name, value in (("--preset", args.preset), ("--config", args.config)) if value is not None]
    # the search options' flags (--hypotheses is also the learned model's D)
    classical += [FLAGS[k] for k in _search_flags(args) if not (k == "num_hypotheses" and args.model == "learned")]
    if args.model in ("learned", "hybrid") and classical:
        raise PrismStereoError(f"{', '.join(classical)} set the classical model's options, not --model "
                               f"{args.model}'s")
    if (args.model == "classical" or classical) and args.weights is not None:
        raise PrismStereoError("--weights is the hybrid's or the learned model's, not the classical model's")
    if args.last_stage is not None and (classical or args.model not in (None, "hybrid")):
        raise PrismStereoError(f"--last-stage is the hybrid's, not the {args.model or 'classical'} model's")
    if args.last_stage is not None:
        return ModelSpec(rig=rig, kind="hybrid", z_range=args.z_range, config={"last_stage": args.last_stage},
                         weights=args.weights)
    kind = args.model or ("classical" if classical else "hybrid" if args.weights is not None else None)
    spec = ModelSpec(rig=rig, kind=kind, z_range=args.z_range, weights=args.weights)
    if spec.resolved_kind == "classical":
        config = _classical_config(args)
        args.dense = config.validity.dense
        return ModelSpec(rig=rig, kind="classical", z_range=args.z_range, config=config)
    if spec.resolved_kind == "learned" and args.hypotheses is not None:
        if args.hypotheses < 2:
            raise PrismStereoError(f"--hypotheses must be an int >= 2, got {args.hypotheses}")
        return ModelSpec(rig=rig, kind="learned", z_range=args.z_range, config={"num_hypotheses": args.hypotheses},
                         weights=args.weights)
    return spec


def _content(path: str | None) -> str | None:
    """A file flag's value by its content (sha256), so that a changed file is a new request; the text itself when
    it names no file (a preset, a rig's JSON text)."""
    if path is None:
        return None
    file = Path(path)
    return f"sha256:{hashlib.sha256(file.read_bytes()).hexdigest()}" if file.is_file() else str(path)


def request_flags(args: argparse.Namespace, *, tracked: bool) -> dict[str, Any]:
    """What the flags of ``prismstereo depth`` ask of the model, as JSON: the rig, the model flags and, when
    sequences are ``tracked`` by the temporal prior, its binning; the files named (rig, weights, config) by their
    content. The cache's index remembers the graphs a request was served by under this
    (:func:`~prismstereo.export.index.flags_key`), so the same command again runs them without torch.

    Example:
        >>> args = argparse.Namespace(rig="thesis_setup1", z_range=None, hypotheses=None, downsample=None,
        ...     full_band=None, band_edges=None, model=None, last_stage=None, weights=None, preset=None, config=None,
        ...     dense=False, temporal_binning=None)
        >>> request_flags(args, tracked=False)["rig"]
        'thesis_setup1'
    """
    flags = {name: getattr(args, name) for name in ("z_range", "hypotheses", "downsample", "full_band",
                                                     "band_edges", "model", "last_stage", "preset", "dense")}
    return {**flags, "rig": _content(args.rig), "weights": _content(args.weights), "config": _content(args.config),
            "temporal": {"binning": args.temporal_binning} if tracked else None}


def range_note(args: argparse.Namespace, z_range: tuple[float, float]) -> str:
    """"depth range Z0-Z1 mm (how it was chosen)" for the command's first line."""
    how = "default for this rig" if args.z_range is None else "--z-range"
    return f"depth range {z_range[0]:.1f}-{z_range[1]:.1f} mm ({how})"


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """The model flags of ``depth`` and ``export``: ``--z-range``, ``--hypotheses``, ``--downsample``,
    ``--full-band``, ``--band-edges``, ``--model``, ``--last-stage``, ``--weights``, ``--preset``, ``--config``,
    ``--dense``."""
    parser.add_argument("--z-range", type=float, nargs=2, default=None, metavar=("ZMIN", "ZMAX"),
                        help="depths searched (mm); default from the rig's common field of view "
                             "(prismstereo.depth.default_z_range)")
    parser.add_argument("--hypotheses", type=int, default=None, metavar="N",
                        help="number of depth hypotheses (default: neighbours <= 1 px apart)")
    parser.add_argument("--downsample", type=int, default=None, metavar="K",
                        help="match on KxK-binned pixels, depth on the full grid (~K^2 faster, K x coarser "
                             "unless --full-band); default: 2 with --full-band 2 on sensors whose reference "
                             "half is >= 384 px on its shorter side, else 1")
    parser.add_argument("--full-band", type=int, default=None, metavar="R",
                        help="with --downsample: re-estimate every pixel at full resolution in a band of 2R+1 "
                             "hypotheses around the binned estimate (0: each pixel its block's value; "
                             "default: 0 with an explicit --downsample)")
    parser.add_argument("--band-edges", choices=("reject", "clamp"), default=None,
                        help="a pixel whose best hypothesis is on the edge of its band: invalid (reject) or "
                             "refined from the edge's inner neighbour (clamp, every band; with --full-band 1 the "
                             "fast full-resolution setting); default: clamp where the calibrated confidence "
                             "judges, reject where thresholds do (a binned level)")
    parser.add_argument("--model", choices=MODEL_KINDS, default=None,
                        help="the depth model (prismstereo.build_model): hybrid (HybridStereo: the exact sweep on "
                             "binned blocks refined by learned 2-D stages, a depth and confidence for every pixel), "
                             "classical (PrismStereo, its settings from --preset / --config and the options above) "
                             "or learned (LearnedStereo; --hypotheses: its D, default: neighbours 0.69 px apart on "
                             "the sweep at its 1/4 resolution). Default: classical with --preset, --config or a "
                             "search option, hybrid with --weights or --last-stage, else the rig's default "
                             "(prismstereo.models.default_kind: hybrid from 512 x 384 up, when the reference half "
                             "is >= 192 px on its shorter side). On videos and sequences under the temporal prior "
                             "the hybrid computes the key frames and the classical model's band tracks between them")
    parser.add_argument("--last-stage", choices=LAST_STAGES, default=None,
                        help="the hybrid's last stage: exact (default: the classical band's exact fit where it "
                             "agrees with the learned estimate; textured surfaces as precise as the classical "
                             "model) or learned (the learned estimate as it is: about a fifth faster, planes about "
                             "twice the classical model's error)")
    parser.add_argument("--weights", default=None, metavar="FILE.pt",
                        help="the hybrid's or (--model learned) the learned model's weights, written by prismstereo "
                             "train (default: the shipped ones)")
    parser.add_argument("--preset", choices=("accurate", "fast", "dense", "reference"), default=None,
                        help="the classical model's named settings (prismstereo.classical.PRESETS; accurate is its "
                             "default); the options above override them")
    parser.add_argument("--config", default=None, metavar="FILE.json",
                        help="the classical model with settings from a StereoConfig JSON file "
                             "(prismstereo.classical.config); the options above override it")
    parser.add_argument("--dense", action="store_true",
                        help="a depth for every pixel of the common field of view with its calibrated confidence "
                             "(the probability of a depth within 1 %%), not only for the valid ones; with the "
                             "classical model, from the preset's chain (--preset dense is the chain built for it: its "
                             "coarse level matched by cost-volume filtering, fewer wrong depths on weakly textured "
                             "photographs)")
