"""The outputs of a depth job, named and checked before any work: one :class:`Task` per capture or sequence."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import torch

from prismstereo.errors import PrismStereoError
from prismstereo.io import DEPTH_SUFFIXES

__all__ = ["Outputs", "WriteOptions", "Selection", "Task", "plan"]


class Outputs(NamedTuple):
    """The files of one capture or frame: the depth map, the preview and scale sidecar of a PNG, the point cloud
    (``ply``) and the confidence (``dense``); None where not written."""

    depth: Path
    preview: Path | None = None
    ply: Path | None = None
    confidence: Path | None = None
    sidecar: Path | None = None

    def exist(self) -> bool:
        """Whether every file is there (what ``skip_existing`` skips)."""
        return all(p.is_file() for p in self if p is not None)


class WriteOptions(NamedTuple):
    """How results are written: ``format`` 'npy' | 'png' | 'tiff' (None: from a file ``out``'s suffix, else npy),
    ``ply`` point clouds (in the world frame of ``camera_to_world`` (4, 4), if given), ``dense`` (every pixel with
    a depth, and its confidence), ``png_scale`` (levels per mm; None: automatic), and for a single sequence a
    colour-mapped ``preview_video`` at ``preview_fps``."""

    format: str | None = None
    ply: bool = False
    dense: bool = False
    png_scale: float | None = None
    camera_to_world: torch.Tensor | None = None
    preview_video: Path | None = None
    preview_fps: float = 10.0


class Selection(NamedTuple):
    """The frames of a sequence: every ``every``-th from ``start`` to ``stop`` (exclusive; None: the end)."""

    every: int = 1
    start: int = 0
    stop: int | None = None


class Task(NamedTuple):
    """One input and its outputs.

    Attributes:
        source: the capture, video, directory or glob as given.
        sequence: whether it is a sequence (frames in order through one :class:`~prismstereo.stream.DepthStream`).
        outputs: one :class:`Outputs` per capture (one) or selected frame (numbered from 0).
        first: the first output still to write (``len(outputs)``: nothing left, skipped); a sequence resumes at
            frame ``start + first * every``.
        selection: a sequence's frames.
        error: why the input cannot be processed (found while planning), else None.
    """

    source: str
    sequence: bool
    outputs: tuple[Outputs, ...]
    first: int = 0
    selection: Selection = Selection()
    error: str | None = None

def _outputs(folder: Path, stem: str, path: Path, options: WriteOptions) -> Outputs:
    png = path.suffix.lower() == ".png"
    return Outputs(path, folder / f"{stem}_preview.png" if png else None,
                   folder / f"{stem}.ply" if options.ply else None,
                   folder / f"{stem}_confidence.npy" if options.dense else None,
                   path.with_suffix(".json") if png else None)


def plan(inputs: Sequence[str | Path], out: Path, options: WriteOptions, selection: Selection | None = None, *,
         skip_existing: bool = False) -> list[Task]:
    """The tasks of a job: each input's outputs, checked before any work.

    ``out`` is a directory (created when written to), or for a single capture a ``.npy`` / ``.png`` / ``.tiff``
    file. A capture writes ``out/<stem>.<format>``, a sequence (video, directory of images, glob) one file per
    selected frame, ``out/<name>_000000.<format>``, ... (:func:`~prismstereo.video.sequence_name`). An input that
    cannot be opened, or a selection that keeps no frame of it, becomes a task with an ``error`` (reported, the
    others still run); outputs that collide or would overwrite an input raise.

    Args:
        inputs: captures and sequence sources.
        out: output directory or file.
        options: formats and companions.
        selection: the frames of every sequence (default: all).
        skip_existing: start each task after the outputs already on disk (:attr:`Task.first`).

    Returns:
        One :class:`Task` per input, in order.

    Raises:
        PrismStereoError: a bad ``out``, a ``format`` contradicting it, colliding outputs, an output overwriting an
            input, a preview video with other than one sequence or a sequence option without a sequence.

    Example:
        >>> [t.outputs[0].depth.name for t in plan(["a.png", "b.png"], Path("out"), WriteOptions(format="png"))]
        ['a.png', 'b.png']
    """
    from prismstereo.video import (
        check_selection,
        is_sequence_source,
        is_video_file,
        sequence_files,
        sequence_length,
        sequence_name,
    )

    if not inputs:
        raise PrismStereoError("no inputs")
    selection = selection or Selection()
    sequences = [is_sequence_source(p) for p in inputs]
    fmt, suffix = options.format, out.suffix.lower()
    if suffix in DEPTH_SUFFIXES and not out.is_dir():
        if len(inputs) > 1 or any(sequences):
            what = "a video or sequence writes one file per frame" if any(sequences) else f"{len(inputs)} images"
            raise PrismStereoError(f"{what}: --out must be a directory, got {out}")
        if fmt is not None and fmt != DEPTH_SUFFIXES[suffix]:
            raise PrismStereoError(f"--format {fmt} contradicts --out {out}")
    elif out.exists() and not out.is_dir():
        raise PrismStereoError(f"--out {out} exists and is not a directory")
    elif suffix:
        raise PrismStereoError(f"--out must end in .npy, .png or .tiff (one image) or be a directory, got {out}")
    if not any(sequences) and (selection != Selection() or options.preview_video is not None):
        raise PrismStereoError("--every, --start, --stop and --preview-video need a video, a directory or a glob "
                               "of images")
    if options.preview_video is not None and (len(inputs) > 1 or skip_existing):
        raise PrismStereoError("--preview-video needs a single video or sequence and no --skip-existing")
    if any(sequences):
        check_selection(*selection)
    fmt = fmt or DEPTH_SUFFIXES.get(suffix, "npy")
    tasks, protected = [], {}
    for source, sequence in zip(inputs, sequences, strict=True):
        source = str(source)
        if not sequence:
            path = out if suffix in DEPTH_SUFFIXES else out / f"{Path(source).stem}.{fmt}"
            folder, stem = (out.parent, out.stem) if suffix in DEPTH_SUFFIXES else (out, Path(source).stem)
            outputs = (_outputs(folder, stem, path, options),)
            protected[Path(source).resolve()] = source
            error = None if Path(source).is_file() else f"image not found: {source}"
            tasks.append(Task(source, False, outputs, error=error))
            continue
        try:
            total = sequence_length(source)
            if not is_video_file(source):
                protected.update({p.resolve(): source for p in sequence_files(source)})
        except PrismStereoError as exc:
            tasks.append(Task(source, True, (), selection=selection, error=str(exc)))
            continue
        stop = total if selection.stop is None else min(selection.stop, total)
        count = max(0, -(-(stop - selection.start) // selection.every))
        name = sequence_name(source)
        outputs = tuple(_outputs(out, f"{name}_{k:06d}", out / f"{name}_{k:06d}.{fmt}", options) for k in range(count))
        error = None if count else f"--start {selection.start} selects no frame: {source} has {total} frames"
        tasks.append(Task(source, True, outputs, selection=selection, error=error))
    written: dict[Path, str] = {}
    for task in tasks:
        for files in task.outputs:
            for path in files:
                if path is None:
                    continue
                key = path.resolve()
                if key in protected:
                    what = "frame" if is_sequence_source(protected[key]) else "image"
                    raise PrismStereoError(f"--out would overwrite the input {what} {protected[key]} ({path})")
                if key in written:
                    raise PrismStereoError(f"{written[key]} and {task.source} would both write {path}")
                written[key] = task.source
    if skip_existing:
        tasks = [t._replace(first=next((k for k, o in enumerate(t.outputs) if not o.exist()), len(t.outputs)))
                 for t in tasks]
    return tasks
