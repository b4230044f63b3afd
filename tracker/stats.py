"""Statistics for the tracker: robust spreads (`MAD_TO_SIGMA`, `robust_sigma`), and `np.cov`
and `np.percentile` for its point clouds: the same numbers (the same operations in the same
order), without the argument handling that costs them more than the arithmetic on a few
hundred points. Compiled ones (the median, 3×3 medians) are in `stats_kernels`."""

from __future__ import annotations

import math

import numpy as np

from tofcut._types import F64

MAD_TO_SIGMA = 1.4826
"""A normal variable's σ over its median absolute deviation."""


def robust_sigma(deviations: F64) -> float:
    """σ of values that scatter normally, from their deviations from their centre:
    `MAD_TO_SIGMA` × the median absolute deviation (a few outliers do not move it)."""
    return MAD_TO_SIGMA * float(np.median(np.abs(deviations)))


def covariance(points: F64) -> F64:
    """`np.cov(points.T)` of (N, 3) float points, N ≥ 2."""
    x = np.array(points.T, dtype=np.float64)
    x -= (np.add.reduce(x, axis=1) / x.shape[1])[:, None]  # x.mean(axis=1), as numpy takes it
    c: F64 = np.dot(x, x.T.conj())
    c *= np.true_divide(1, x.shape[1] - 1)
    return c


def percentile(values: F64, q: float) -> float:
    """`np.percentile(values, q)` (linear interpolation) of a 1-D float array."""
    n = values.size
    if n == 0 or not math.isfinite(float(values.max())) or not math.isfinite(values.min()):
        return float(np.percentile(values, q))  # empty, inf or nan: numpy's own rules
    fraction = np.true_divide(q, 100)
    virtual = (n - 1) * fraction
    if virtual >= n - 1:
        return float(np.max(values))
    below = max(0, math.floor(virtual))
    gamma = np.float64(virtual - below)
    lo, hi = np.partition(values, [below, below + 1])[below : below + 2]
    diff = hi - lo
    return float(hi - diff * (1 - gamma) if gamma >= 0.5 else lo + diff * gamma)
