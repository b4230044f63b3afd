"""Giving the mixed pixels of an object's rim to it, compiled (see `tofcut.tracker.rims` and
`tofcut.tracker.compiled`)."""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, I64, U16, B
from tofcut.tracker.compiled import B_2D, F64_2D, U16_2D, kernel

NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))
"""A pixel's four neighbours, (row, column) offsets, in the order they are weighed."""


@kernel((U16_2D, F64_2D, B_2D, F64_2D, B_2D))
def rims(labels: U16, seen: F64, valid: B, scenery: F64, known: B) -> tuple[U16, I64, I64]:
    """`labels` with each valid background pixel over known scenery given to the track of a
    valid 4-neighbour when its range lies past the midpoint from the scenery's range to that
    neighbour's (the neighbour in front of the scenery; of several, the one whose range is
    nearest its own, the first in `NEIGHBOURS` on a tie), and the pixels given, in
    row-major order."""
    h, w = labels.shape
    out = labels.copy()
    rows = np.empty(h * w, np.int64)
    cols = np.empty(h * w, np.int64)
    n = 0
    for v in range(h):
        for u in range(w):
            if labels[v, u] != 0 or not valid[v, u] or not known[v, u]:
                continue
            r = seen[v, u]
            bg = scenery[v, u]
            best = np.inf
            take = 0
            for dv, du in NEIGHBOURS:
                y = v + dv
                x = u + du
                if y < 0 or y >= h or x < 0 or x >= w:
                    continue
                k = labels[y, x]
                if k == 0 or not valid[y, x]:
                    continue
                r_k = seen[y, x]
                if r_k < bg and bg - r > 0.5 * (bg - r_k):
                    gap = abs(r - r_k)
                    if gap < best:
                        best = gap
                        take = k
            if take != 0:
                out[v, u] = take
                rows[n] = v
                cols[n] = u
                n += 1
    return out, rows[:n], cols[:n]
