"""Giving an object's outline back to its mask, compiled (see `tofcut.tracker.rims` and
`tofcut.tracker.compiled`). Only pixels beside a track can change, and a frame's tracks are a
small part of it: the work goes through the list of those pixels, not the whole frame
(`tofcut.tracker.box_kernels`)."""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, I64, U16, B
from tofcut.tracker.box_kernels import pixels_of
from tofcut.tracker.compiled import B_2D, F64_2D, I64_1D, I64_2D, U16_2D, helper, kernel

NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))
"""A pixel's four neighbours, (row, column) offsets, in the order they are weighed."""
NOTCH = 5
"""Of a pixel's eight neighbours, how many one track must hold for the pixel to be a notch in
its outline."""


@kernel((U16_2D, F64_2D, B_2D, F64_2D, B_2D, I64_1D, I64_2D, I64_1D))
def rims(
    labels: U16, seen: F64, valid: B, scenery: F64, known: B, ids: I64, boxes: I64, pixels: I64
) -> tuple[U16, I64, I64]:
    """`labels` with the outlines given back (`mixed_rim`, then `notch`), and the image boxes
    (u0, v0, u1, v1) and pixel counts of the tracks `ids` (`boxes` and `pixels` before) as
    the pixels given grow them."""
    h, w = labels.shape
    out = labels.copy()
    n, rows, cols = pixels_of(labels)
    beside, m = _beside(labels, rows[:n], cols[:n])
    given = np.empty(h * w, np.int64)  # row * w + column
    k = 0
    for i in range(m):
        v, u = beside[i] // w, beside[i] % w
        take = mixed_rim(labels, seen, valid, scenery, known, v, u)
        if take != 0:
            out[v, u] = take
            given[k] = beside[i]
            k += 1
    rimmed = given[:k].copy()
    # a notch takes in one of the four beside it: beside the tracks as the rim left them
    extra, e = _beside(out, rimmed // w, rimmed % w)
    notched = out.copy()
    for candidates, count in ((beside, m), (extra, e)):
        for i in range(count):
            v, u = candidates[i] // w, candidates[i] % w
            if out[v, u] != 0 or notched[v, u] != 0:
                continue
            take = notch(out, v, u)
            if take != 0:
                notched[v, u] = take
                given[k] = candidates[i]
                k += 1
    slot = np.full(int(ids.max()) + 1 if ids.size else 1, -1, np.int64)
    for j in range(ids.size):
        slot[ids[j]] = j
    grown = boxes.copy()
    counts = pixels.copy()
    for i in range(k):
        v, u = given[i] // w, given[i] % w
        j = slot[notched[v, u]] if notched[v, u] < slot.size else -1
        if j < 0:
            continue
        if counts[j] == 0:  # a box round nothing yet
            grown[j, 0], grown[j, 1], grown[j, 2], grown[j, 3] = u, v, u + 1, v + 1
        counts[j] += 1
        grown[j, 0] = min(grown[j, 0], u)
        grown[j, 1] = min(grown[j, 1], v)
        grown[j, 2] = max(grown[j, 2], u + 1)
        grown[j, 3] = max(grown[j, 3], v + 1)
    return notched, grown, counts


@helper
def _beside(labels: U16, rows: I64, cols: I64) -> tuple[I64, int]:
    """The background pixels beside (4-neighbours of) the pixels (rows, cols) of `labels`,
    each once, as row * width + column, and how many."""
    h, w = labels.shape
    marked = np.zeros((h, w), np.bool_)
    out = np.empty(4 * rows.size, np.int64)
    m = 0
    for i in range(rows.size):
        for dv, du in NEIGHBOURS:
            y = rows[i] + dv
            x = cols[i] + du
            if 0 <= y < h and 0 <= x < w and labels[y, x] == 0 and not marked[y, x]:
                marked[y, x] = True
                out[m] = y * w + x
                m += 1
    return out, m


@helper
def mixed_rim(labels: U16, seen: F64, valid: B, scenery: F64, known: B, v: int, u: int) -> int:
    """The track a background pixel (v, u) of `labels` is the mixed rim of, or 0: where it is
    valid over known scenery, the track of a valid 4-neighbour when its range lies past the
    midpoint from the scenery's range to that neighbour's (the neighbour in front of the
    scenery; of several, the one whose range is nearest its own, the first in `NEIGHBOURS`
    on a tie)."""
    h, w = labels.shape
    if not valid[v, u] or not known[v, u]:
        return 0
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
    return take


@helper
def notch(labels: U16, v: int, u: int) -> int:
    """The track that holds `NOTCH` or more of the eight neighbours of pixel (v, u) of
    `labels`, or 0."""
    h, w = labels.shape
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
        return 0
    n = 0
    for y in range(max(v - 1, 0), min(v + 2, h)):
        for x in range(max(u - 1, 0), min(u + 2, w)):
            n += labels[y, x] == held
    return int(held) if n >= NOTCH else 0
