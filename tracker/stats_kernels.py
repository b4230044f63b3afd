"""Robust statistics, compiled (see `tofcut.tracker.compiled`): numpy's median of an array,
and 3×3 medians over an image.
"""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, B
from tofcut.tracker.compiled import B_2D, F64_1D, F64_2D, helper, kernel


@helper
def _select(a: F64, lo: int, hi: int, k: int) -> float:
    """The k-th smallest of a[lo:hi + 1] (no nan), partly reordering it (quickselect)."""
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return float(a[k])
    return float(a[k])


@kernel((F64_1D,))
def median(values: F64) -> float:
    """`np.median(values)` of a 1-D array (at least one value): the middle value, or the
    mean of the middle two, (a + b) / 2; nan if any is. (`tracker.paper.energy.median`, by
    histogram, is the faster on a whole frame's values; this one on a few hundred.)"""
    a = values.copy()
    n = a.size
    for x in a:
        if np.isnan(x):
            return np.nan
    upper = _select(a, 0, n - 1, n // 2)
    if n % 2:
        return upper
    lower = float(a[0])  # the largest of those left below the upper middle
    for x in a[1 : n // 2]:
        lower = max(lower, x)
    return (lower + upper) / 2.0


@helper
def _insert(window: F64, k: int, x: float) -> None:
    """Put `x` in order into `window`, whose first `k` values are in ascending order: one step
    of an insertion sort, for a window's median as it fills."""
    while k > 0 and window[k - 1] > x:
        window[k] = window[k - 1]
        k -= 1
    window[k] = x


@kernel((F64_2D, B_2D))
def median3_at(values: F64, where: B) -> F64:
    """`values` with each pixel in `where` replaced by the median of its 3×3 neighbourhood
    (`scipy.ndimage.median_filter(values, 3, mode="nearest")` there)."""
    h, w = values.shape
    out = values.copy()
    window = np.empty(9)
    for v in range(h):
        for u in range(w):
            if not where[v, u]:
                continue
            k = 0
            for dv in (-1, 0, 1):
                for du in (-1, 0, 1):
                    x = values[min(max(v + dv, 0), h - 1), min(max(u + du, 0), w - 1)]
                    _insert(window, k, x)
                    k += 1
            out[v, u] = window[4]
    return out


@kernel((F64_2D, B_2D, B_2D))
def median3_within(values: F64, where: B, loud: B) -> F64:
    """`values` with each pixel of `where` that is `loud` replaced by the median of its 3×3
    neighbours in `where` (itself included): one surface's noise quietened without taking
    in what lies beyond its edge."""
    h, w = values.shape
    out = values.copy()
    window = np.empty(9)
    for v in range(h):
        for u in range(w):
            if not (where[v, u] and loud[v, u]):
                continue
            k = 0
            for dv in (-1, 0, 1):
                for du in (-1, 0, 1):
                    y, x = v + dv, u + du
                    if not (0 <= y < h and 0 <= x < w and where[y, x]):
                        continue
                    _insert(window, k, values[y, x])
                    k += 1
            out[v, u] = window[k // 2] if k % 2 else 0.5 * (window[k // 2 - 1] + window[k // 2])
    return out
