"""Robust statistics, compiled (see `tofcut.tracker.compiled`): numpy's median of an array
(and whether it lies above a value), 3×3 medians over an image, and for a track's points the
two middle values of a percentile and the centring of their covariance.
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


SAMPLED = 512
"""Values from which `median` brackets the middle by a sample before selecting."""
SAMPLE_STEP = 16
"""Every SAMPLE_STEP-th value is in the sample."""


@kernel((F64_1D,))
def median(values: F64) -> float:
    """`np.median(values)` of a 1-D array (at least one value): the middle value, or the
    mean of the middle two, (a + b) / 2; nan if any is. (`tracker.paper.energy.median`, by
    histogram, is the faster on a whole frame's values; this one on a few thousand.) Of
    SAMPLED values or more, the middle is bracketed by a sorted sample first and only the
    values between its brackets are selected from (all of them where it misses)."""
    n = values.size
    for x in values:
        if np.isnan(x):
            return np.nan
    low_rank = (n - 1) // 2  # the middle two (one, of an odd count)
    a = values.copy() if n < SAMPLED else np.empty(n)
    offset = 0  # how many values lie below a's
    if n >= SAMPLED:
        sample = np.sort(values[::SAMPLE_STEP])
        m = sample.size
        margin = 2 * int(np.sqrt(m)) + 2  # a miss is many standard deviations out
        at = low_rank // SAMPLE_STEP
        lo = sample[at - margin] if at - margin >= 0 else -np.inf
        hi = sample[at + margin] if at + margin < m else np.inf
        below = count = 0
        for x in values:  # without branches: which way a value goes is unforeseeable
            below += x < lo
            a[count] = x
            count += (x >= lo) & (x <= hi)
        if below <= low_rank and below + count > n // 2:
            a, offset = a[:count], below
        else:  # missed: all of them
            a[:] = values
    upper = _select(a, 0, a.size - 1, n // 2 - offset)
    if n % 2:
        return upper
    # the largest of those left below the upper middle
    lower = float(a[0])
    for x in a[1 : n // 2 - offset]:
        lower = max(lower, x)
    return (lower + upper) / 2.0


@kernel((F64_1D, 1))
def order_pair(values: F64, k: int) -> tuple[bool, float, float]:
    """The k-th and (k + 1)-th smallest of `values` (0 ≤ k, k + 1 < its size), as
    `np.partition(values, [k, k + 1])[k : k + 2]` has them, where every value is finite;
    False (and nans) where one is not."""
    for x in values:
        if not np.isfinite(x):
            return False, np.nan, np.nan
    a = values.copy()
    lo = _select(a, 0, a.size - 1, k)
    # quickselect leaves nothing smaller than the k-th after it
    hi = a[k + 1]
    for x in a[k + 2 :]:
        hi = min(hi, x)
    return True, lo, float(hi)


@kernel((F64_2D,))
def centred(points: F64) -> F64:
    """(N, 3) C-ordered `points` less their mean, as `np.cov` centres them: numpy sums the
    columns of `points.T` (an F-ordered array) point by point, in order, from 0."""
    n = points.shape[0]
    mean = np.zeros(3)
    for m in range(n):
        for a in range(3):
            mean[a] += points[m, a]
    mean /= n
    out = np.empty((n, 3))
    for m in range(n):
        for a in range(3):
            out[m, a] = points[m, a] - mean[a]
    return out


@kernel((F64_1D, 1.0))
def median_above(values: F64, x: float) -> bool:
    """`median(values) > x` (False on no value or a nan), in one pass and without a copy:
    the middle value is above `x` where more than half the values are; of an even count,
    with exactly half above, the two middle values are the largest not above and the
    smallest above, and their mean, (a + b) / 2 as `median` takes it, is compared."""
    n = values.size
    above = 0
    low, high = -np.inf, np.inf  # the largest value not above x, the smallest above
    for y in values:
        if np.isnan(y):
            return False
        if y > x:
            above += 1
            high = min(high, y)
        else:
            low = max(low, y)
    if n == 0 or above < n - n // 2:
        return False
    if n % 2 or above > n // 2:
        return True
    return (low + high) / 2.0 > x


@helper
def insert_sorted(window: F64, k: int, x: float) -> None:
    """Put `x` in order into `window`, whose first `k` values are in ascending order: one step
    of an insertion sort, for a window's median as it fills."""
    while k > 0 and window[k - 1] > x:
        window[k] = window[k - 1]
        k -= 1
    window[k] = x


@helper
def _median9(
    p0: float,
    p1: float,
    p2: float,
    p3: float,
    p4: float,
    p5: float,
    p6: float,
    p7: float,
    p8: float,
) -> float:
    """The median of nine values, none nan, by the sorting network that leaves it in the
    middle (Paeth's, as in N. Devillard's "Fast median search", 1998): 19 compare-exchanges."""
    p1, p2 = min(p1, p2), max(p1, p2)
    p4, p5 = min(p4, p5), max(p4, p5)
    p7, p8 = min(p7, p8), max(p7, p8)
    p0, p1 = min(p0, p1), max(p0, p1)
    p3, p4 = min(p3, p4), max(p3, p4)
    p6, p7 = min(p6, p7), max(p6, p7)
    p1, p2 = min(p1, p2), max(p1, p2)
    p4, p5 = min(p4, p5), max(p4, p5)
    p7, p8 = min(p7, p8), max(p7, p8)
    p3 = max(p0, p3)
    p5 = min(p5, p8)
    p4, p7 = min(p4, p7), max(p4, p7)
    p6 = max(p3, p6)
    p4 = max(p1, p4)
    p2 = min(p2, p5)
    p4 = min(p4, p7)
    p4, p2 = min(p4, p2), max(p4, p2)
    p4 = max(p6, p4)
    return min(p4, p2)


@kernel((F64_2D, B_2D))
def median3_at(values: F64, where: B) -> F64:
    """`values` with each pixel in `where` replaced by the median of its 3×3 neighbourhood
    (`scipy.ndimage.median_filter(values, 3, mode="nearest")` there): by the sorting network
    of nine (the median is the one value either way), or, where a nan is among them, by
    the insertion sort that places it as before."""
    h, w = values.shape
    out = values.copy()
    window = np.empty(9)
    for v in range(h):
        for u in range(w):
            if where[v, u]:
                out[v, u] = median3(values, v, u, window)
    return out


@helper
def median3(values: F64, v: int, u: int, window: F64) -> float:
    """The median of the 3×3 neighbourhood of (v, u) in `values`, edges repeated
    (`median3_at`'s, `window` nine values' room to work in)."""
    h, w = values.shape
    k = 0
    nan = False
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            x = values[min(max(v + dv, 0), h - 1), min(max(u + du, 0), w - 1)]
            window[k] = x
            nan |= np.isnan(x)
            k += 1
    if nan:
        for k in range(9):
            insert_sorted(window, k, window[k])
        return float(window[4])
    return _median9(
        window[0], window[1], window[2], window[3], window[4], window[5], window[6], window[7],
        window[8],
    )  # fmt: skip


@helper
def sorted_column(values: F64, v: int, u: int, column: F64) -> bool:
    """Into `column`, the values of (v − 1, u), (v, u) and (v + 1, u) in `values` (rows at
    the edges repeated) in ascending order, where none is nan (whether none is)."""
    h = values.shape[0]
    a, b, c = values[max(v - 1, 0), u], values[v, u], values[min(v + 1, h - 1), u]
    if np.isnan(a) or np.isnan(b) or np.isnan(c):
        return False
    a, b = min(a, b), max(a, b)
    b, c = min(b, c), max(b, c)
    a, b = min(a, b), max(a, b)
    column[0], column[1], column[2] = a, b, c
    return True


@helper
def median3_from_columns(left: F64, middle: F64, right: F64) -> float:
    """The median of nine values, none nan, given as three sorted columns of three (as
    `sorted_column` leaves them): the median of the largest of the smallest, the median of
    the middles and the smallest of the largest (Paeth's 3×3 median by columns)."""
    low = max(left[0], middle[0], right[0])
    high = min(left[2], middle[2], right[2])
    a, b, c = left[1], middle[1], right[1]
    mid = max(min(a, b), min(max(a, b), c))
    return float(max(min(low, mid), min(max(low, mid), high)))


@helper
def median_in(values: F64, where: B, v: int, u: int, r: int, window: F64) -> float:
    """The median of the values of `where`'s pixels in the (2r+1)×(2r+1) window round (v, u)
    (one of them; `window` room for their values): one surface's noise quietened without
    taking in what lies beyond its edge."""
    h, w = values.shape
    k = 0
    for y in range(max(v - r, 0), min(v + r + 1, h)):
        for x in range(max(u - r, 0), min(u + r + 1, w)):
            if where[y, x]:
                insert_sorted(window, k, values[y, x])
                k += 1
    return float(window[k // 2] if k % 2 else 0.5 * (window[k // 2 - 1] + window[k // 2]))
