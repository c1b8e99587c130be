"""The ``prismstereo depth`` and ``prismstereo export`` subcommands: depth maps (and point clouds) of bi-prism
captures, and the ONNX export of the same depth model.

Parses nothing itself beyond its own arguments and only calls the library: the model from the flags (``--model``,
else by :func:`_model_kind`'s rules: :class:`~prismstereo.learned.HybridStereo` or
:class:`~prismstereo.model.PrismStereo`; built once), the job's outputs and their checks
(:func:`prismstereo.jobs.plan`) and the pipelined run over captures, sequences and videos
(:func:`prismstereo.jobs.run`).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import time
from pathlib import Path

import torch

from prismstereo.errors import PrismStereoError
from prismstereo.geometry.presets import load_rig
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.io import DEPTH_FILE_FORMATS
from prismstereo.jobs import BACKENDS
from prismstereo.threads import session_threads

__all__ = ["add_depth_parser", "add_export_parser"]


# the config options that have a flag of their own: errors about them name the flag
_FLAGS = {"num_hypotheses": "--hypotheses", "downsample": "--downsample", "full_band": "--full-band",
          "band_edges": "--band-edges"}


def _flag_error(exc: PrismStereoError, given: dict[str, object]) -> PrismStereoError:
    """The config's error about options set by flags (``given``), naming the flags (a flag is never None)."""
    message = str(exc)
    for option in given:
        if option in _FLAGS:
            message = re.sub(rf"\b{option}\b", _FLAGS[option], message).replace(" or None,", ",")
    return PrismStereoError(message)


def _requested_config(args: argparse.Namespace):
    """The model's :class:`~prismstereo.config.StereoConfig` as asked: ``--preset`` (default 'accurate') or
    ``--config``, with the explicit options (``--hypotheses``, ``--downsample``, ``--full-band``, ``--band-edges``,
    ``--dense``) on top; sets ``args.dense`` to the config's. The model resolves the rest
    (:func:`~prismstereo.defaults.resolve_config`)."""
    from prismstereo.config import StereoConfig, preset

    if args.preset is not None and args.config is not None:
        raise PrismStereoError("--preset and --config exclude each other")
    base = StereoConfig.from_json(args.config) if args.config is not None else preset(args.preset or "accurate")
    search = _search_flags(args)
    try:
        config = base.replace(search=search, validity={"dense": True} if args.dense else {})
    except PrismStereoError as exc:
        raise _flag_error(exc, search) from exc
    args.dense = config.validity.dense
    return config


def _request(args: argparse.Namespace, config, kind: str) -> dict[str, object]:
    """What the flags ask of the model (``config``: :func:`_requested_config`'s, parsed once; ``kind``:
    :func:`_model_kind`'s), before the rig resolves it: the key of its graph in the ONNX cache (with the rig;
    :func:`prismstereo.export.request_key`)."""
    import hashlib

    if kind == "classical":
        return {"config": config.to_dict(), "z_range_mm": args.z_range}
    weights = "default" if args.weights is None else hashlib.sha256(Path(args.weights).read_bytes()).hexdigest()
    if kind == "hybrid":
        return {"hybrid": weights, "z_range_mm": args.z_range}
    return {"learned": weights, "z_range_mm": args.z_range, "hypotheses": args.hypotheses}


def _model_kind(args: argparse.Namespace, rig: BiPrismRig) -> str:
    """Which model the flags ask for: ``--model``, else ``'classical'`` (:class:`~prismstereo.model.PrismStereo`)
    with ``--preset``, ``--config`` or a search option, ``'hybrid'`` with ``--weights``, else the rig's default
    (:func:`~prismstereo.defaults.default_model`).

    Raises:
        PrismStereoError: options of another model.
    """
    from prismstereo.defaults import default_model

    classical = [name for name, value in (("--preset", args.preset), ("--config", args.config)) if value is not None]
    # the search options' flags (--hypotheses is also the learned model's D)
    classical += [_FLAGS[k] for k in _search_flags(args) if not (k == "num_hypotheses" and args.model == "learned")]
    if args.model in ("learned", "hybrid") and classical:
        raise PrismStereoError(f"{', '.join(classical)} set the classical model's options, not --model "
                               f"{args.model}'s")
    if (args.model == "classical" or classical) and args.weights is not None:
        raise PrismStereoError("--weights is the hybrid's or the learned model's, not the classical model's")
    if args.model is not None:
        return args.model
    if classical:
        return "classical"
    return "hybrid" if args.weights is not None else default_model(rig)


def _search_flags(args: argparse.Namespace) -> dict[str, object]:
    """The search options set by flags."""
    return {k: v for k, v in (("num_hypotheses", args.hypotheses), ("downsample", args.downsample),
                              ("full_band", args.full_band), ("band_edges", args.band_edges)) if v is not None}


def _z_range(args: argparse.Namespace, rig: BiPrismRig) -> tuple[tuple[float, float], str]:
    """``--z-range`` checked against the rig, or the rig's default, with how it was chosen."""
    from prismstereo.depth import check_z_range, default_z_range

    if args.z_range is None:
        return default_z_range(rig), "default for this rig"
    return check_z_range(rig, args.z_range), "--z-range"


def _build_model(args: argparse.Namespace, rig: BiPrismRig, kind: str, config):
    """The model of ``kind`` (:func:`_model_kind`) for ``rig`` from the flags and ``config`` (the classical model's:
    :func:`_requested_config`'s, parsed once; shared by ``depth`` and ``export``), with a line describing it and its
    range."""
    z_range, how = _z_range(args, rig)
    rng = f"depth range {z_range[0]:.1f}-{z_range[1]:.1f} mm ({how})"
    weights = "default" if args.weights is None else args.weights
    if kind == "hybrid":
        from prismstereo.learned import HybridStereo

        model = HybridStereo(rig, tuple(z_range), weights=weights).eval()
        return model, f"{rng}, {model.summary()}"
    if kind == "learned":
        from prismstereo.learned import LearnedStereo

        if args.hypotheses is not None and args.hypotheses < 2:
            raise PrismStereoError(f"--hypotheses must be an int >= 2, got {args.hypotheses}")
        model = LearnedStereo(rig, tuple(z_range), num_hypotheses=args.hypotheses, weights=weights).eval()
        return model, f"{rng}, {model.summary()}"
    from prismstereo.model import PrismStereo

    try:
        model = PrismStereo(rig, z_range, config).eval()
    except PrismStereoError as exc:
        raise _flag_error(exc, _search_flags(args)) from exc
    return model, f"{rng}, {model.summary()}"


def _camera_to_world(path: str) -> torch.Tensor:
    """A (4, 4) rigid camera-to-world transform from a JSON file: a 4 x 4 list, or {"camera_to_world": ...}."""
    import json

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise PrismStereoError(f"cannot read --camera-to-world {path}: {exc}") from exc
    if isinstance(data, dict):
        data = data.get("camera_to_world")
    try:
        pose = torch.tensor(data, dtype=torch.float64)
    except (TypeError, ValueError):
        pose = None
    if pose is None or pose.shape != (4, 4) or not bool(torch.isfinite(pose).all()):
        raise PrismStereoError(f"--camera-to-world {path} must hold a finite 4 x 4 matrix")
    rot = pose[:3, :3]
    rigid = torch.allclose(rot.T @ rot, torch.eye(3, dtype=torch.float64), atol=1e-6) and abs(
        float(torch.linalg.det(rot)) - 1) < 1e-6 and pose[3].tolist() == [0.0, 0.0, 0.0, 1.0]
    if not rigid:
        raise PrismStereoError(f"--camera-to-world {path} is not a rigid transform (rotation, translation, last row "
                               "0 0 0 1)")
    return pose


def _cmd_depth(args: argparse.Namespace) -> int:
    from prismstereo.jobs import Runner, Selection, WriteOptions, plan, run

    rig = load_rig(args.rig)
    config = _requested_config(args)  # --preset / --config: fails early, and sets args.dense for the outputs
    if args.png_scale is not None and not (math.isfinite(args.png_scale) and args.png_scale > 0):
        raise PrismStereoError(f"--png-scale must be a positive number, got {args.png_scale:g}")
    for flag, value in (("--batch-size", args.batch_size), ("--workers", args.workers),
                        ("--temporal-binning", args.temporal_binning)):
        if value is not None and value < 1:
            raise PrismStereoError(f"{flag} must be >= 1, got {value}")
    if args.temporal_binning is not None and not args.temporal:
        raise PrismStereoError("--temporal-binning places the temporal prior's band: not with --no-temporal")
    if args.ray is not None and args.workers > 1:
        raise PrismStereoError("--ray and --workers exclude each other (Ray places the workers)")
    pose = _camera_to_world(args.camera_to_world) if args.camera_to_world else None
    if pose is not None and not args.ply:
        raise PrismStereoError("--camera-to-world transforms the --ply point clouds: add --ply")
    options = WriteOptions(args.format, args.ply, args.dense, args.png_scale, pose,
                           Path(args.preview_video) if args.preview_video else None, args.preview_fps)
    tasks = plan(args.images, Path(args.out), options, Selection(args.every, args.start, args.stop),
                 skip_existing=args.skip_existing)
    runnable = [t for t in tasks if t.error is None and t.first < len(t.outputs)]
    if len(tasks) == 1 and tasks[0].error is not None:
        raise PrismStereoError(tasks[0].error)  # one input: its error is the command's
    sequences = any(t.sequence for t in runnable)
    kind = _model_kind(args, rig)
    key, cached = None, None
    tracked = sequences and args.temporal
    if args.backend == "onnx":  # the graphs alone will do
        from prismstereo.export import OnnxDepth, recall, request_key

        # sequences under the temporal prior: the per-frame graph and the temporal graph of its tracker
        temporal_request = {"temporal": {"downsample": args.temporal_binning}} if tracked else {}
        key = request_key(rig, {**_request(args, config, kind), **temporal_request})
        cached = recall(key)  # (a tracked request is remembered only with its temporal graph)
    temporal, tracker = None, None
    if cached is not None:  # exported before for the same request: no torch model to build
        threads = os.cpu_count() or 1  # as jobs.Runner's sessions
        model = OnnxDepth(cached.path, threads=session_threads(threads), spinning=False)
        if tracked:
            tracker = OnnxDepth(cached.temporal, threads=session_threads(threads, temporal=True), spinning=False)
            temporal = tracker.temporal
        summary = cached.summary + (" (cached graphs)" if tracked else " (cached graph)")
    else:
        model, summary = _build_model(args, rig, kind, config)
    if tracked and cached is None:
        from prismstereo.depth.temporal import TemporalOptions, supports_temporal, temporal_downsample

        if supports_temporal(model):
            tracker = model
        elif kind == "hybrid":  # key frames by the hybrid, tracked by the classical model's band if it has one
            classical = _build_model(args, rig, "classical", config)[0]
            if supports_temporal(classical):
                tracker = classical
                summary += f"; tracked between key frames by the classical model ({tracker.summary()})"
        if tracker is not None:
            temporal = TemporalOptions(downsample=args.temporal_binning)
            k = temporal_downsample(tracker, temporal)
            binned = f" on the {k}x{k}-binned frame" if k > 1 else ""
            summary += (f", temporal prior on sequences (a band +-{temporal.band}{binned} around the previous depth "
                        "between key frames)")
        elif args.temporal_binning is not None:
            raise PrismStereoError("--temporal-binning: this model has no full-resolution band for the temporal prior")
        else:
            summary += ", every frame on its own (this model has no full-resolution band for the temporal prior)"
    outputs = sum(len(t.outputs) - t.first for t in runnable)
    workers = f", {args.workers} worker processes" if args.workers > 1 else ""
    if args.ray is not None:
        workers = f", on Ray ({args.ray})"
    print(f"{summary}, backend {args.backend}{workers}; {outputs} depth maps to write from {len(runnable)} of "
          f"{len(tasks)} inputs")
    runner = Runner(model, backend=args.backend, options=options, temporal=temporal,
                    tracker=None if tracker is model else tracker)
    result = run(tasks, runner, workers=args.workers, batch_size=args.batch_size, ray=args.ray)
    print(result.describe())
    if key is not None and cached is None:
        from prismstereo.export import cache_path, remember

        graph = cache_path(model)
        band = None if tracker is None else cache_path(tracker, temporal=temporal)
        if graph.is_file() and (not tracked or (band is not None and band.is_file())):
            remember(key, graph, summary, temporal=band)
    if len(tasks) == 1 and result.failed:
        raise PrismStereoError(result.failed[0].error)
    for failure in result.failed:
        print(f"prismstereo: failed: {failure.source}: {failure.error}", file=sys.stderr)
    return 1 if result.failed else 0


def _add_resolution_arguments(parser: argparse.ArgumentParser) -> None:
    """``--downsample``, ``--full-band``, ``--band-edges``, ``--dense``, ``--preset`` and ``--config``, shared by
    ``depth`` and ``export`` (the preset's values when absent)."""
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
    parser.add_argument("--model", choices=("hybrid", "classical", "learned"), default=None,
                        help="the depth model: hybrid (prismstereo.learned.HybridStereo: the exact sweep on 4 x 4 "
                             "bins refined by learned 2-D stages, a depth and confidence for every pixel), classical "
                             "(prismstereo.PrismStereo, its settings from --preset / --config and the options above) "
                             "or learned (prismstereo.learned.LearnedStereo; --hypotheses: its D, default: neighbours "
                             "0.69 px apart on the sweep at its 1/4 resolution). Default: classical with --preset, "
                             "--config or a search option, hybrid with --weights, else the rig's default "
                             "(prismstereo.defaults.default_model: hybrid when the reference half is >= 384 px on "
                             "its shorter side). On videos and sequences under the temporal prior the hybrid "
                             "computes the key frames and the classical model's band tracks between them")
    parser.add_argument("--weights", default=None, metavar="FILE.pt",
                        help="the hybrid's or (--model learned) the learned model's weights, written by prismstereo "
                             "train (default: the shipped ones)")
    parser.add_argument("--preset", choices=("accurate", "fast", "dense", "reference"), default=None,
                        help="the classical model's named settings (prismstereo.config.PRESETS; accurate is its "
                             "default); the options above override them")
    parser.add_argument("--config", default=None, metavar="FILE.json",
                        help="the classical model with settings from a StereoConfig JSON file (prismstereo.config); "
                             "the options above override it")
    parser.add_argument("--dense", action="store_true",
                        help="a depth for every pixel of the common field of view with its calibrated confidence "
                             "(the probability of a depth within 1 %%), not only for the valid ones; with the "
                             "classical model, from the preset's chain (--preset dense is the chain built for it: its "
                             "coarse level matched by cost-volume filtering, fewer wrong depths on weakly textured "
                             "photographs)")


def add_depth_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``prismstereo depth`` on the main parser's subcommands."""
    depth = sub.add_parser("depth", help="metric depth of the reference (left) half of bi-prism captures")
    depth.add_argument("images", metavar="IMAGE", nargs="+",
                       help="full sensor image(s): 8/16-bit grey or RGB PNG/TIFF/JPEG of the rig's size; or one "
                            "video file (.mp4, .avi, .mkv, ...), directory of images or quoted glob ('frames/*.png'),"
                            " written as OUT/<stem>_000000.<format>, ... numbered from 0 in frame order")
    depth.add_argument("--rig", required=True, help="rig JSON file or preset name")
    depth.add_argument("--out", required=True,
                       help="OUT.npy or OUT.tiff (float32 mm, NaN invalid) or OUT.png (16-bit mm x scale, 0 "
                            "invalid, plus OUT_preview.png and OUT.json with the scale) for one image; a directory "
                            "(created) of <stem>.npy/.png/.tiff otherwise")
    depth.add_argument("--z-range", type=float, nargs=2, default=None, metavar=("ZMIN", "ZMAX"),
                       help="depths searched (mm); default from the rig's common field of view "
                            "(prismstereo.depth.default_z_range)")
    depth.add_argument("--hypotheses", type=int, default=None, metavar="N",
                       help="number of depth hypotheses (default: neighbours <= 1 px apart)")
    _add_resolution_arguments(depth)
    depth.add_argument("--backend", choices=BACKENDS, default="torch", help="inference backend")
    depth.add_argument("--batch-size", type=int, default=1, metavar="B", help="images processed together")
    depth.add_argument("--workers", type=int, default=1, metavar="N",
                       help="spread the inputs (batches of images, whole videos or sequences) over N processes, each "
                            "with its share of the cores (default 1: this process, reading and writing on threads "
                            "beside the model)")
    depth.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                       help="run the inputs on Ray actors (pip install 'prismstereo[ray]'): a local instance, or the "
                            "cluster at ADDRESS ('auto', 'ray://head:10001'); a dead worker is restarted and its "
                            "inputs retried")
    depth.add_argument("--skip-existing", action="store_true",
                       help="resume a job: skip the images whose outputs exist, and continue each video or sequence "
                            "at its first missing frame (a key frame)")
    depth.add_argument("--format", choices=DEPTH_FILE_FORMATS, default=None,
                       help="output format when --out is a directory (default npy)")
    depth.add_argument("--png-scale", type=float, default=None, metavar="S",
                       help="16-bit PNG levels per mm (default: 256, the endoscopy convention, where every depth "
                            "is <= 255.996 mm, else the largest power of two that fits; stored in the PNG)")
    depth.add_argument("--every", type=int, default=1, metavar="N", help="video / sequence: every N-th frame")
    depth.add_argument("--start", type=int, default=0, metavar="I", help="video / sequence: first frame (0-based)")
    depth.add_argument("--stop", type=int, default=None, metavar="J", help="video / sequence: end frame (exclusive)")
    depth.add_argument("--preview-video", default=None, metavar="OUT.mp4",
                       help="video / sequence: also write the colour-mapped depth as a video (mp4v)")
    depth.add_argument("--preview-fps", type=float, default=10.0, help="frame rate of --preview-video")
    depth.add_argument("--no-temporal", dest="temporal", action="store_false",
                       help="video / sequence: every frame on its own (default: the temporal prior, a narrow band "
                            "around the previous frame's depth between key frames; prismstereo.depth.temporal)")
    depth.add_argument("--temporal-binning", type=int, default=None, metavar="K",
                       help="video / sequence: the temporal prior's band on the K x K-binned frame (default: 2 for a "
                            "pyramid, 1 for a one-level model; a coarser binning tracks faster and less accurately: "
                            "docs/benchmarks.md, Video)")
    depth.add_argument("--ply", action="store_true",
                       help="also write <stem>.ply point clouds (camera frame, mm, coloured by the reference half, "
                            "with each point's confidence as a 'confidence' property)")
    depth.add_argument("--camera-to-world", default=None, metavar="POSE.json",
                       help="write the --ply points in a world frame: a JSON 4 x 4 rigid transform (a list, or "
                            "{\"camera_to_world\": [[...], ...]}) from the camera frame")
    depth.set_defaults(func=_cmd_depth)


def _cmd_export(args: argparse.Namespace) -> int:
    import shutil

    from prismstereo.export import DEFAULT_OPSET, OnnxDepth, describe, export_onnx, recall, request_key
    from prismstereo.io import replacing

    out = Path(args.out)
    if out.suffix.lower() != ".onnx":
        raise PrismStereoError(f"--out must end in .onnx, got {out}")
    rig = load_rig(args.rig)
    config = _requested_config(args)  # --preset / --config: checked as for depth
    kind = _model_kind(args, rig)
    cached = None  # the graph `prismstereo depth --backend onnx` exported for the same request (grey, default opset)
    if args.channels == 1 and args.opset == DEFAULT_OPSET:
        cached = recall(request_key(rig, _request(args, config, kind)))
    t0 = time.perf_counter()
    if cached is not None:  # no torch model to build: the cached file, copied whole
        print(f"{cached.summary} (cached graph)")
        with replacing(out) as partial:
            shutil.copyfile(cached.path, partial)
        how = f"copied from the cache in {time.perf_counter() - t0:.1f} s"
    else:
        model, summary = _build_model(args, rig, kind, config)
        print(summary)
        t0 = time.perf_counter()
        export_onnx(model, out, channels=args.channels, opset=args.opset)
        how = f"exported in {time.perf_counter() - t0:.1f} s"
    runner = OnnxDepth(out)  # proves the file loads in onnxruntime with all graph optimisations
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, {how}, onnxruntime load {runner.load_seconds:.1f} s): "
          f"{describe(runner.metadata)}")
    return 0


def add_export_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``prismstereo export`` on the main parser's subcommands."""
    from prismstereo.export import DEFAULT_OPSET

    export = sub.add_parser("export", help="export the depth model of a rig to ONNX (for onnxruntime)")
    export.add_argument("--rig", required=True, help="rig JSON file or preset name")
    export.add_argument("--out", required=True, help="the .onnx file to write")
    export.add_argument("--z-range", type=float, nargs=2, default=None, metavar=("ZMIN", "ZMAX"),
                        help="depths searched (mm); default as for `prismstereo depth`")
    export.add_argument("--hypotheses", type=int, default=None, metavar="N",
                        help="number of depth hypotheses (default: neighbours <= 1 px apart)")
    _add_resolution_arguments(export)
    export.add_argument("--opset", type=int, default=DEFAULT_OPSET, metavar="K",
                        help=f"ONNX opset (16-20, default {DEFAULT_OPSET})")
    export.add_argument("--channels", type=int, choices=(1, 3), default=1,
                        help="input channels of the graph (default 1: grey, as `prismstereo depth` feeds it)")
    export.set_defaults(func=_cmd_export)
