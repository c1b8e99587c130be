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
