"""One process's depth pipeline (:class:`Pipeline`): a :class:`~prismstereo.predictor.Predictor` and its writers, over
captures in batches and sequences frame after frame, reading, the model and writing overlapping on three threads,
every file renamed into place whole.

The pipeline itself imports no torch: captures and frames are decoded into numpy arrays, results written from
either kind of array. With a :class:`~prismstereo.export.graphs.GraphPredictor` (a model's graphs on arrays) a job
runs without torch; with a :class:`~prismstereo.predictor.Predictor` the arrays become its tensors."""

from __future__ import annotations

import functools
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import numpy as np

from prismstereo.errors import OptionError, PrismStereoError
from prismstereo.export.graphs import GraphPredictor
from prismstereo.export.session import as_array
from prismstereo.io import replacing
from prismstereo.jobs.plan import Outputs, Task, TaskReport, WriteOptions, size_error
from prismstereo.threads import ThreadPlan, thread_plan, torch_threads

if TYPE_CHECKING:
    from prismstereo.predictor import Predictor

__all__ = ["Pipeline", "TaskReport"]


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
            # decoding's tensor work must not compete with the model's thread pool
            with torch_threads(thread_plan().side):
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
    """``job()`` on the side threads (one): a writer's tensor work beside the model's thread pool (its OpenMP team
    would otherwise share the cores with a second one, and both wait on each other)."""
    with torch_threads(thread_plan().side):
        return job()


def _tally(state: dict[str, Any], depth: Any, valid: Any) -> None:
    """Add a written frame's valid pixels and depth range (a tensor's or an array's) to a sequence's ``state``."""
    depth, valid = as_array(depth), as_array(valid)
    ok = valid & np.isfinite(depth)
    state["valid"] += int(np.count_nonzero(ok))
    state["pixels"] += ok.size
    if ok.any():
        state["lo"], state["hi"] = min(state["lo"], float(depth[ok].min())), max(state["hi"], float(depth[ok].max()))


def _depth_range(depths: np.ndarray) -> str:
    """``depths`` (N,) mm in words: their range and median (the lower middle value, as torch's), or that there is
    none."""
    if not depths.size:
        return "no valid depth"
    median = float(np.partition(depths, (depths.size - 1) // 2)[(depths.size - 1) // 2])
    return f"depth {float(depths.min()):.1f}-{float(depths.max()):.1f} mm (median {median:.1f})"


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


class Pipeline:
    """One process's predictor and writers: depth of captures in batches, and of sequences frame after frame.

    A graph shares the cores with the reader and writer threads, so build its predictor with ``spinning=False``
    (its onnxruntime threads sleep when idle, :class:`~prismstereo.export.OnnxDepth`); those threads' tensor work
    runs on one torch thread: otherwise each waits on the other's busy threads.

    Args:
        predictor: the model in torch or its graphs in onnxruntime (a :class:`~prismstereo.predictor.Predictor`), or
            the graphs on arrays without torch (a :class:`~prismstereo.export.graphs.GraphPredictor`); sequences are
            tracked by its temporal band when it has one (``temporal``), else every frame on its own.
        options: how results are written (default :class:`WriteOptions`).

    Attributes:
        progress: called with 1 per output written (on the thread that calls the pipeline), or None.

    Example:
        >>> from prismstereo.models import build_model
        >>> from prismstereo.predictor import Predictor
        >>> model = build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0))
        >>> Pipeline(Predictor(model)).predictor.backend
        'torch'
    """

    def __init__(self, predictor: Predictor | GraphPredictor, *, options: WriteOptions | None = None) -> None:
        if not isinstance(predictor, GraphPredictor):
            from prismstereo.predictor import Predictor

            if not isinstance(predictor, Predictor):
                raise OptionError(f"a pipeline runs a Predictor or a GraphPredictor, got {type(predictor).__name__}")
        self.predictor = predictor
        self.options = options or WriteOptions()
        self.progress: Callable[[int], None] | None = None

    @property
    def rig(self):
        """The predictor's rig (a :class:`~prismstereo.export.graphs.GraphPredictor` builds it from its metadata,
        importing torch: the point clouds need it)."""
        return self.predictor.rig

    @property
    def z_range(self) -> tuple[float, float]:
        """The predictor's depth range (mm)."""
        return self.predictor.z_range

    @property
    def threads(self) -> ThreadPlan:
        """The threads of this process's parts (:func:`~prismstereo.threads.thread_plan` of the predictor's cores)."""
        return thread_plan(cores=self.predictor.threads)

    def for_process(self, threads: int) -> Pipeline:
        """This pipeline for a worker process on ``threads`` cores: its predictor's own sessions, no progress
        callback.

        Example:
            >>> pipeline.for_process(1)  # doctest: +SKIP
        """
        return Pipeline(self.predictor.for_process(threads), options=self.options)

    def __getstate__(self) -> dict[str, Any]:
        """Pickled for a spawned worker or a Ray actor: the predictor (its model or graphs' paths), not a callback."""
        return {**self.__dict__, "progress": None}

    def depth(self, batch: Any):
        """The predictor's result for a batch (B, C, H, W): ``depth``, ``valid``, ``confidence``, (B, 1, H, W_ref)
        each.

        Example:
            >>> from prismstereo.models import build_model
            >>> from prismstereo.predictor import Predictor
            >>> pipeline = Pipeline(Predictor(build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0))))
            >>> pipeline.depth(torch.rand(2, 1, 48, 64)).depth.shape
            torch.Size([2, 1, 48, 32])
        """
        return self.predictor.depth(batch)

    # ----------------------------------------------------------------------------- writing
    def _write(self, files: Outputs, depth: Any, valid: Any, confidence: Any, points: Any, colors: Any) -> str:
        """Write one result (depth (H, W_ref), its companions); returns the note for its line."""
        from prismstereo.io import write_depth
        from prismstereo.preview import write_depth_preview

        opts = self.options
        written = write_depth(files.depth, depth, valid, png_scale=opts.png_scale)
        note = ""
        if files.preview is not None:
            write_depth_preview(files.preview, depth, valid)
            note = f", preview {files.preview.name}"
        if written.format == "png":
            note += f", {written.scale:g} levels/mm (stored in the PNG and {files.sidecar.name})"
            if written.clipped:
                note += (f"; warning: {written.clipped} pixels deeper than {65535 / written.scale:.3f} mm clipped to "
                         "65535 (see --png-scale)")
        if files.confidence is not None:
            with replacing(files.confidence) as partial:
                np.save(partial, as_array(confidence).astype(np.float32))
            note += f", confidence {files.confidence.name}"
        if files.ply is not None and points is not None:
            import torch

            from prismstereo.depth import write_ply

            count = write_ply(files.ply, points, colors=torch.as_tensor(colors),
                              confidence=torch.as_tensor(confidence), camera_to_world=opts.camera_to_world)
            note += f", {files.ply.name} ({count} points)"
        return note

    def written_pixels(self, result: Any) -> Any:
        """The (B, 1, H, W_ref) pixels whose depth is written: the valid ones, or with ``dense`` every pixel with a
        depth (confidence > 0).

        Example:
            >>> from prismstereo.models import build_model
            >>> from prismstereo.predictor import Predictor
            >>> pipeline = Pipeline(Predictor(build_model(thesis_setup1().downscaled(16), z_range=(400.0, 700.0))))
            >>> pipeline.written_pixels(pipeline.depth(torch.rand(1, 1, 48, 64))).shape
            torch.Size([1, 1, 48, 32])
        """
        return (result.confidence > 0) if self.options.dense else result.valid

    def _points(self, depth: Any, written: Any) -> Any:
        if not self.options.ply:
            return None
        import torch

        from prismstereo.depth import depth_to_points

        with torch.inference_mode():
            return depth_to_points(self.rig, torch.as_tensor(depth).to(torch.float64), torch.as_tensor(written))

    def _tick(self) -> None:
        if self.progress is not None:
            self.progress(1)

    # ----------------------------------------------------------------------------- captures
    def _read(self, path: str) -> tuple[np.ndarray, np.ndarray] | str:
        """A capture of the sensor's size, grey (1, H, W) and as read (C, H, W) float32 arrays, or why not."""
        from prismstereo.io import decode_image, grey_array

        try:
            image = decode_image(path)
        except _FAILURES as exc:
            return str(exc)
        error = size_error(path, image, self.predictor.image_size)
        return error if error else (grey_array(image), image)

    def run_captures(self, tasks: Sequence[Task], batch_size: int = 1) -> Iterator[TaskReport]:
        """Depth of single captures, ``batch_size`` at a time: the next batch is read while this one runs and the
        previous one is written. Yields one report per task, in order, as its files are complete.

        Example:
            >>> reports = list(pipeline.run_captures(plan(["a.png"], Path("out"), WriteOptions())))  # doctest: +SKIP
        """
        chunks = [list(tasks[i:i + batch_size]) for i in range(0, len(tasks), batch_size)]
        ready: deque = deque()
        writer = _Writer()
        w_ref = self.predictor.reference_width
        for chunk, images in zip(chunks, _prefetch([self._read(t.source) for t in c] for c in chunks), strict=True):
            good = [(t, im) for t, im in zip(chunk, images, strict=True) if not isinstance(im, str)]
            ready.extend(TaskReport(t.source, 0, 0, (), 0.0, im) for t, im in zip(chunk, images, strict=True)
                         if isinstance(im, str))
            if good:
                start = time.perf_counter()
                res = self.depth(np.stack([grey for _, (grey, _) in good]))
                seconds = (time.perf_counter() - start) / len(good)
                mask = self.written_pixels(res)
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

    def _captured(self, ready: deque, task: Task, depth: Any, valid: Any, seconds: float, future: Future) -> None:
        """Queue the report of a capture whose files were written by ``future``."""
        error = future.exception()
        if error is not None:
            if not isinstance(error, _FAILURES):
                raise error
            ready.append(TaskReport(task.source, 0, 0, (), seconds, str(error)))
            return
        self._tick()
        depth, valid = as_array(depth), as_array(valid)
        ok = valid & np.isfinite(depth)
        kind = "with a depth (dense)" if self.options.dense else "valid"
        line = (f"wrote {task.outputs[0].depth}: {np.count_nonzero(ok) / ok.size:.1%} of reference pixels {kind}, "
                f"{_depth_range(depth[ok])}{future.result()}")
        ready.append(TaskReport(task.source, 1, 0, (line,), seconds))

    # ----------------------------------------------------------------------------- sequences
    def run_sequence(self, task: Task) -> TaskReport:
        """Depth of a sequence's selected frames from ``task.first`` on, in order through one
        :class:`~prismstereo.stream.DepthStream` (the temporal prior if the predictor has a band): frames decoded ahead
        on a reader thread, files (and the preview video's frames) written on a writer thread. A frame that cannot
        be read or written stops the sequence; the frames before it are complete.

        Example:
            >>> report = pipeline.run_sequence(plan(["clip.mp4"], Path("out"), WriteOptions())[0])  # doctest: +SKIP
        """
        from prismstereo.sources import decode_frames

        sel, opts = task.selection, self.options
        stream = self._stream()
        writer, preview = _Writer(depth=4), [None]
        state = {"written": 0, "error": None, "valid": 0, "pixels": 0, "lo": math.inf, "hi": -math.inf}

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
                _tally(state, depth, valid)
                if opts.preview_video is not None:
                    from prismstereo.preview import depth_preview

                    add_preview(depth_preview(depth, valid, limits_mm=self.z_range))
            except BaseException:
                failed.set()
                raise
            return True

        # grey frames from the reader thread, unless the point cloud takes the frames' colours; a video decoded on
        # every core but one (the graph's, or under the temporal prior the band's: thread_plan)
        frames = decode_frames(task.source, every=sel.every, start=sel.start + task.first * sel.every, stop=sel.stop,
                             grey=not opts.ply, decode_threads=self.threads.decode)
        try:
            for files, frame in zip(task.outputs[task.first:], _prefetch(frames, depth=4), strict=False):
                res = stream.push(frame.image)
                mask = self.written_pixels(res)
                points = self._points(res.depth, mask)
                writer.submit(functools.partial(job, files, res.depth[0, 0], mask[0, 0], res.confidence[0, 0],
                                                None if points is None else points[0],
                                                frame.image[:, :, : self.predictor.reference_width]), done)
                if state["error"] is not None:
                    break
        except _FAILURES as exc:
            state["error"] = str(exc)
        finally:
            writer.close()
            if preview[0] is not None:
                preview[0].release()
        return self._sequence_report(task, stream, state)

    def _stream(self) -> Any:
        """A sequence's stream: a :class:`~prismstereo.stream.frame_stream.FrameStream` of graphs on arrays, or a
        :class:`~prismstereo.stream.DepthStream` of a predictor; tracked by its band if it has one."""
        tracked = self.predictor.temporal is not None
        if isinstance(self.predictor, GraphPredictor):
            from prismstereo.stream.frame_stream import FrameStream

            return FrameStream(self.predictor, temporal=tracked)
        from prismstereo.stream import DepthStream

        return DepthStream(self.predictor, temporal=tracked)

    def _sequence_report(self, task: Task, stream: Any, state: dict[str, Any]) -> TaskReport:
        lines, written, error = [], state["written"], state["error"]
        if written:
            times = sorted(stream.times_ms)
            first = task.outputs[task.first].depth
            keys = f", {stream.keyframes} key frames" if stream.temporal is not None else ""
            resumed = f" (resumed at output {task.first})" if task.first else ""
            kind = "with a depth (dense)" if self.options.dense else "valid"
            spread = (f"depth {state['lo']:.1f}-{state['hi']:.1f} mm" if state["hi"] >= state["lo"] else
                      "no valid depth")
            lines.append(f"wrote {written} depth files {first.name} ... to {first.parent}{resumed}: "
                         f"{state['valid'] / max(1, state['pixels']):.1%} of reference pixels {kind}, {spread}; "
                         f"{times[len(times) // 2]:.1f} ms per frame (median of the depth computation), "
                         f"{stream.frames_per_second():.1f} frames/s{keys}"
                         + (f"; preview video {self.options.preview_video}" if self.options.preview_video else ""))
        return TaskReport(task.source, written, task.first, tuple(lines), sum(stream.times_ms) / 1000, error)
