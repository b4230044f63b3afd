"""Timing for `tofcut bench`: warm-up, repetitions, medians, percentiles and fitted exponents.

Times are the CPU time of the calling thread (`time.thread_time`), not wall time: every
stage runs on one thread with one-thread numeric libraries, so this is what the work costs
one core, and other processes on a shared machine (which take the core away, and make wall
time swing by 2× and more) do not count against it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np

CLOCK = time.thread_time
"""The clock of every time `tofcut bench` reports, unless it says otherwise."""


def median_seconds(
    fn: Callable[[], object], *, warmup: int, repeats: int, number: int = 1
) -> float:
    """Median over `repeats` of the mean CPU time of `number` calls, after `warmup` calls."""
    if repeats < 1 or number < 1:
        raise ValueError("repeats and number must be at least 1")
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = CLOCK()
        for _ in range(number):
            fn()
        times.append((CLOCK() - start) / number)
    return float(np.median(times))


def percentiles_ms(
    seconds: Sequence[float], qs: Sequence[float] = (50, 90, 99)
) -> dict[str, float]:
    """{"p50": ms, ...} of a list of durations."""
    values = np.percentile(np.asarray(seconds), qs) * 1e3
    return {f"p{q:g}": float(v) for q, v in zip(qs, values, strict=True)}


def fit_exponent(xs: Sequence[float], ys: Sequence[float]) -> float:
    """k in y ≈ a·x^k, by least squares on log-log (needs two or more distinct x > 0)."""
    if len(xs) != len(ys) or len(set(xs)) < 2:
        raise ValueError("an exponent needs two or more distinct points")
    if min(xs) <= 0 or min(ys) <= 0:
        raise ValueError("an exponent needs positive values")
    slope, _ = np.polyfit(np.log(np.asarray(xs, float)), np.log(np.asarray(ys, float)), 1)
    return float(slope) if math.isfinite(slope) else math.nan
