"""Timing for `tofcut bench`: warm-up, repetitions, medians, percentiles and fitted exponents."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np


def median_seconds(
    fn: Callable[[], object], *, warmup: int, repeats: int, number: int = 1
) -> float:
    """Median over `repeats` of the mean time of `number` calls, after `warmup` calls."""
    if repeats < 1 or number < 1:
        raise ValueError("repeats and number must be at least 1")
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - start) / number)
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
