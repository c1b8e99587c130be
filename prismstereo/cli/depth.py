"""``prismstereo depth``: depth maps (and point clouds) of bi-prism captures, image sequences and videos.

It parses its own arguments and only calls the library: the model the flags ask for
(:func:`~prismstereo.cli.model_flags.model_spec`) in a :class:`~prismstereo.predictor.Predictor` (torch, or its
graphs from the ONNX cache without building the model when the same request was exported before), the job's
outputs checked before any work (:func:`~prismstereo.jobs.plan`, its errors named by the flags) and the pipelined
run over captures, sequences and videos (:func:`~prismstereo.jobs.run`) on the executor the flags choose.

With ``--backend onnx`` the same flags again (the cache's index remembers them:
:func:`~prismstereo.cli.model_flags.request_flags`) run the remembered graphs through a
:class:`~prismstereo.export.graphs.GraphPredictor` without importing torch, unless the job needs it (``--ply``,
``--ray``); so do deployed graph files (``--graph``, ``--temporal-graph``), which carry their rig and range.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from prismstereo.cli.model_flags import add_model_arguments, flag_errors, model_spec, range_note, request_flags
from prismstereo.errors import PrismStereoError
from prismstereo.names import BACKENDS, DEPTH_FILE_FORMATS

if TYPE_CHECKING:  # imported by the command as it runs: its parser and --help need no torch
    import torch


__all__ = ["add_parser"]

# the plan's arguments by their flags (its errors name its arguments: prismstereo.jobs.PlanError)
PLAN_FLAGS = {"out": "--out", "format": "--format", "every": "--every", "start": "--start", "stop": "--stop",
              "preview_video": "--preview-video", "skip_existing": "--skip-existing"}


def _camera_to_world(path: str) -> torch.Tensor:
    """A (4, 4) rigid camera-to-world transform from a JSON file: a 4 x 4 list, or {"camera_to_world": ...}."""
    import json

    import torch

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


def _check_numbers(args: argparse.Namespace) -> None:
    """The flags' own checks of numbers and combinations, before anything is read or built."""
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
    if args.camera_to_world and not args.ply:
        raise PrismStereoError("--camera-to-world transforms the --ply point clouds: add --ply")


def _check_flags(args: argparse.Namespace) -> torch.Tensor | None:
    """The flags' own checks, before anything is read or built; returns the ``--camera-to-world`` pose."""
    _check_numbers(args)
    return _camera_to_world(args.camera_to_world) if args.camera_to_world else None


def _failed(source: str, error: str) -> None:
    print(f"prismstereo: failed: {source}: {error}", file=sys.stderr)


def _plan(args: argparse.Namespace, pose: torch.Tensor | None, dense: bool):
    """The job's tasks and write options (:func:`~prismstereo.jobs.plan`, its errors naming the flags)."""
    from prismstereo.jobs import Selection, WriteOptions, plan

    options = WriteOptions(args.format, args.ply, dense, args.png_scale, pose,
                           Path(args.preview_video) if args.preview_video else None, args.preview_fps, args.preview)
    tasks = plan(args.images, Path(args.out), options, Selection(args.every, args.start, args.stop),
                 skip_existing=args.skip_existing, names=PLAN_FLAGS)
    return tasks, options


def _checked(tasks: list, size: tuple[int, int]) -> list:
    """The tasks with every input's first image read (:func:`~prismstereo.jobs.check_inputs`) for a sensor of
    ``size`` (H, W): a bad input fails before the model is built; one bad input, or all, end the command."""
    from prismstereo.jobs import check_inputs

    tasks = check_inputs(tasks, size)
    if len(tasks) == 1 and tasks[0].error is not None:
        raise PrismStereoError(tasks[0].error)  # one input: its error is the command's
    if all(t.error is not None for t in tasks):
        for task in tasks:
            _failed(task.source, task.error)
        raise PrismStereoError(f"none of the {len(tasks)} inputs can be processed")
    return tasks


def _runnable(tasks: list) -> list:
    """The tasks with outputs left to write and no input error."""
    return [t for t in tasks if t.error is None and t.first < len(t.outputs)]


def _tracked(args: argparse.Namespace, tasks: list) -> bool:
    """Whether the job tracks sequences with the temporal prior."""
    return args.temporal and any(t.sequence for t in _runnable(tasks))


def _executor(args: argparse.Namespace):
    """Where the job runs: Ray actors (``--ray``), worker processes (``--workers``) or this process."""
    from prismstereo.jobs import InProcess, WorkerProcesses

    if args.ray is not None:
        from prismstereo.jobs.ray_executor import RayCluster

        cluster = RayCluster(args.ray)
        cluster.check()  # before the model is built
        return cluster, f", on Ray ({args.ray})"
    if args.workers > 1:
        return WorkerProcesses(args.workers), f", {args.workers} worker processes"
    return InProcess(), ""


def _remembered(args: argparse.Namespace):
    """The job on the graphs the cache's index remembers for these flags, without torch
    (:class:`~prismstereo.export.graphs.GraphPredictor`): (tasks, options, predictor), or None when the flags were
    not served before (or their sequences would now be tracked otherwise)."""
    from prismstereo.export.graphs import GraphPredictor
    from prismstereo.export.index import flags_key, recall

    tasks, options = _plan(args, None, args.dense)
    tracked = args.temporal and any(t.sequence for t in tasks if t.first < len(t.outputs))
    files = recall(flags_key(request_flags(args, tracked=tracked)))
    if files is None:
        return None
    predictor = GraphPredictor(files, spinning=False)
    if predictor.dense != options.dense:
        tasks, options = _plan(args, None, predictor.dense)
    tasks = _checked(tasks, predictor.image_size)
    return None if _tracked(args, tasks) != tracked else (tasks, options, predictor)


# the flags that choose the model to build: a deployed graph is one already built
MODEL_FLAGS = {"rig": "--rig", "z_range": "--z-range", "hypotheses": "--hypotheses", "downsample": "--downsample",
               "full_band": "--full-band", "band_edges": "--band-edges", "model": "--model",
               "last_stage": "--last-stage", "weights": "--weights", "preset": "--preset", "config": "--config"}


def _deployed(args: argparse.Namespace):
    """The job on deployed graph files (``--graph``, ``--temporal-graph``), without torch: (tasks, options,
    predictor)."""
    from prismstereo.export.graphs import GraphPredictor

    given = [flag for name, flag in MODEL_FLAGS.items() if getattr(args, name) not in (None, False)]
    if args.dense:
        given.append("--dense")
    if given:
        raise PrismStereoError(f"{', '.join(given)} choose a model to build: --graph runs one built already (its "
                               "rig, range and options are in the file)")
    if args.backend == "torch":
        raise PrismStereoError("--graph runs in onnxruntime: not with --backend torch")
    if args.ply or args.ray is not None:
        raise PrismStereoError("--graph runs without torch: --ply and --ray need it (export the model's request "
                               "instead, or pass --rig and the model flags)")
    if args.temporal_binning is not None:
        raise PrismStereoError("--temporal-binning places the band of a model to build: a temporal graph's band was "
                               "placed when it was exported")
    predictor = GraphPredictor(Path(args.graph), None if args.temporal_graph is None else Path(args.temporal_graph),
                               spinning=False)
    tasks, options = _plan(args, None, predictor.dense)
    return _checked(tasks, predictor.image_size), options, predictor


def _cmd_depth(args: argparse.Namespace) -> int:
    _check_numbers(args)
    if args.temporal_graph is not None and args.graph is None:
        raise PrismStereoError("--temporal-graph goes with --graph")
    if args.graph is not None:
        tasks, options, predictor = _deployed(args)
        tracked = _tracked(args, tasks) and predictor.temporal is not None
        return _run(args, tasks, options, predictor, *_executor(args), tracked=tracked)
    if args.rig is None:
        raise PrismStereoError("the following arguments are required: --rig (or --graph)")
    args.backend = args.backend or "torch"
    if args.backend == "onnx" and not args.ply and args.ray is None:
        job = _remembered(args)
        if job is not None:
            return _run(args, *job, *_executor(args), tracked=_tracked(args, job[0]))
    from prismstereo.classical import TemporalOptions
    from prismstereo.export.index import flags_key, remember
    from prismstereo.geometry.presets import load_rig
    from prismstereo.predictor import Predictor

    rig = load_rig(args.rig)
    given = argparse.Namespace(**vars(args))  # the flags as given (model_spec sets dense)
    spec = model_spec(args, rig)  # the model's flags fail early, and set args.dense for the outputs
    pose = _check_flags(args)
    tasks, options = _plan(args, pose, args.dense)
    tasks = _checked(tasks, (rig.image_height, rig.image_width))
    tracked = _tracked(args, tasks)
    temporal = TemporalOptions(downsample=args.temporal_binning) if tracked else None
    executor, where = _executor(args)
    with flag_errors(args):
        predictor = Predictor(spec, backend=args.backend, temporal=temporal, spinning=False)
    if tracked and predictor.temporal is None and args.temporal_binning is not None:
        raise PrismStereoError("--temporal-binning: this model has no full-resolution band for the temporal prior")
    if predictor.files is not None:  # the same flags again run these graphs without torch
        files = predictor.files
        remember(flags_key(request_flags(given, tracked=tracked)), files.path, files.summary, temporal=files.temporal)
    return _run(args, tasks, options, predictor, executor, where, tracked=tracked)


def _run(args: argparse.Namespace, tasks: list, options, predictor, executor, where: str, *, tracked: bool) -> int:
    """Run the job: its first line, the pipelined run, its summary and failures; the exit status."""
    from prismstereo.jobs import Pipeline, run

    runnable = _runnable(tasks)
    cached = (" (cached graphs)" if tracked else " (cached graph)") if predictor.cached else ""
    torch_free = "" if sys.modules.get("torch") is not None else " (without torch)"
    outputs = sum(len(t.outputs) - t.first for t in runnable)
    z0, z1 = predictor.z_range
    head = (f"depth range {z0:.1f}-{z1:.1f} mm (the graph's), {Path(args.graph).name}: {predictor.summary}"
            if args.graph is not None else f"{range_note(args, predictor.z_range)}, {predictor.summary}{cached}")
    print(f"{head}, backend {args.backend or 'onnx'}{torch_free}{where}; {outputs} depth maps to write from "
          f"{len(runnable)} of {len(tasks)} inputs")
    try:
        result = run(tasks, Pipeline(predictor, options=options), executor=executor, batch_size=args.batch_size)
    except KeyboardInterrupt as exc:  # the same kind (Ctrl-C or SIGTERM), saying what is on disk
        written = sum(o.exist() for t in runnable for o in t.outputs[t.first:])
        raise type(exc)(f"{written} of {outputs} depth maps written; rerun with --skip-existing to resume") from None
    print(result.describe())
    if len(tasks) == 1 and result.failed:
        raise PrismStereoError(result.failed[0].error)
    for failure in result.failed:
        _failed(failure.source, failure.error)
    return 1 if result.failed else 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``prismstereo depth`` on the main parser's subcommands."""
    depth = sub.add_parser("depth", help="metric depth of the reference (left) half of bi-prism captures")
    depth.add_argument("images", metavar="IMAGE", nargs="+",
                       help="full sensor image(s): 8/16-bit grey or RGB PNG/TIFF/JPEG of the rig's size; or one "
                            "video file (.mp4, .avi, .mkv, ...), directory of images or quoted glob ('frames/*.png'),"
                            " written as OUT/<image stem>.<format> (a video's frames as OUT/<stem>_000000.<format>, "
                            "... numbered from 0)")
    depth.add_argument("--rig", default=None, help="rig JSON file or preset name (required unless --graph)")
    depth.add_argument("--out", required=True,
                       help="OUT.npy or OUT.tiff (float32 mm, NaN invalid) or OUT.png (16-bit mm x scale, 0 "
                            "invalid, plus OUT.json with the scale) for one image, with OUT_preview.png; a directory "
                            "(created) of <stem>.npy/.png/.tiff otherwise")
    add_model_arguments(depth)
    depth.add_argument("--graph", default=None, metavar="FILE.onnx",
                       help="run a deployed graph (prismstereo export, or export_onnx) instead of building a model: "
                            "its rig, range and options are in the file; runs in onnxruntime without torch")
    depth.add_argument("--temporal-graph", default=None, metavar="FILE.onnx",
                       help="with --graph: the temporal band's graph of the same model (export_onnx(..., "
                            "temporal=TemporalOptions())), tracking videos and sequences between key frames")
    depth.add_argument("--backend", choices=BACKENDS, default=None,
                       help="inference backend: the model in torch (default), or its graphs in onnxruntime "
                            "(exported once into the cache, prismstereo.export.cached_graphs: the same request again "
                            "runs without building the model or importing torch)")
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
    depth.add_argument("--no-preview", dest="preview", action="store_false",
                       help="no <stem>_preview.png (the colour-mapped depth with its colour bar in mm) beside each "
                            "capture's depth file and each frame's 16-bit PNG")
    depth.add_argument("--no-temporal", dest="temporal", action="store_false",
                       help="video / sequence: every frame on its own (default: the temporal prior, a narrow band "
                            "around the previous frame's depth between key frames; prismstereo.classical.temporal)")
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
