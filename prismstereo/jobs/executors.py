"""Where a job's units of work run, behind one interface (:class:`Executor`): this process (:class:`InProcess`),
worker processes (:class:`WorkerProcesses`) or Ray actors (:class:`~prismstereo.jobs.ray_executor.RayCluster`).

A unit is a batch of captures or one sequence, with the indices of its tasks (:func:`units`). Every executor runs a
unit on a :class:`~prismstereo.jobs.pipeline.Pipeline` (:func:`work`) and hands each task's report back as it
completes; the files written are the same whichever runs them. A worker gets its share of the cores
(:func:`~prismstereo.threads.thread_plan`) and opens its own sessions
(:meth:`~prismstereo.jobs.pipeline.Pipeline.for_process`).
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Protocol

from prismstereo.errors import check_int
from prismstereo.jobs.pipeline import Pipeline, TaskReport
from prismstereo.jobs.plan import Task
from prismstereo.threads import thread_plan, torch_threads

__all__ = ["Deliver", "Executor", "InProcess", "Tick", "Unit", "WorkerProcesses", "unit_reports", "units", "work"]

Unit = list[tuple[int, Task]]
Deliver = Callable[[int, TaskReport], None]
Tick = Callable[[int], None]


class Executor(Protocol):
    """Runs a job's units on a pipeline.

    Methods:
        ``run(units, pipeline, batch_size, deliver, tick) -> int``: runs every unit, calls ``deliver(index,
        report)`` for each task as it completes and ``tick(n)`` as outputs are written; returns the number of
        processes (or actors) that ran them.
    """

    def run(self, units: list[Unit], pipeline: Pipeline, batch_size: int, deliver: Deliver, tick: Tick) -> int: ...


def units(tasks: Sequence[tuple[int, Task]], batch_size: int) -> list[Unit]:
    """Consecutive captures in batches of ``batch_size``, each sequence on its own.

    Example:
        >>> from prismstereo.jobs.plan import Outputs
        >>> from pathlib import Path
        >>> capture = Task("a.png", False, (Outputs(Path("a.npy")),))
        >>> [len(u) for u in units([(0, capture), (1, capture), (2, capture)], 2)]
        [2, 1]
    """
    out: list[Unit] = []
    for item in tasks:
        last = out[-1] if out else None
        if item[1].sequence or last is None or last[0][1].sequence or len(last) == batch_size:
            out.append([item])
        else:
            last.append(item)
    return out


def unit_reports(pipeline: Pipeline, unit: Unit, batch_size: int) -> Iterator[tuple[int, TaskReport]]:
    """A unit's (index, report) pairs as its tasks complete: a batch of captures or one sequence.

    Example:
        >>> list(unit_reports(pipeline, [(0, plan(["a.png"], Path("out"), WriteOptions())[0])], 1))  # doctest: +SKIP
    """
    if unit[0][1].sequence:
        yield unit[0][0], pipeline.run_sequence(unit[0][1])
        return
    yield from zip((i for i, _ in unit), pipeline.run_captures([t for _, t in unit], batch_size), strict=True)


def work(pipeline: Pipeline, unit: Unit, batch_size: int) -> list[tuple[int, TaskReport]]:
    """A worker's unit (:func:`unit_reports`) on its pipeline's threads: the (index, report) pairs.

    Example:
        >>> work(pipeline, [(0, plan(["a.png"], Path("out"), WriteOptions())[0])], 1)  # doctest: +SKIP
    """
    with torch_threads(pipeline.threads.torch):
        return list(unit_reports(pipeline, unit, batch_size))


class InProcess:
    """This process, with its reader and writer threads beside the model.

    Example:
        >>> InProcess().workers
        1
    """

    workers = 1

    def run(self, units: list[Unit], pipeline: Pipeline, batch_size: int, deliver: Deliver, tick: Tick) -> int:
        """Run ``units`` here (:class:`Executor`); ``tick`` is called as each output is written."""
        pipeline.progress = tick
        try:
            for unit in units:
                for i, report in unit_reports(pipeline, unit, batch_size):
                    deliver(i, report)
        finally:
            pipeline.progress = None
        return 1


_WORKER: dict[str, Pipeline] = {}


def _start_worker(pipeline: Pipeline, threads: int) -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent stops them
    _WORKER["pipeline"] = pipeline.for_process(threads)


def _work(unit: Unit, batch_size: int) -> list[tuple[int, TaskReport]]:
    return work(_WORKER["pipeline"], unit, batch_size)


class WorkerProcesses:
    """``workers`` processes, each with its share of the cores (:func:`~prismstereo.threads.thread_plan`) and its
    own sessions; forked where the platform allows, so the model and the graphs are the parent's, else spawned with a
    copy of the pipeline. A worker that dies fails its unit's inputs, not the job.

    Args:
        workers: processes (>= 1).

    Raises:
        OptionError: ``workers`` not an int >= 1.

    Example:
        >>> WorkerProcesses(2).workers
        2
    """

    def __init__(self, workers: int) -> None:
        check_int(workers, "workers", 1)
        self.workers = workers

    def run(self, units: list[Unit], pipeline: Pipeline, batch_size: int, deliver: Deliver, tick: Tick) -> int:
        """Run ``units`` over the worker processes (:class:`Executor`); one unit runs here, without workers."""
        if len(units) <= 1:
            return InProcess().run(units, pipeline, batch_size, deliver, tick)
        method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
        threads = thread_plan(self.workers).cores
        with ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context(method),
                                 initializer=_start_worker, initargs=(pipeline, threads)) as pool:
            futures = {pool.submit(_work, unit, batch_size): unit for unit in units}
            try:
                for future in as_completed(futures):
                    try:
                        done = future.result()
                    except BrokenProcessPool as exc:
                        done = [(i, TaskReport(t.source, 0, 0, (), 0.0, f"its worker process died ({exc})"))
                                for i, t in futures[future]]
                    for i, report in done:
                        deliver(i, report)
                        tick(report.written)
            except KeyboardInterrupt:  # stop now: the workers' unfinished files are temporary ones (removed)
                for process in list(getattr(pool, "_processes", {}).values()):
                    process.terminate()
                pool.shutdown(wait=False, cancel_futures=True)
                raise
        return self.workers
