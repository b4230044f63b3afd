"""Giving an object's outline back to its mask, compiled (see `tofcut.tracker.rims` and
`tofcut.tracker.compiled`)."""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, I64, U16, B
from tofcut.tracker.compiled import B_2D, F64_2D, U16_2D, helper, kernel

NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))
"""A pixel's four neighbours, (row, column) offsets, in the order they are weighed."""
NOTCH = 5
"""Of a pixel's eight neighbours, how many one track must hold for the pixel to be a notch in
its outline."""


@kernel((U16_2D, F64_2D, B_2D, F64_2D, B_2D))
def rims(labels: U16, seen: F64, valid: B, scenery: F64, known: B) -> tuple[U16, I64, I64]:
    """`labels` with the outlines given back (`mixed_rim`, then `notches`), and the pixels
    given, in row-major order."""
    rimmed = mixed_rim(labels, seen, valid, scenery, known)
    out = notches(rimmed)
    h, w = labels.shape
    n = 0
    for v in range(h):
        for u in range(w):
            n += out[v, u] != labels[v, u]
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    k = 0
    for v in range(h):
        for u in range(w):
            if out[v, u] != labels[v, u]:
                rows[k] = v
                cols[k] = u
                k += 1
    return out, rows, cols


@helper
def mixed_rim(labels: U16, seen: F64, valid: B, scenery: F64, known: B) -> U16:
    """`labels` with each valid background pixel over known scenery given to the track of a
    valid 4-neighbour when its range lies past the midpoint from the scenery's range to that
    neighbour's (the neighbour in front of the scenery; of several, the one whose range is
    nearest its own, the first in `NEIGHBOURS` on a tie)."""
    h, w = labels.shape
    out = labels.copy()
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
            out[v, u] = take
    return out


@helper
def notches(labels: U16) -> U16:
    """`labels` with each background pixel of which `NOTCH` of the eight neighbours or more
    hold one track given to it (all at once: as `labels` stood)."""
    h, w = labels.shape
    out = labels.copy()
    for v in range(h):
        for u in range(w):
            if labels[v, u] != 0:
                continue
            # five of eight is a majority: the one label a majority vote may leave
            held = 0
            votes = 0
            for y in range(max(v - 1, 0), min(v + 2, h)):
                for x in range(max(u - 1, 0), min(u + 2, w)):
                    if y == v and x == u:
                        continue
                    if votes == 0:
                        held = labels[y, x]
                        votes = 1
                    elif labels[y, x] == held:
                        votes += 1
                    else:
                        votes -= 1
            if held == 0:
                continue
            n = 0
            for y in range(max(v - 1, 0), min(v + 2, h)):
                for x in range(max(u - 1, 0), min(u + 2, w)):
                    n += labels[y, x] == held
            if n >= NOTCH:
                out[v, u] = held
    return out
