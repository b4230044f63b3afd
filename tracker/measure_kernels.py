"""Measuring tracks from their masks, compiled (see `tofcut.tracker.compiled`): each mask's
box and points, their mean and extent, how many pixels of each piece each track holds, and
each piece's box and size.
"""

from __future__ import annotations

import math

import numpy as np

from tofcut._types import F64, I32, I64, U16, B
from tofcut.tracker.box_kernels import box_of, pixels_of
from tofcut.tracker.compiled import B_2D, F64_2D, F64_3D, I32_2D, I64_1D, I64_2D, U16_2D, kernel


@kernel((U16_2D, F64_3D, I64_1D))
def label_points(
    labels: U16, xyz: F64, ids: I64
) -> tuple[I64, I64, F64]:  # fmt: skip
    """Each id's pixels in `labels`: (ids, 4) their box (first row, row past the last, first
    column, column past the last, as `ndimage.find_objects`; 0s where none), where each
    id's points start (ids + 1) in the (N, 3) 3D points of them all, each id's in
    row-major order (`xyz[box][labels[box] == id]`)."""
    top = 0
    for k in range(ids.size):
        top = max(top, ids[k])
    slot = np.full(top + 1, -1, np.int64)
    for k in range(ids.size):
        slot[ids[k]] = k
    boxes = np.zeros((ids.size, 4), np.int64)
    starts = np.zeros(ids.size + 1, np.int64)
    r0, r1, c0, c1 = box_of(labels)
    which = np.full((r1 - r0, c1 - c0), -1, np.int64)  # each pixel's id's index, in the box
    for v in range(r0, r1):
        for u in range(c0, c1):
            lab = labels[v, u]
            k = slot[lab] if lab <= top else -1
            if k < 0:
                continue
            which[v - r0, u - c0] = k
            if starts[k + 1] == 0:
                boxes[k, 0], boxes[k, 2] = v, u
            boxes[k, 1] = v + 1
            boxes[k, 2] = min(boxes[k, 2], u)
            boxes[k, 3] = max(boxes[k, 3], u + 1)
            starts[k + 1] += 1
    for k in range(ids.size):
        starts[k + 1] += starts[k]
    points = np.empty((starts[-1], 3))
    fill = starts[:-1].copy()
    for v in range(r0, r1):
        for u in range(c0, c1):
            k = which[v - r0, u - c0]
            if k < 0:
                continue
            points[fill[k], 0], points[fill[k], 1] = xyz[v, u, 0], xyz[v, u, 1]
            points[fill[k], 2] = xyz[v, u, 2]
            fill[k] += 1
    return boxes, starts, points


@kernel((F64_2D,))
def point_stats(points: F64) -> tuple[F64, F64, F64]:
    """`points.mean(axis=0)`, `.min(axis=0)` and `.max(axis=0)` of (N, 3) C-ordered points,
    N ≥ 1, in one pass: numpy sums such an array's rows in order, then divides by N, and a
    nan anywhere in a column is that column's min and max."""
    total = np.zeros(3)
    lo = points[0].copy()
    hi = points[0].copy()
    for n in range(points.shape[0]):
        for a in range(3):
            x = points[n, a]
            total[a] += x
            lo[a] = lo[a] if (lo[a] <= x or lo[a] != lo[a]) else x
            hi[a] = hi[a] if (hi[a] >= x or hi[a] != hi[a]) else x
    return total / points.shape[0], lo, hi


@kernel((U16_2D, I32_2D, I64_1D, 1, 1))
def held_pieces(
    labels: U16, pieces: I32, row: I64, rows: int,
    n_pieces: int,
) -> I64:  # fmt: skip
    """(rows, n_pieces) how many pixels of each piece > 0 each label holds, by the label's
    row (`row[label]`), for the rows > 0: the bincount of row[labels]·n_pieces + pieces
    there (0 in row 0 and column 0: counting the many pixels with neither one by one would
    wait on each count before the next)."""
    out = np.zeros((rows, n_pieces), np.int64)
    count, at_v, at_u = pixels_of(pieces)
    for i in range(count):
        v, u = at_v[i], at_u[i]
        r, k = row[labels[v, u]], pieces[v, u]
        if r > 0 and k > 0:
            out[r, k] += 1
    return out


@kernel((U16_2D, I32_2D, 1))
def touching(labels: U16, pieces: I32, reach: int) -> tuple[I64, I64, I32]:
    """Per label > 0 of `labels`, the pieces > 0 of `pieces` with a pixel at most `reach`
    pixels from one of its pixels across and down (an 8-connected `reach`-step dilation):
    the labels that have some, ascending, where each one's start in the pieces (and, last,
    where the last ends), and the pieces, ascending for each label. From the pieces' pixels,
    which are few beside the tracks' (they stand out and no track took them): one pass to
    count the pairs, one to write them."""
    h, w = labels.shape
    count, at_v, at_u = pixels_of(pieces)
    pairs = np.empty(0, np.int64)
    for write in (False, True):
        n = 0
        for k in range(count):
            v, u = at_v[k], at_u[k]
            r = pieces[v, u]
            if r <= 0:
                continue
            for v2 in range(max(v - reach, 0), min(v + reach + 1, h)):
                for u2 in range(max(u - reach, 0), min(u + reach + 1, w)):
                    lab = labels[v2, u2]
                    if lab == 0:
                        continue
                    if write:
                        pairs[n] = np.int64(lab) << 32 | np.int64(r)
                    n += 1
        if not write:
            pairs = np.empty(n, np.int64)
    pairs = np.unique(pairs)
    ids = np.empty(pairs.size, np.int64)
    starts = np.empty(pairs.size + 1, np.int64)
    k = 0
    for n in range(pairs.size):
        if n == 0 or pairs[n] >> 32 != pairs[n - 1] >> 32:
            ids[k] = pairs[n] >> 32
            starts[k] = n
            k += 1
    starts[k] = pairs.size
    return ids[:k].copy(), starts[: k + 1].copy(), (pairs & 0xFFFFFFFF).astype(np.int32)


@kernel((B_2D, 1, 1, I32_2D, I64_1D, I64_2D, F64_3D, 1.0))
def seams(
    mask: B, top: int, left: int, pieces: I32, near: I64, boxes: I64, xyz: F64,
    step_m: float,
) -> tuple[I64, I64, I64]:  # fmt: skip
    """For each piece `near[k]` of `pieces`, within its box `boxes[k]` (first row, row past
    the last, first column, column past the last): its pixels there; and of the pairs of
    side-by-side pixels (across or down) in that box grown by one of which one is in `mask`
    (a mask whose first pixel is the frame's (top, left)) and the other in the piece, how
    many, and how many of them have 3D points within `step_m` of each other (numpy's
    `norm`: the square root of the squares summed in order x, y, z)."""
    h, w = pieces.shape
    mh, mw = mask.shape
    sizes = np.zeros(near.size, np.int64)
    meet = np.zeros(near.size, np.int64)
    joined = np.zeros(near.size, np.int64)
    for k in range(near.size):
        r = near[k]
        size = 0  # counted in a register, not through the array
        for v in range(boxes[k, 0], boxes[k, 1]):
            for u in range(boxes[k, 2], boxes[k, 3]):
                size += pieces[v, u] == r
        sizes[k] = size
        r0, r1 = max(boxes[k, 0] - 1, 0), min(boxes[k, 1] + 1, h)
        c0, c1 = max(boxes[k, 2] - 1, 0), min(boxes[k, 3] + 1, w)
        for dv, du in ((0, 1), (1, 0)):
            for v in range(r0, r1 - dv):
                for u in range(c0, c1 - du):
                    v2, u2 = v + dv, u + du
                    a1 = 0 <= v - top < mh and 0 <= u - left < mw and mask[v - top, u - left]
                    a2 = 0 <= v2 - top < mh and 0 <= u2 - left < mw and mask[v2 - top, u2 - left]
                    if not ((a1 and pieces[v2, u2] == r) or (a2 and pieces[v, u] == r)):
                        continue
                    x = xyz[v, u, 0] - xyz[v2, u2, 0]
                    y = xyz[v, u, 1] - xyz[v2, u2, 1]
                    z = xyz[v, u, 2] - xyz[v2, u2, 2]
                    meet[k] += 1
                    joined[k] += math.sqrt(x * x + y * y + z * z) <= step_m
    return sizes, meet, joined


@kernel((I32_2D,))
def piece_boxes(pieces: I32) -> I64:
    """(n, 4) the box of each piece 1..n of `pieces` (n the largest number in it; first row,
    row past the last, first column, column past the last, as `ndimage.find_objects` has
    them; 0s for a number no pixel holds)."""
    count, at_v, at_u = pixels_of(pieces)
    n = 0
    for i in range(count):
        n = max(n, pieces[at_v[i], at_u[i]])
    boxes = np.zeros((n, 4), np.int64)
    seen = np.zeros(n, np.bool_)
    for i in range(count):
        v, u = at_v[i], at_u[i]
        r = pieces[v, u] - 1
        if r < 0:
            continue
        if not seen[r]:
            seen[r] = True
            boxes[r, 0], boxes[r, 2], boxes[r, 3] = v, u, u + 1
        boxes[r, 1] = v + 1
        boxes[r, 2] = min(boxes[r, 2], u)
        boxes[r, 3] = max(boxes[r, 3], u + 1)
    return boxes


@kernel((I32_2D,))
def piece_sizes(pieces: I32) -> I64:
    """`np.bincount(pieces.ravel())` of pieces numbered from 0 up: each number's pixels (0
    the rest: counting the many 0s one by one would wait on each count before the next)."""
    h, w = pieces.shape
    count, at_v, at_u = pixels_of(pieces)
    n = 0
    for i in range(count):
        n = max(n, pieces[at_v[i], at_u[i]])
    sizes = np.zeros(n + 1, np.int64)
    for i in range(count):
        sizes[pieces[at_v[i], at_u[i]]] += 1
    sizes[0] = h * w - count
    return sizes
