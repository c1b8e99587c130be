"""Running a depth job (:func:`run`): one progress bar, failures per input, on any executor."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from prismstereo.errors import check_int
from prismstereo.io import partial_stem
from prismstereo.jobs.plan import Task, TaskReport

if TYPE_CHECKING:  # the executors and the pipeline import torch: imported by run() as it starts
    from prismstereo.jobs.executors import Executor
    from prismstereo.jobs.pipeline import Pipeline

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


def run(tasks: Sequence[Task], pipeline: Pipeline, *, executor: Executor | None = None, batch_size: int = 1,
        progress: bool = True, report: Callable[[TaskReport], None] | None = None) -> JobSummary:
    """Run a job's tasks (:func:`~prismstereo.jobs.plan.plan`) with one progress bar over all outputs to write.

    Tasks with a planning error and tasks with nothing left are reported without running; a failing input is
    reported and the others run. The files written are the same whichever executor runs them.

    Args:
        tasks: from :func:`~prismstereo.jobs.plan.plan`.
        pipeline: the predictor and write options.
        executor: where the units run (:mod:`prismstereo.jobs.executors`): this process (None, the default),
            :class:`~prismstereo.jobs.executors.WorkerProcesses` or
            :class:`~prismstereo.jobs.ray_executor.RayCluster`.
        batch_size: captures per model call (>= 1).
        progress: show the bar (stderr, where it is a terminal).
        report: called with each task's report as it completes (default: print its lines).

    Returns:
        JobSummary: the reports in input order, the wall time, the processes that ran them.

    Raises:
        OptionError: ``batch_size`` not an int >= 1.

    Example:
        >>> summary = run(plan(["a.png", "b.png"], Path("out"), WriteOptions()), pipeline)  # doctest: +SKIP
        >>> [report.written for report in summary.reports]  # doctest: +SKIP
        [1, 1]
    """
    from tqdm import tqdm

    from prismstereo.jobs.executors import InProcess, units

    check_int(batch_size, "batch_size", 1)
    executor = executor or InProcess()
    start = time.perf_counter()
    reports: dict[int, TaskReport] = {}
    total = sum(len(t.outputs) - t.first for t in tasks if t.error is None)
    # one bar on a terminal; none where stderr is a file or a pipe (a log would hold every redraw)
    with tqdm(total=total, unit="map", file=sys.stderr, desc="depth", disable=None if progress else True) as bar:

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
        work = units(todo, batch_size)
        try:
            workers = executor.run(work, pipeline, batch_size, deliver, bar.update) if work else 1
        finally:  # also when interrupted: only whole files are left
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
