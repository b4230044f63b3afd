"""Statistics for the tracker: robust spreads (`MAD_TO_SIGMA`, `robust_sigma`), and `np.cov`
and `np.percentile` for its point clouds: the same numbers (the same operations in the same
order), without the argument handling that costs them more than the arithmetic on a few
hundred points. Compiled ones (the median, 3×3 medians, and the steps of these two that are
not numpy's BLAS) are in `stats_kernels`."""

from __future__ import annotations

import math

import numpy as np

from tofcut._types import F64
from tofcut.tracker import stats_kernels

MAD_TO_SIGMA = 1.4826
"""A normal variable's σ over its median absolute deviation."""


def robust_sigma(deviations: F64) -> float:
    """σ of values that scatter normally, from their deviations from their centre:
    `MAD_TO_SIGMA` × the median absolute deviation (a few outliers do not move it)."""
    return MAD_TO_SIGMA * float(np.median(np.abs(deviations)))


def covariance(points: F64) -> F64:
    """`np.cov(points.T)` of (N, 3) C-ordered float points, N ≥ 2: centred in one compiled
    pass (`x` laid out as numpy's, for the same BLAS product)."""
    x = stats_kernels.centred(points).T
    c: F64 = np.dot(x, x.T.conj())
    c *= np.true_divide(1, x.shape[1] - 1)
    return c


def percentile(values: F64, q: float) -> float:
    """`np.percentile(values, q)` (linear interpolation) of a 1-D float array."""
    n = values.size
    fraction = np.true_divide(q, 100)
    virtual = (n - 1) * fraction
    if n == 0 or virtual >= n - 1:
        return float(np.percentile(values, q))  # empty, or the largest: numpy's own rules
    below = max(0, math.floor(virtual))
    gamma = np.float64(virtual - below)
    finite, lo, hi = stats_kernels.order_pair(values, below)
    if not finite:
        return float(np.percentile(values, q))  # inf or nan: numpy's own rules
    diff = np.float64(hi) - np.float64(lo)
    return float(hi - diff * (1 - gamma) if gamma >= 0.5 else lo + diff * gamma)
