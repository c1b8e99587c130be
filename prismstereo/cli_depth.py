"""The ``prismstereo depth`` and ``prismstereo export`` subcommands: depth maps (and point clouds) of bi-prism
captures, and the ONNX export of the same depth model.

Parses nothing itself beyond its own arguments and only calls the library: reading and size-checking the
images, building :class:`~prismstereo.model.PrismStereo` once, running it in batches on the chosen backend
and writing .npy / 16-bit .png (+ preview) / .ply outputs without ever overwriting an input.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from prismstereo.errors import PrismStereoError
from prismstereo.geometry.presets import load_rig
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.io import DEPTH_SUFFIXES

__all__ = ["add_depth_parser", "add_export_parser"]

DEPTH_FORMATS = ("npy", "png", "tiff")
BACKENDS = ("torch", "onnx")


class _DepthTarget(NamedTuple):
    """Where one image's results go: the depth file, its preview and scale sidecar (png format), its point cloud
    (--ply) and its confidence (--dense)."""

    depth: Path
    preview: Path | None
    ply: Path | None
    confidence: Path | None = None
    sidecar: Path | None = None


def _target(folder: Path, stem: str, path: Path, ply: bool, dense: bool) -> _DepthTarget:
    """The outputs of one image or frame: ``path`` and its companions ``folder/<stem>_...``."""
    png = path.suffix.lower() == ".png"
    return _DepthTarget(path, folder / f"{stem}_preview.png" if png else None,
                        folder / f"{stem}.ply" if ply else None, folder / f"{stem}_confidence.npy" if dense else None,
                        path.with_suffix(".json") if png else None)


def _depth_targets(images: list[Path], out: Path, fmt: str | None, ply: bool,
                   dense: bool = False) -> list[_DepthTarget]:
    """Output paths of ``prismstereo depth`` (OUT a .npy/.png/.tiff file for one image, else a directory),
    checked so that no two outputs collide and no output overwrites an input image."""
    suffix = out.suffix.lower()
    if suffix in DEPTH_SUFFIXES and not out.is_dir():
        if len(images) > 1:
            raise PrismStereoError(f"{len(images)} images: --out must be a directory, got {out}")
        if fmt is not None and fmt != DEPTH_SUFFIXES[suffix]:
            raise PrismStereoError(f"--format {fmt} contradicts --out {out}")
        fmt, stems = DEPTH_SUFFIXES[suffix], [(out.parent, out.stem, out)]
    else:
        if out.exists() and not out.is_dir():
            raise PrismStereoError(f"--out {out} exists and is not a directory")
        if suffix and not out.is_dir():
            raise PrismStereoError(f"--out must end in .npy, .png or .tiff (one image) or be a directory, got {out}")
        fmt = fmt or "npy"
        stems = [(out, image.stem, out / f"{image.stem}.{fmt}") for image in images]
    targets = [_target(folder, stem, path, ply, dense) for folder, stem, path in stems]
    inputs = {image.resolve(): image for image in images}
    written: dict[Path, Path] = {}
    for image, target in zip(images, targets, strict=True):
        for path in target:
            if path is None:
                continue
            if path.resolve() in inputs:
                raise PrismStereoError(f"--out would overwrite the input image {inputs[path.resolve()]}")
            if path.resolve() in written:
                raise PrismStereoError(f"{written[path.resolve()]} and {image} would both write {path}")
            written[path.resolve()] = image
    return targets


def _run_backend(name: str, model, batch: torch.Tensor):
    """Depth of a (B, C, H, W) batch by backend ``name``: ``torch`` runs the model, ``onnx`` its exported graph
    in onnxruntime (exported once per rig and options into the cache, :func:`prismstereo.export.onnx_session`).
    Returns an object with ``depth`` and ``valid`` (B, 1, H, W_ref)."""
    if name == "torch":
        with torch.inference_mode():
            return model(batch)
    if name == "onnx":
        from prismstereo.export import onnx_session

        return onnx_session(model, channels=batch.shape[1])(batch)
    raise PrismStereoError(f"unknown backend {name!r}. Choose from: {', '.join(BACKENDS)}")


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


def _learned_model(args: argparse.Namespace, rig: BiPrismRig):
    """The :class:`~prismstereo.learned.LearnedStereo` of ``--learned`` (shipped weights) or ``--weights FILE``."""
    from prismstereo.learned import LearnedStereo

    classical = [name for name, value in (("--preset", args.preset), ("--config", args.config),
                                          ("--downsample", args.downsample), ("--full-band", args.full_band),
                                          ("--band-edges", args.band_edges)) if value is not None]
    if classical:
        raise PrismStereoError(f"{', '.join(classical)} set the classical model's options, not --learned's")
    if args.hypotheses is not None and args.hypotheses < 2:
        raise PrismStereoError(f"--hypotheses must be an int >= 2, got {args.hypotheses}")
    z_range, how = _z_range(args, rig)
    weights = "default" if args.weights is None else args.weights
    model = LearnedStereo(rig, tuple(z_range), num_hypotheses=args.hypotheses or 48, weights=weights).eval()
    return model, f"depth range {z_range[0]:.1f}-{z_range[1]:.1f} mm ({how}), {model.summary()}"


def _build_model(args: argparse.Namespace, rig: BiPrismRig):
    """The PrismStereo of ``--z-range`` and the config (:func:`_requested_config`; shared by ``depth`` and
    ``export``), with a line describing its range."""
    from prismstereo.model import PrismStereo

    if args.learned or args.weights is not None:
        return _learned_model(args, rig)
    config = _requested_config(args)
    z_range, how = _z_range(args, rig)
    try:
        model = PrismStereo(rig, z_range, config).eval()
    except PrismStereoError as exc:
        raise _flag_error(exc, _search_flags(args)) from exc
    return model, f"depth range {z_range[0]:.1f}-{z_range[1]:.1f} mm ({how}), {model.summary()}"


def _read_capture(path: Path, rig: BiPrismRig) -> torch.Tensor:
    """A full sensor image (C, H, W) in [0, 1], checked against the rig's sensor size."""
    from prismstereo.io import read_image

    image = read_image(path)
    h, w = image.shape[-2:]
    if (w, h) != (rig.image_width, rig.image_height):
        raise PrismStereoError(f"image {path} is {w}x{h} px but the rig's sensor is "
                               f"{rig.image_width}x{rig.image_height} px")
    return image


def _write_depth(target: _DepthTarget, depth: torch.Tensor, valid: torch.Tensor, png_scale: float | None) -> str:
    """Write one depth map (H, W_ref) to its target; returns a note for the summary line."""
    from prismstereo.io import write_depth, write_depth_preview

    written = write_depth(target.depth, depth, valid, png_scale=png_scale)
    if written.format != "png":
        return ""
    write_depth_preview(target.preview, depth, valid)
    note = f", preview {target.preview.name}, {written.scale:g} levels/mm (stored in the PNG and {target.sidecar.name})"
    if written.clipped:
        note += (f"; warning: {written.clipped} pixels deeper than {65535 / written.scale:.3f} mm clipped to 65535"
                 " (see --png-scale)")
    return note


def _write_outputs(target: _DepthTarget, depth: torch.Tensor, valid: torch.Tensor, confidence: torch.Tensor,
                   png_scale: float | None, points: torch.Tensor | None, colors: torch.Tensor,
                   pose: torch.Tensor | None) -> str:
    """Write one result's depth (:func:`_write_depth`), confidence (--dense) and point cloud (--ply: ``points``
    (3, H, W_ref)); returns the note for the summary line."""
    from prismstereo.depth import write_ply

    note = _write_depth(target, depth, valid, png_scale)
    if target.confidence is not None:
        np.save(target.confidence, confidence.numpy().astype(np.float32))
        note += f", confidence {target.confidence.name}"
    if target.ply is not None and points is not None:
        count = write_ply(target.ply, points, colors=colors, confidence=confidence, camera_to_world=pose)
        note += f", {target.ply.name} ({count} points)"
    return note


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
    import kornia
    from tqdm import tqdm

    from prismstereo.depth import depth_to_points

    rig = load_rig(args.rig)
    _requested_config(args)  # --preset / --config: fails early, and sets args.dense for the outputs
    if args.png_scale is not None and not (math.isfinite(args.png_scale) and args.png_scale > 0):
        raise PrismStereoError(f"--png-scale must be a positive number, got {args.png_scale:g}")
    pose = _camera_to_world(args.camera_to_world) if args.camera_to_world else None
    if pose is not None and not args.ply:
        raise PrismStereoError("--camera-to-world transforms the --ply point clouds: add --ply")
    from prismstereo.video import is_sequence_source

    if len(args.images) == 1 and is_sequence_source(args.images[0]):
        return _cmd_depth_sequence(args, rig, pose)
    if args.preview_video or args.every != 1 or args.start != 0 or args.stop is not None:
        raise PrismStereoError("--every, --start, --stop and --preview-video need a video, a directory or a glob "
                               "of images")
    images = [Path(p) for p in args.images]
    targets = _depth_targets(images, Path(args.out), args.format, args.ply, args.dense)
    if args.batch_size < 1:
        raise PrismStereoError(f"--batch-size must be >= 1, got {args.batch_size}")
    for image in images:  # fail early, before any work or output, on an unreadable or wrong-sized image
        _read_capture(image, rig)
    model, summary = _build_model(args, rig)
    print(f"{summary}, backend {args.backend}")
    w_ref = rig.reference_width
    with tqdm(total=len(images), unit="image", file=sys.stderr, desc="depth") as bar:
        for start in range(0, len(images), args.batch_size):
            chunk = list(range(start, min(start + args.batch_size, len(images))))
            captures = [_read_capture(images[i], rig) for i in chunk]
            grey = torch.stack([c if c.shape[0] == 1 else kornia.color.rgb_to_grayscale(c) for c in captures])
            res = _run_backend(args.backend, model, grey)
            written = (res.confidence > 0) if args.dense else res.valid  # dense: every pixel with a depth
            if args.ply:
                with torch.inference_mode():
                    points = depth_to_points(rig, res.depth.to(torch.float64), written)
            for k, i in enumerate(chunk):
                depth, valid = res.depth[k, 0], written[k, 0]
                note = _write_outputs(targets[i], depth, valid, res.confidence[k, 0], args.png_scale,
                                      points[k] if args.ply else None, captures[k][:, :, :w_ref], pose)
                ok = valid & torch.isfinite(depth)
                median = f"median {float(depth[ok].median()):.1f} mm" if bool(ok.any()) else "no valid depth"
                kind = "with a depth (dense)" if args.dense else "valid"
                tqdm.write(f"wrote {targets[i].depth}: {ok.float().mean():.1%} of reference pixels {kind}, "
                           f"{median}{note}", file=sys.stdout)
                bar.update(1)
    return 0


def _cmd_depth_sequence(args: argparse.Namespace, rig: BiPrismRig, pose: torch.Tensor | None) -> int:
    """``prismstereo depth`` on a video, a directory or a glob: one depth file per selected frame,
    ``OUT/<stem>_000000.<format>`` numbered from 0 in frame order, through a :class:`~prismstereo.stream.DepthStream`
    of the chosen backend, and optionally a colour-mapped depth video."""
    import cv2
    from tqdm import tqdm

    from prismstereo.depth import depth_to_points
    from prismstereo.io import depth_preview
    from prismstereo.stream import DepthStream
    from prismstereo.video import (
        check_selection,
        is_video_file,
        read_frames,
        sequence_files,
        sequence_length,
        sequence_name,
    )

    source, out = args.images[0], Path(args.out)
    if out.suffix.lower() in DEPTH_SUFFIXES or (out.exists() and not out.is_dir()):
        raise PrismStereoError(f"a video or sequence writes one file per frame: --out must be a directory, got {out}")
    fmt = args.format or "npy"
    check_selection(args.every, args.start, args.stop)
    total = sequence_length(source)  # fails early on a missing or unreadable source
    stop = total if args.stop is None else min(args.stop, total)
    count = max(0, -(-(stop - args.start) // args.every))
    if count == 0:
        raise PrismStereoError(f"--start {args.start} selects no frame: {source} has {total} frames")
    inputs = set()
    if not is_video_file(source):
        inputs = {p.resolve() for p in sequence_files(source)}
    stem = sequence_name(source)
    model, summary = _build_model(args, rig)
    from prismstereo.depth.temporal import TemporalOptions, supports_temporal, temporal_downsample

    temporal = None
    if args.temporal and supports_temporal(model):
        temporal = TemporalOptions()
        k = temporal_downsample(model, temporal)
        binned = f" on the {k}x{k}-binned frame" if k > 1 else ""
        summary += (f", temporal prior (a band +-{temporal.band}{binned} around the previous depth between key "
                    "frames)")
    elif args.temporal:
        summary += ", every frame on its own (this model has no full-resolution band for the temporal prior)"
    if args.backend == "onnx":
        from prismstereo.export import onnx_session

        tracker = None if temporal is None else onnx_session(model, channels=1, temporal=temporal)
        stream = DepthStream(onnx_session(model, channels=1), temporal_graph=tracker)
    else:
        stream = DepthStream(model, temporal=temporal or False)
    print(f"{summary}, backend {args.backend}, {count} of {total} frames of {source}")
    writer = None
    try:
        with tqdm(total=count, unit="frame", file=sys.stderr, desc="depth") as bar:
            for k, frame in enumerate(read_frames(source, every=args.every, start=args.start, stop=args.stop)):
                name = f"{stem}_{k:06d}"
                path = out / f"{name}.{fmt}"
                target = _target(out, name, path, args.ply, args.dense)
                if any(p is not None and p.resolve() in inputs for p in target):
                    raise PrismStereoError(f"{path} would overwrite an input frame")
                res = stream.push(frame.image)
                written = (res.confidence > 0) if args.dense else res.valid
                depth, valid = res.depth[0, 0], written[0, 0]
                out.mkdir(parents=True, exist_ok=True)
                points = None
                if args.ply:
                    with torch.inference_mode():
                        points = depth_to_points(rig, res.depth.to(torch.float64), written)[0]
                _write_outputs(target, depth, valid, res.confidence[0, 0], args.png_scale, points,
                               frame.image[:, :, : rig.reference_width], pose)
                if args.preview_video:
                    picture = depth_preview(depth, valid, limits_mm=tuple(model.z_range))
                    if writer is None:
                        Path(args.preview_video).parent.mkdir(parents=True, exist_ok=True)
                        writer = cv2.VideoWriter(str(args.preview_video), cv2.VideoWriter_fourcc(*"mp4v"),
                                                 args.preview_fps, (picture.shape[1], picture.shape[0]))
                        if not writer.isOpened():
                            raise PrismStereoError(f"OpenCV cannot write the video {args.preview_video}")
                    writer.write(picture)
                bar.set_postfix(ms=f"{res.milliseconds:.0f}")
                bar.update(1)
    finally:
        if writer is not None:
            writer.release()
    times = sorted(stream.times_ms)
    median = times[len(times) // 2] if times else float("nan")
    keys = f", {stream.keyframes} key frames" if stream.temporal is not None else ""
    print(f"wrote {stream.frames} depth files {stem}_000000.{fmt} ... to {out}: {median:.1f} ms per frame "
          f"(median of the depth computation), {stream.frames_per_second():.1f} frames/s{keys}"
          + (f"; preview video {args.preview_video}" if args.preview_video else ""))
    return 0


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
    parser.add_argument("--learned", action="store_true",
                        help="the learned model (prismstereo.learned.LearnedStereo) with its shipped weights "
                             "instead of the classical one (--hypotheses: its D, default 48)")
    parser.add_argument("--weights", default=None, metavar="FILE.pt",
                        help="the learned model with these weights (written by prismstereo train); implies --learned")
    parser.add_argument("--preset", choices=("accurate", "fast", "dense", "reference"), default=None,
                        help="named model settings (prismstereo.config.PRESETS; default accurate); the options "
                             "above override it")
    parser.add_argument("--config", default=None, metavar="FILE.json",
                        help="model settings from a StereoConfig JSON file (prismstereo.config); the options above "
                             "override it")
    parser.add_argument("--dense", action="store_true",
                        help="a depth for every pixel of the common field of view with its calibrated confidence "
                             "(the probability of a depth within 1 %%), not only for the valid ones, from the "
                             "preset's chain; --preset dense is the chain built for it (its coarse level matched by "
                             "cost-volume filtering: fewer wrong depths on weakly textured photographs)")


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
    depth.add_argument("--format", choices=DEPTH_FORMATS, default=None,
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
    depth.add_argument("--ply", action="store_true",
                       help="also write <stem>.ply point clouds (camera frame, mm, coloured by the reference half, "
                            "with each point's confidence as a 'confidence' property)")
    depth.add_argument("--camera-to-world", default=None, metavar="POSE.json",
                       help="write the --ply points in a world frame: a JSON 4 x 4 rigid transform (a list, or "
                            "{\"camera_to_world\": [[...], ...]}) from the camera frame")
    depth.set_defaults(func=_cmd_depth)


def _cmd_export(args: argparse.Namespace) -> int:
    from prismstereo.export import OnnxDepth, describe, export_onnx

    out = Path(args.out)
    if out.suffix.lower() != ".onnx":
        raise PrismStereoError(f"--out must end in .onnx, got {out}")
    rig = load_rig(args.rig)
    model, summary = _build_model(args, rig)
    print(summary)
    t0 = time.perf_counter()
    export_onnx(model, out, channels=args.channels, opset=args.opset)
    seconds = time.perf_counter() - t0
    runner = OnnxDepth(out)  # proves the file loads in onnxruntime with all graph optimisations
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, exported in {seconds:.1f} s, onnxruntime load "
          f"{runner.load_seconds:.1f} s): {describe(runner.metadata)}")
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
