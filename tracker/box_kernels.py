"""Where an image's nonzero pixels lie, compiled (see `tofcut.tracker.compiled`): the box round
them, or the list of them, for the kernels that need go over only those (what stands out, or
is tracked, is a small part of a frame). A loop over a whole frame with much work inside a
test at each pixel compiles poorly (some 25 µs a frame for the tests alone): listing the
pixels first in a loop of its own, then working through the list, is a third of that.
"""

from __future__ import annotations

import numpy as np

from tofcut.tracker.compiled import helper


@helper
def box_of(image: np.ndarray) -> tuple[int, int, int, int]:
    """The box round the nonzero pixels of a 2-D bool or integer image: first row, row past
    the last, first column, column past the last; (0, 0, 0, 0) where there are none. Each
    row's pixels and columns are or-ed together without a branch, for the compiler to
    vectorise (a test at each pixel costs a whole frame some 10 µs)."""
    h, w = image.shape
    if h == 0 or w == 0:
        return 0, 0, 0, 0
    columns = np.zeros(w, image.dtype)
    r0, r1 = h, 0
    for v in range(h):
        row = image[v, 0]
        for u in range(w):
            row |= image[v, u]
            columns[u] |= image[v, u]
        if row:
            r0 = min(r0, v)
            r1 = v + 1
    if r1 == 0:
        return 0, 0, 0, 0
    c0, c1 = w, 0
    for u in range(w):
        if columns[u]:
            c0 = min(c0, u)
            c1 = u + 1
    return r0, r1, c0, c1


@helper
def pixels_of(image: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """How many nonzero pixels a 2-D bool or integer image has, and (longer arrays whose
    first that many are) their rows and columns, in row-major order."""
    h, w = image.shape
    rows = np.empty(h * w, np.int64)
    cols = np.empty(h * w, np.int64)
    n = 0
    for v in range(h):
        for u in range(w):
            if image[v, u]:
                rows[n], cols[n] = v, u
                n += 1
    return n, rows, cols
