"""Shared timing helper of the benchmark scripts."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def times_ms(fn: Callable[[], object], repeats: int = 5) -> list[float]:
    """Wall times (ms) of ``repeats`` calls of ``fn`` after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return times


def median_ms(fn: Callable[[], object], repeats: int = 5) -> float:
    """Median wall time (ms) of ``repeats`` calls of ``fn`` after one warm-up call."""
    return statistics.median(times_ms(fn, repeats))


def interleaved_ms(fns: dict[str, Callable[[], object]], rounds: int = 9, gap_s: float = 0.1) -> dict[str, list[float]]:
    """Wall times (ms) of each function over ``rounds`` rounds that call every function once, in the given order
    on even rounds and reversed on odd ones, with a pause of ``gap_s`` before each call; one warm-up call each.

    On a shared VM the speed of the host drifts between phases within minutes, and not equally for every kind
    of code (single-threaded OpenCV and 2-thread onnxruntime swing in different phases): times taken block by
    block compare different phases. Round by round, times of the same round
    compare like with like; the ratio of two methods is then best read as the median of their per-round ratios
    (:func:`paired_ratio`). The pause lets a previous run's spinning threads (onnxruntime's, OpenMP's) go idle
    before the next call: without it the second of two onnxruntime sessions run back to back is the slower.
    """
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    names = list(fns)
    for r in range(rounds):
        for name in names if r % 2 == 0 else names[::-1]:
            time.sleep(gap_s)
            t0 = time.perf_counter()
            fns[name]()
            times[name].append((time.perf_counter() - t0) * 1e3)
    return times


def paired_ratio(times: list[float], reference: list[float]) -> float:
    """Median over rounds of ``times[i] / reference[i]`` (same-round ratios of :func:`interleaved_ms`)."""
    return statistics.median(t / r for t, r in zip(times, reference, strict=True))
