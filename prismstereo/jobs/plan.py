"""The outputs of a depth job, named and checked before any work: one :class:`Task` per capture or sequence."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from prismstereo.errors import PrismStereoError
from prismstereo.io import DEPTH_SUFFIXES
from prismstereo.quiet import c_stderr_silenced

if TYPE_CHECKING:  # the plan imports without torch (a cached graph's host plans its outputs too)
    import torch

__all__ = ["ARGUMENTS", "Outputs", "PlanError", "Selection", "Task", "TaskReport", "WriteOptions", "check_inputs",
           "plan", "size_error"]


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
    a depth, and its confidence), ``png_scale`` (levels per mm; None: automatic), for a single sequence a
    colour-mapped ``preview_video`` at ``preview_fps``, and ``preview``: a colour-mapped ``<stem>_preview.png`` (with
    its colour bar in mm) beside each capture's depth file in any format and each frame's 16-bit PNG (a sequence
    in another format is previewed by ``preview_video``)."""

    format: str | None = None
    ply: bool = False
    dense: bool = False
    png_scale: float | None = None
    camera_to_world: torch.Tensor | None = None
    preview_video: Path | None = None
    preview_fps: float = 10.0
    preview: bool = True


class TaskReport(NamedTuple):
    """What became of a task: outputs ``written`` and ``skipped``, the ``lines`` to print, the model's seconds,
    and the ``error`` that stopped it (None if it completed)."""

    source: str
    written: int
    skipped: int
    lines: tuple[str, ...]
    model_seconds: float
    error: str | None = None


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

ARGUMENTS: tuple[str, ...] = ("out", "format", "every", "start", "stop", "preview_video", "skip_existing")
"""The arguments :class:`PlanError` messages name (:func:`plan`'s, the selection's and the write options')."""


class PlanError(PrismStereoError, ValueError):
    """A job that cannot be planned. Its message names :func:`plan`'s arguments (:data:`ARGUMENTS`: ``out``,
    ``format``, ...) by ``names`` (the CLI's flags), else by their own names; :meth:`naming` says it with others.

    Example:
        >>> error = PlanError("{out} must be a directory, got {path}", path="a.npy")
        >>> str(error), error.naming({"out": "--out"})
        ('out must be a directory, got a.npy', '--out must be a directory, got a.npy')
    """

    def __init__(self, template: str, names: Mapping[str, str] | None = None, **values: object) -> None:
        self.template, self.values = template, values
        super().__init__(self.naming(names or {}))

    def naming(self, names: Mapping[str, str]) -> str:
        """The message with each argument named by ``names`` (the argument's own name where it has none)."""
        return self.template.format(**{a: names.get(a, a) for a in ARGUMENTS}, **self.values)


def _outputs(folder: Path, stem: str, path: Path, options: WriteOptions, sequence: bool = False) -> Outputs:
    png = path.suffix.lower() == ".png"
    preview = options.preview and (png or not sequence)
    return Outputs(path, folder / f"{stem}_preview.png" if preview else None,
                   folder / f"{stem}.ply" if options.ply else None,
                   folder / f"{stem}_confidence.npy" if options.dense else None,
                   path.with_suffix(".json") if png else None)


def plan(inputs: Sequence[str | Path], out: Path, options: WriteOptions, selection: Selection | None = None, *,
         skip_existing: bool = False, names: Mapping[str, str] | None = None) -> list[Task]:
    """The tasks of a job: each input's outputs, checked before any work (it reads no image and writes nothing).

    ``out`` is a directory (created when written to), or for a single capture a ``.npy`` / ``.png`` / ``.tiff``
    file. A capture writes ``out/<stem>.<format>``, a sequence one file per selected frame: a directory or glob of
    images each image's ``out/<stem>.<format>``, a video ``out/<name>_000000.<format>``, ... numbered from 0
    (:func:`~prismstereo.stream.video.sequence_name`). An input
    that cannot be opened, or a selection that keeps no frame of it, becomes a task with an ``error`` (reported, the
    others still run); outputs that collide or would overwrite an input raise.

    Args:
        inputs: captures and sequence sources.
        out: output directory or file.
        options: formats and companions.
        selection: the frames of every sequence (default: all).
        skip_existing: start each task after the outputs already on disk (:attr:`Task.first`).
        names: how the errors name the arguments (:data:`ARGUMENTS`; the CLI passes its flags); default their own
            names.

    Returns:
        One :class:`Task` per input, in order.

    Raises:
        PlanError: no inputs, a bad ``out``, a ``format`` contradicting it, colliding outputs, an output overwriting
            an input, a preview video with other than one sequence or a sequence option without a sequence (its
            message names these arguments: :class:`PlanError`).

    Example:
        >>> [t.outputs[0].depth.name for t in plan(["a.png", "b.png"], Path("out"), WriteOptions(format="png"))]
        ['a.png', 'b.png']
    """
    from prismstereo.sources import check_selection, is_sequence_source

    if not inputs:
        raise PlanError("no inputs")
    names = dict(names or {})
    selection = selection or Selection()
    sequences = [is_sequence_source(p) for p in inputs]
    fmt = _check_arguments(inputs, out, options, selection, any(sequences), skip_existing, names)
    if any(sequences):
        try:
            check_selection(*selection)
        except PrismStereoError as exc:  # its message starts with the argument's name: every, start or stop
            name, rest = str(exc).split(" ", 1)
            raise PlanError("{" + name + "} {rest}", names, rest=rest) from exc
    tasks, protected = [], {}
    for source, sequence in zip(inputs, sequences, strict=True):
        if sequence:
            tasks.append(_sequence_task(str(source), out, fmt, options, selection, protected, names))
        else:
            tasks.append(_capture_task(str(source), out, fmt, options, protected))
    _check_collisions(tasks, protected, names)
    if skip_existing:
        tasks = [t._replace(first=next((k for k, o in enumerate(t.outputs) if not o.exist()), len(t.outputs)))
                 for t in tasks]
    return tasks


def _check_arguments(inputs: Sequence[str | Path], out: Path, options: WriteOptions, selection: Selection,
                     sequences: bool, skip_existing: bool, names: dict[str, str]) -> str:
    """:func:`plan`'s checks of its arguments together; returns the depth files' format."""
    fmt, suffix = options.format, out.suffix.lower()
    if suffix in DEPTH_SUFFIXES and not out.is_dir():
        if len(inputs) > 1 or sequences:
            what = "a video or sequence writes one file per frame" if sequences else f"{len(inputs)} images"
            raise PlanError("{what}: {out} must be a directory, got {path}", names, what=what, path=out)
        if fmt is not None and fmt != DEPTH_SUFFIXES[suffix]:
            raise PlanError("{format} {fmt} contradicts {out} {path}", names, fmt=fmt, path=out)
    elif out.exists() and not out.is_dir():
        raise PlanError("{out} {path} exists and is not a directory", names, path=out)
    elif suffix:
        raise PlanError("{out} must end in .npy, .png or .tiff (one image) or be a directory, got {path}", names,
                        path=out)
    _check_writable(out if not (suffix in DEPTH_SUFFIXES and not out.is_dir()) else out.parent, names)
    if options.preview_video is not None:
        _check_writable(options.preview_video.parent, names, "preview_video")
    if not sequences and (selection != Selection() or options.preview_video is not None):
        raise PlanError("{every}, {start}, {stop} and {preview_video} need a video, a directory or a glob of images",
                        names)
    if options.preview_video is not None and (len(inputs) > 1 or skip_existing):
        raise PlanError("{preview_video} needs a single video or sequence and no {skip_existing}", names)
    return fmt or DEPTH_SUFFIXES.get(suffix, "npy")


def _check_writable(folder: Path, names: dict[str, str], argument: str = "out") -> None:
    """A PlanError unless ``folder`` can be created (its nearest existing ancestor is a writable directory)."""
    import os

    existing = folder.absolute()
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise PlanError("{" + argument + "} {path}: {existing} is not a directory", names, path=folder,
                        existing=existing)
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PlanError("{" + argument + "} {path}: no permission to write in {existing}", names, path=folder,
                        existing=existing)


def _capture_task(source: str, out: Path, fmt: str, options: WriteOptions, protected: dict[Path, str]) -> Task:
    """A single capture's task (its file protected from being overwritten)."""
    single = out.suffix.lower() in DEPTH_SUFFIXES
    path = out if single else out / f"{Path(source).stem}.{fmt}"
    folder, stem = (out.parent, out.stem) if single else (out, Path(source).stem)
    protected[Path(source).resolve()] = source
    error = None if Path(source).is_file() else f"image not found: {source}"
    return Task(source, False, (_outputs(folder, stem, path, options),), error=error)


def _sequence_task(source: str, out: Path, fmt: str, options: WriteOptions, selection: Selection,
                   protected: dict[Path, str], names: dict[str, str]) -> Task:
    """A sequence's task: one output per selected frame (its image files protected from being overwritten)."""
    from prismstereo.sources import is_video_file, sequence_files, sequence_length, sequence_name

    try:
        total = sequence_length(source)
        files = [] if is_video_file(source) else sequence_files(source)
        protected.update({p.resolve(): source for p in files})
    except PrismStereoError as exc:
        return Task(source, True, (), selection=selection, error=str(exc))
    stop = total if selection.stop is None else min(selection.stop, total)
    count = max(0, -(-(stop - selection.start) // selection.every))
    if files:  # images keep their names
        stems = [p.stem for p in files[selection.start:stop:selection.every]]
    else:  # a video's frames are numbered
        stems = [f"{sequence_name(source)}_{k:06d}" for k in range(count)]
    outputs = tuple(_outputs(out, stem, out / f"{stem}.{fmt}", options, True) for stem in stems)
    error = None if count else str(PlanError("{start} {first} selects no frame: {source} has {total} frames", names,
                                             first=selection.start, source=source, total=total))
    return Task(source, True, outputs, selection=selection, error=error)


def _check_collisions(tasks: list[Task], protected: dict[Path, str], names: dict[str, str]) -> None:
    """Outputs that would overwrite an input or that two inputs would both write: a PlanError."""
    from prismstereo.sources import is_sequence_source

    written: dict[Path, str] = {}
    for task in tasks:
        for files in task.outputs:
            for path in files:
                if path is None:
                    continue
                key = path.resolve()
                if key in protected:
                    what = "frame" if is_sequence_source(protected[key]) else "image"
                    raise PlanError("{out} would overwrite the input {what} {source} ({path})", names, what=what,
                                    source=protected[key], path=path)
                if key in written:
                    raise PlanError("{first} and {second} would both write {path}", names, first=written[key],
                                    second=task.source, path=path)
                written[key] = task.source


def size_error(source: str, image: torch.Tensor, size: tuple[int, int]) -> str | None:
    """Why the (C, H, W) ``image`` read from ``source`` is not a capture of the sensor ``size`` (H, W), else None.

    Example:
        >>> size_error("a.png", torch.zeros(1, 48, 64), (96, 128))
        "image a.png is 64x48 px but the rig's sensor is 128x96 px"
    """
    h, w = image.shape[-2:]
    if (h, w) != tuple(size):
        return f"image {source} is {w}x{h} px but the rig's sensor is {size[1]}x{size[0]} px"
    return None


def _input_error(task: Task, size: tuple[int, int]) -> str | None:
    """Why ``task``'s first image to process cannot be read as a capture of ``size``, else None."""
    from prismstereo.io import decode_image
    from prismstereo.sources import decode_frames

    try:  # decoded without torch
        if not task.sequence:
            return size_error(task.source, decode_image(task.source), size)
        every, start, _ = task.selection
        index = start + task.first * every
        frame = next(decode_frames(task.source, start=index, stop=index + 1), None)
        if frame is None:
            return f"no frame {index} in {task.source}"
        return size_error(f"{task.source} (frame {index})", frame.image, size)
    except PrismStereoError as exc:
        return str(exc)


def check_inputs(tasks: Sequence[Task], size: tuple[int, int]) -> list[Task]:
    """The tasks with their inputs read before any model is built: each capture still to write decoded and sized,
    and each sequence's first frame to process (a sequence's later frames are read as it runs). A task that fails
    gets its :attr:`Task.error`; the others are unchanged. Captures are decoded on a few threads.

    Args:
        tasks: :func:`plan`'s tasks.
        size: (H, W) of the rig's sensor.

    Returns:
        The tasks, in order.

    Example:
        >>> tasks = check_inputs(plan(["missing.png"], Path("out"), WriteOptions()), (768, 1024))
        >>> tasks[0].error
        'image not found: missing.png'
    """
    from concurrent.futures import ThreadPoolExecutor

    todo = [k for k, t in enumerate(tasks) if t.error is None and t.first < len(t.outputs)]
    with c_stderr_silenced(), ThreadPoolExecutor(max_workers=min(4, max(1, len(todo)))) as pool:
        errors = dict(zip(todo, pool.map(lambda k: _input_error(tasks[k], size), todo), strict=True))
    return [t._replace(error=errors[k]) if errors.get(k) else t for k, t in enumerate(tasks)]
