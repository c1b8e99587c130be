"""Running a depth job (:func:`run`): one progress bar, failures per input, in this process or over workers."""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, NamedTuple

from prismstereo.errors import PrismStereoError
from prismstereo.io import partial_stem
from prismstereo.jobs.plan import Task
from prismstereo.jobs.runner import Runner, TaskReport

__all__ = ["JobSummary", "run"]


class JobSummary(NamedTuple):
    """A whole run: per-task reports in input order, wall seconds and worker processes."""

    reports: tuple[TaskReport, ...]
    seconds: float
    workers: int

    @property
    def failed(self) -> tuple[TaskReport, ...]:
        return tuple(r for r in self.reports if r.error is not None)

    def describe(self) -> str:
        """One line: outputs, skips, failures, end-to-end rate and the model's share of the processes' time."""
        written = sum(r.written for r in self.reports)
        skipped = sum(r.skipped for r in self.reports)
        model = sum(r.model_seconds for r in self.reports)
        text = f"{len(self.reports)} inputs, {written} depth maps written"
        if skipped:
            text += f", {skipped} skipped (already written)"
        if self.failed:
            text += f", {len(self.failed)} inputs failed"
        if written and self.seconds > 0:
            busy = self.seconds * self.workers
            text += (f"; {self.seconds:.1f} s, {written / self.seconds:.1f} depth maps/s end to end, the depth model "
                     f"{model / busy:.0%} of {'the processes' if self.workers > 1 else 'the'} time")
        return text

_WORKER: dict[str, Runner] = {}


def _start_worker(runner: Runner, threads: int) -> None:
    runner.for_worker(threads)
    _WORKER["runner"] = runner


def _work(unit: list[tuple[int, Task]], batch_size: int) -> list[tuple[int, TaskReport]]:
    return work(_WORKER["runner"], unit, batch_size)


def unit_reports(runner: Runner, unit: list[tuple[int, Task]], batch_size: int) -> Iterator[tuple[int, TaskReport]]:
    """A unit's (index, report) pairs as its tasks complete: a batch of captures or one sequence, with their task
    indices, on ``runner``.

    Example:
        >>> list(unit_reports(runner, [(0, plan(["a.png"], Path("out"), WriteOptions())[0])], 1))  # doctest: +SKIP
    """
    if unit[0][1].sequence:
        yield unit[0][0], runner.run_sequence(unit[0][1])
        return
    yield from zip((i for i, _ in unit), runner.run_captures([t for _, t in unit], batch_size), strict=True)


def work(runner: Runner, unit: list[tuple[int, Task]], batch_size: int) -> list[tuple[int, TaskReport]]:
    """A worker process's unit (:func:`unit_reports`) on its runner's threads: the (index, report) pairs.

    Example:
        >>> work(runner, [(0, plan(["a.png"], Path("out"), WriteOptions())[0])], 1)  # doctest: +SKIP
    """
    from prismstereo.threads import torch_threads

    with torch_threads(runner.threads):
        return list(unit_reports(runner, unit, batch_size))


def _units(tasks: Sequence[tuple[int, Task]], batch_size: int) -> list[list[tuple[int, Task]]]:
    """Consecutive captures in batches, each sequence on its own."""
    units: list[list[tuple[int, Task]]] = []
    for item in tasks:
        last = units[-1] if units else None
        if item[1].sequence or last is None or last[0][1].sequence or len(last) == batch_size:
            units.append([item])
        else:
            last.append(item)
    return units


def run(tasks: Sequence[Task], runner: Runner, *, workers: int = 1, batch_size: int = 1, progress: bool = True,
        report: Callable[[TaskReport], None] | None = None, ray: str | None = None) -> JobSummary:
    """Run a job's tasks (:func:`plan`) with one progress bar over all outputs to write.

    Tasks with a planning error and tasks with nothing left are reported without running; a failing input is
    reported and the others run. With ``workers`` > 1 the captures (in batches) and sequences are spread over that
    many processes, each with ``cores // workers`` threads (forked where the platform allows, so the model and the
    exported graph are the parent's; else spawned with a copy of ``runner``); the files written are the same as
    with one process.

    Args:
        tasks: from :func:`plan`.
        runner: the model and write options.
        workers: processes (1: this one, with its reader and writer threads).
        batch_size: captures per model call.
        progress: show the bar (stderr).
        report: called with each task's report as it completes (default: print its lines).
        ray: run on Ray actors instead (:mod:`prismstereo.jobs.distributed`): 'local' (a local instance) or a
            cluster's address ('auto', 'ray://host:10001'); ``workers`` must then be 1.

    Returns:
        JobSummary: the reports in input order, the wall time, the worker count.

    Example:
        >>> summary = run(plan(["a.png", "b.png"], Path("out"), WriteOptions()), runner)  # doctest: +SKIP
        >>> [report.written for report in summary.reports]  # doctest: +SKIP
        [1, 1]
    """
    from tqdm import tqdm

    if not isinstance(workers, int) or workers < 1:
        raise PrismStereoError(f"workers must be an int >= 1, got {workers}")
    if not isinstance(batch_size, int) or batch_size < 1:
        raise PrismStereoError(f"batch_size must be an int >= 1, got {batch_size}")
    if ray is not None and workers != 1:
        raise PrismStereoError("ray and workers > 1 exclude each other (Ray places the workers)")
    start = time.perf_counter()
    reports: dict[int, TaskReport] = {}
    total = sum(len(t.outputs) - t.first for t in tasks if t.error is None)
    with tqdm(total=total, unit="map", file=sys.stderr, desc="depth", disable=not progress) as bar:

        def deliver(i: int, rep: TaskReport) -> None:
            reports[i] = rep
            if report is not None:
                report(rep)
            else:
                for line in rep.lines:
                    tqdm.write(line, file=sys.stdout)

        todo = []
        for i, task in enumerate(tasks):
            if task.error is not None:
                deliver(i, TaskReport(task.source, 0, 0, (), 0.0, task.error))
            elif task.first >= len(task.outputs):
                deliver(i, TaskReport(task.source, 0, len(task.outputs), (), 0.0))
            else:
                todo.append((i, task))
        units = _units(todo, batch_size)
        if ray is not None:
            from prismstereo.jobs.distributed import run_on_ray

            def tally(i: int, rep: TaskReport) -> None:
                deliver(i, rep)
                bar.update(rep.written)

            workers = run_on_ray(units, runner, ray, batch_size, tally) if units else 1
        elif workers == 1 or len(units) <= 1:
            workers = 1
            runner.progress = bar.update
            try:
                for unit in units:
                    for i, rep in unit_reports(runner, unit, batch_size):
                        deliver(i, rep)
            finally:
                runner.progress = None
        else:
            _run_workers(units, runner, workers, batch_size, deliver, bar)
    _remove_partials(tasks)
    ordered = tuple(reports[i] for i in range(len(tasks)))
    return JobSummary(ordered, time.perf_counter() - start, workers)


def _remove_partials(tasks: Sequence[Task]) -> None:
    """Remove the temporary files a killed worker left beside the outputs (``io.replacing``'s names)."""
    folders: dict[Path, set[str]] = {}
    for task in tasks:
        for files in task.outputs:
            for path in files:
                if path is not None:
                    folders.setdefault(path.parent, set()).add(path.stem)
    for folder, stems in folders.items():
        if folder.is_dir():
            for stray in folder.glob(".*.partial*"):
                if partial_stem(stray) in stems:
                    stray.unlink(missing_ok=True)


def _run_workers(units: list[list[tuple[int, Task]]], runner: Runner, workers: int, batch_size: int,
                 deliver: Callable[[int, TaskReport], None], bar: Any) -> None:
    """:func:`run` over ``workers`` processes (the module docstring)."""
    runner.prepare()
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    threads = max(1, (os.cpu_count() or 1) // workers)
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(method), initializer=_start_worker,
                             initargs=(runner, threads)) as pool:
        futures = {pool.submit(_work, unit, batch_size): unit for unit in units}
        for future in as_completed(futures):
            try:
                done = future.result()
            except BrokenProcessPool as exc:
                done = [(i, TaskReport(t.source, 0, 0, (), 0.0, f"its worker process died ({exc})"))
                        for i, t in futures[future]]
            for i, rep in done:
                deliver(i, rep)
                bar.update(rep.written)
