"""One process's depth model and writers (:class:`Runner`): captures in batches and sequences frame after frame,
reading, the model and writing overlapping on three threads, every file renamed into place whole."""

from __future__ import annotations

import functools
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np
import torch
from torch import nn

from prismstereo.errors import PrismStereoError, check_option
from prismstereo.io import replacing
from prismstereo.jobs.plan import Outputs, Task, WriteOptions
from prismstereo.threads import session_threads, torch_threads

if TYPE_CHECKING:
    from prismstereo.export import OnnxDepth

__all__ = ["BACKENDS", "Runner", "TaskReport"]

BACKENDS = ("torch", "onnx")
Backend = Literal["torch", "onnx"]


class TaskReport(NamedTuple):
    """What became of a task: outputs ``written`` and ``skipped``, the ``lines`` to print, the model's seconds,
    and the ``error`` that stopped it (None if it completed)."""

    source: str
    written: int
    skipped: int
    lines: tuple[str, ...]
    model_seconds: float
    error: str | None = None

def _prefetch(items: Iterable[Any], depth: int = 2) -> Iterator[Any]:
    """The items of ``items``, produced on a background thread up to ``depth`` ahead (decoding overlaps the
    consumer's work); an exception of the producer is raised at its position."""
    box: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def offer(entry: tuple[bool, Any]) -> bool:
        """Queue ``entry`` unless the consumer has stopped; whether it was queued."""
        while not stop.is_set():
            try:
                box.put(entry, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            with torch_threads(1):  # decoding's tensor work must not compete with the model's thread pool
                for item in items:
                    if not offer((True, item)):
                        return
            offer((False, None))
        except BaseException as exc:  # handed to the consumer
            offer((False, exc))

    thread = threading.Thread(target=produce, name="prismstereo-reader", daemon=True)
    thread.start()
    try:
        while True:
            more, item = box.get()
            if not more:
                if item is not None:
                    raise item
                return
            yield item
    finally:
        stop.set()
        thread.join()


def _one_thread(job: Callable[[], Any]) -> Any:
    """``job()`` with one torch thread: a writer's tensor work beside the model's thread pool (its OpenMP team would
    otherwise share the cores with a second one, and both wait on each other)."""
    with torch_threads(1):
        return job()


class _Writer:
    """Runs write jobs on one background thread in submission order, at most ``depth`` pending; each job's
    ``done(future)`` is called on the submitting thread, in order."""

    def __init__(self, depth: int = 2) -> None:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="prismstereo-writer")
        self._pending: deque = deque()
        self._depth = depth

    def submit(self, job: Callable[[], Any], done: Callable[[Future], None]) -> None:
        self._pending.append((self._pool.submit(_one_thread, job), done))
        while len(self._pending) > self._depth:
            self._finish_one()

    def _finish_one(self) -> None:
        future, done = self._pending.popleft()
        future.exception()  # waits
        done(future)

    def close(self) -> None:
        while self._pending:
            self._finish_one()
        self._pool.shutdown()


_FAILURES = (PrismStereoError, OSError)  # what fails one input (unreadable, wrong size, disk full), not the job


class Runner:
    """One process's model and writers: depth of captures in batches, and of sequences frame after frame.

    The graph shares the cores with the reader and writer threads, so its onnxruntime threads sleep when idle
    (``spinning=False``, :class:`~prismstereo.export.OnnxDepth`) and those threads' tensor work runs on one torch
    thread: otherwise each waits on the other's busy threads.

    Args:
        model: a :class:`~prismstereo.model.PrismStereo` or :class:`~prismstereo.learned.LearnedStereo`, or an
            exported graph (:class:`~prismstereo.export.OnnxDepth`, backend 'onnx': no torch model is built; for
            sequences under the temporal prior with an exported temporal graph as ``tracker``).
        backend: 'torch' (the module) or 'onnx' (its exported graph in onnxruntime, exported once into the cache,
            :func:`~prismstereo.export.onnx_session`).
        options: how results are written (default :class:`WriteOptions`).
        temporal: sequences: the temporal prior's options, or None (every frame on its own).
        tracker: sequences under the temporal prior: the :class:`~prismstereo.model.PrismStereo` whose band tracks
            between key frames (default ``model``; key frames by a model without a band, such as
            :class:`~prismstereo.learned.HybridStereo`, tracked by the classical band), or with an exported
            ``model`` that band's exported temporal graph (an :class:`~prismstereo.export.OnnxDepth`).
        threads: torch / onnxruntime threads (default: every core).

    Attributes:
        progress: called with 1 per output written (on the thread that calls the runner), or None.

    Example:
        >>> from prismstereo.model import PrismStereo
        >>> runner = Runner(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), options=WriteOptions())
        >>> runner.backend
        'torch'
    """

    def __init__(self, model: nn.Module | OnnxDepth, *, backend: Backend = "torch",
                 options: WriteOptions | None = None, temporal: Any = None,
                 tracker: nn.Module | OnnxDepth | None = None, threads: int | None = None) -> None:
        from prismstereo.export import OnnxDepth

        check_option(backend, BACKENDS, "backend")
        self.graph = model if isinstance(model, OnnxDepth) else None
        self._graph_path = None if self.graph is None else self.graph.path
        exported = isinstance(tracker, OnnxDepth)
        if self.graph is not None and (backend != "onnx" or (temporal is not None and not exported)):
            raise PrismStereoError("an exported graph runs with backend 'onnx', and under the temporal prior with an "
                                   "exported temporal graph as its tracker")
        if tracker is not None and temporal is None:
            raise PrismStereoError("a tracker tracks sequences under the temporal prior")
        if exported and (self.graph is None or tracker.temporal is None):
            raise PrismStereoError("an exported tracker is the temporal graph of an exported model's sequences")
        self.model = None if self.graph is not None else model.eval()
        self.tracker = None if tracker is None or exported else tracker.eval()
        self.tracker_graph = tracker if exported else None
        self._tracker_path = tracker.path if exported else None
        self.rig = (self.graph or self.model).rig
        described = self.graph.z_range if self.graph is not None else self.model.describe()["z_range_mm"]
        self.z_range = tuple(float(z) for z in described)
        self.backend, self.temporal = backend, temporal
        self.options = options or WriteOptions()
        self.threads = threads or os.cpu_count() or 1
        self.progress: Callable[[int], None] | None = None

    # ----------------------------------------------------------------------------- models
    def prepare(self) -> None:
        """Export the ONNX graphs into the cache without opening a session (before worker processes fork).

        Example:
            >>> Runner(model, backend="onnx").prepare()  # doctest: +SKIP
        """
        if self.backend == "onnx" and self.model is not None:
            from prismstereo.export import cache_path, export_cached

            export_cached(self.model, cache_path(self.model))
            if self.temporal is not None:
                tracker = self.tracker or self.model
                export_cached(tracker, cache_path(tracker, temporal=self.temporal), temporal=self.temporal)

    def for_worker(self, threads: int) -> None:
        """Make this (forked or unpickled) runner a worker process's: its threads, no progress callback, and its
        own onnxruntime session (a session is not shared across processes).

        Example:
            >>> runner.for_worker(1)  # doctest: +SKIP
        """
        from prismstereo.export import OnnxDepth

        self.threads, self.progress = threads, None
        if self._graph_path is not None:
            self.graph = OnnxDepth(self._graph_path, threads=threads, spinning=False)
        if self._tracker_path is not None:
            self.tracker_graph = OnnxDepth(self._tracker_path, threads=session_threads(threads, temporal=True),
                                           spinning=False)

    def __getstate__(self) -> dict[str, Any]:
        """Pickled for a spawned worker or a Ray actor: the model (or the graphs' paths), not a session or callback."""
        state = dict(self.__dict__)
        state["graph"], state["tracker_graph"], state["progress"] = None, None, None
        return state

    def _session(self, temporal: Any = None):
        """The per-frame graph, or with ``temporal`` the tracker's temporal graph, in onnxruntime."""
        if self._graph_path is not None:
            if self.graph is None:  # unpickled
                self.for_worker(self.threads)
            return self.graph if temporal is None else self.tracker_graph
        from prismstereo.export import onnx_session

        model = self.model if temporal is None else self.tracker or self.model
        return onnx_session(model, channels=1, threads=session_threads(self.threads, temporal is not None),
                            temporal=temporal, spinning=False)

    def depth(self, batch: torch.Tensor):
        """The model's (or graph's) result for a grey batch (B, 1, H, W): ``depth``, ``valid``, ``confidence``,
        (B, 1, H, W_ref) each.

        Example:
            >>> from prismstereo.model import PrismStereo
            >>> runner = Runner(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)))
            >>> runner.depth(torch.rand(2, 1, 48, 64)).depth.shape
            torch.Size([2, 1, 48, 32])
        """
        if self.backend == "onnx":
            return self._session()(batch)
        with torch.inference_mode():
            return self.model(batch)

    def _stream(self):
        from prismstereo.stream import DepthStream

        if self.backend == "onnx":
            tracker = None if self.temporal is None else self._session(self.temporal)
            return DepthStream(self._session(), temporal_graph=tracker, threads=self.threads)
        return DepthStream(self.model, temporal=self.temporal or False, tracker=self.tracker)

    # ----------------------------------------------------------------------------- writing
    def _write(self, files: Outputs, depth: torch.Tensor, valid: torch.Tensor, confidence: torch.Tensor,
               points: torch.Tensor | None, colors: torch.Tensor) -> str:
        """Write one result (depth (H, W_ref), its companions); returns the note for its line."""
        from prismstereo.depth import write_ply
        from prismstereo.io import write_depth
        from prismstereo.preview import write_depth_preview

        opts = self.options
        written = write_depth(files.depth, depth, valid, png_scale=opts.png_scale)
        note = ""
        if written.format == "png":
            write_depth_preview(files.preview, depth, valid)
            note = (f", preview {files.preview.name}, {written.scale:g} levels/mm (stored in the PNG and "
                    f"{files.sidecar.name})")
            if written.clipped:
                note += (f"; warning: {written.clipped} pixels deeper than {65535 / written.scale:.3f} mm clipped to "
                         "65535 (see --png-scale)")
        if files.confidence is not None:
            with replacing(files.confidence) as partial:
                np.save(partial, confidence.numpy().astype(np.float32))
            note += f", confidence {files.confidence.name}"
        if files.ply is not None and points is not None:
            count = write_ply(files.ply, points, colors=colors, confidence=confidence,
                              camera_to_world=opts.camera_to_world)
            note += f", {files.ply.name} ({count} points)"
        return note

    def written(self, result: Any) -> torch.Tensor:
        """The (B, 1, H, W_ref) pixels whose depth is written: the valid ones, or with ``dense`` every pixel with a
        depth (confidence > 0).

        Example:
            >>> from prismstereo.model import PrismStereo
            >>> runner = Runner(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)))
            >>> runner.written(runner.depth(torch.rand(1, 1, 48, 64))).shape
            torch.Size([1, 1, 48, 32])
        """
        return (result.confidence > 0) if self.options.dense else result.valid

    def _points(self, depth: torch.Tensor, written: torch.Tensor) -> torch.Tensor | None:
        if not self.options.ply:
            return None
        from prismstereo.depth import depth_to_points

        with torch.inference_mode():
            return depth_to_points(self.rig, depth.to(torch.float64), written)

    def _tick(self) -> None:
        if self.progress is not None:
            self.progress(1)

    # ----------------------------------------------------------------------------- captures
    def _read(self, path: str) -> tuple[torch.Tensor, torch.Tensor] | str:
        """A capture of the rig's size, grey (1, H, W) and as read (C, H, W), or why not."""
        from prismstereo.io import read_image, to_grey

        try:
            image = read_image(path)
        except _FAILURES as exc:
            return str(exc)
        rig = self.rig
        h, w = image.shape[-2:]
        if (w, h) != (rig.image_width, rig.image_height):
            return f"image {path} is {w}x{h} px but the rig's sensor is {rig.image_width}x{rig.image_height} px"
        return to_grey(image), image

    def run_captures(self, tasks: Sequence[Task], batch_size: int = 1) -> Iterator[TaskReport]:
        """Depth of single captures, ``batch_size`` at a time: the next batch is read while this one runs and the
        previous one is written. Yields one report per task, in order, as its files are complete.

        Example:
            >>> reports = list(runner.run_captures(plan(["a.png"], Path("out"), WriteOptions())))  # doctest: +SKIP
        """
        chunks = [list(tasks[i:i + batch_size]) for i in range(0, len(tasks), batch_size)]
        ready: deque = deque()
        writer = _Writer()
        w_ref = self.rig.reference_width
        for chunk, images in zip(chunks, _prefetch([self._read(t.source) for t in c] for c in chunks), strict=True):
            good = [(t, im) for t, im in zip(chunk, images, strict=True) if not isinstance(im, str)]
            ready.extend(TaskReport(t.source, 0, 0, (), 0.0, im) for t, im in zip(chunk, images, strict=True)
                         if isinstance(im, str))
            if good:
                start = time.perf_counter()
                res = self.depth(torch.stack([grey for _, (grey, _) in good]))
                seconds = (time.perf_counter() - start) / len(good)
                mask = self.written(res)
                points = self._points(res.depth, mask)
                for k, (task, (_, image)) in enumerate(good):
                    depth, valid = res.depth[k, 0], mask[k, 0]
                    job = functools.partial(self._write, task.outputs[0], depth, valid, res.confidence[k, 0],
                                            None if points is None else points[k], image[:, :, :w_ref])
                    writer.submit(job, functools.partial(self._captured, ready, task, depth, valid, seconds))
            while ready:
                yield ready.popleft()
        writer.close()
        yield from ready

    def _captured(self, ready: deque, task: Task, depth: torch.Tensor, valid: torch.Tensor, seconds: float,
                  future: Future) -> None:
        """Queue the report of a capture whose files were written by ``future``."""
        error = future.exception()
        if error is not None:
            if not isinstance(error, _FAILURES):
                raise error
            ready.append(TaskReport(task.source, 0, 0, (), seconds, str(error)))
            return
        self._tick()
        ok = valid & torch.isfinite(depth)
        median = f"median {float(depth[ok].median()):.1f} mm" if bool(ok.any()) else "no valid depth"
        kind = "with a depth (dense)" if self.options.dense else "valid"
        line = (f"wrote {task.outputs[0].depth}: {ok.float().mean():.1%} of reference pixels {kind}, {median}"
                f"{future.result()}")
        ready.append(TaskReport(task.source, 1, 0, (line,), seconds))

    # ----------------------------------------------------------------------------- sequences
    def run_sequence(self, task: Task) -> TaskReport:
        """Depth of a sequence's selected frames from ``task.first`` on, in order through one
        :class:`~prismstereo.stream.DepthStream` (the temporal prior if the runner has one): frames decoded ahead
        on a reader thread, files (and the preview video's frames) written on a writer thread. A frame that cannot
        be read or written stops the sequence; the frames before it are complete.

        Example:
            >>> report = runner.run_sequence(plan(["clip.mp4"], Path("out"), WriteOptions())[0])  # doctest: +SKIP
        """
        from prismstereo.video import read_frames

        sel, rig, opts = task.selection, self.rig, self.options
        stream = self._stream()
        writer, preview, state = _Writer(depth=4), [None], {"written": 0, "error": None}

        def add_preview(picture: np.ndarray) -> None:
            import cv2

            if preview[0] is None:
                opts.preview_video.parent.mkdir(parents=True, exist_ok=True)
                preview[0] = cv2.VideoWriter(str(opts.preview_video), cv2.VideoWriter_fourcc(*"mp4v"),
                                             opts.preview_fps, (picture.shape[1], picture.shape[0]))
                if not preview[0].isOpened():
                    raise PrismStereoError(f"OpenCV cannot write the video {opts.preview_video}")
            preview[0].write(picture)

        failed = threading.Event()  # set by the writer: the frames queued after a failed one are not written

        def done(future: Future) -> None:
            error = future.exception()
            if error is None:
                if future.result():
                    state["written"] += 1
                    self._tick()
            elif not isinstance(error, _FAILURES):
                raise error
            elif state["error"] is None:
                state["error"] = str(error)

        def job(files, depth, valid, conf, points, colors) -> bool:
            if failed.is_set():
                return False
            try:
                self._write(files, depth, valid, conf, points, colors)
                if opts.preview_video is not None:
                    from prismstereo.preview import depth_preview

                    add_preview(depth_preview(depth, valid, limits_mm=self.z_range))
            except BaseException:
                failed.set()
                raise
            return True

        # grey frames from the reader thread, unless the point cloud takes the frames' colours; a video decoded on
        # every core but one (the graph's, or under the temporal prior the band's: session_threads)
        frames = read_frames(task.source, every=sel.every, start=sel.start + task.first * sel.every, stop=sel.stop,
                             grey=not opts.ply, decode_threads=max(1, self.threads - 1))
        try:
            for files, frame in zip(task.outputs[task.first:], _prefetch(frames, depth=4), strict=False):
                res = stream.push(frame.image)
                mask = self.written(res)
                points = self._points(res.depth, mask)
                writer.submit(functools.partial(job, files, res.depth[0, 0], mask[0, 0], res.confidence[0, 0],
                                                None if points is None else points[0],
                                                frame.image[:, :, : rig.reference_width]), done)
                if state["error"] is not None:
                    break
        except _FAILURES as exc:
            state["error"] = str(exc)
        finally:
            writer.close()
            if preview[0] is not None:
                preview[0].release()
        return self._sequence_report(task, stream, state["written"], state["error"])

    def _sequence_report(self, task: Task, stream: Any, written: int, error: str | None) -> TaskReport:
        lines = []
        if written:
            times = sorted(stream.times_ms)
            first = task.outputs[task.first].depth
            keys = f", {stream.keyframes} key frames" if stream.temporal is not None else ""
            resumed = f" (resumed at output {task.first})" if task.first else ""
            lines.append(f"wrote {written} depth files {first.name} ... to {first.parent}{resumed}: "
                         f"{times[len(times) // 2]:.1f} ms per frame (median of the depth computation), "
                         f"{stream.frames_per_second():.1f} frames/s{keys}"
                         + (f"; preview video {self.options.preview_video}" if self.options.preview_video else ""))
        return TaskReport(task.source, written, task.first, tuple(lines), sum(stream.times_ms) / 1000, error)
