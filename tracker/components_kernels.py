"""Connected components, compiled (see `tofcut.tracker.compiled`): a union-find forest, the
4-connected pieces of a mask (as `scipy.ndimage.label`) and the connected parts of a graph
(as scipy's `connected_components`). The paper's cut contracts its graph with the same
union-find (`tofcut.tracker.paper.contraction`).
"""

from __future__ import annotations

import numpy as np

from tofcut._types import I32, I64, B
from tofcut.tracker.box_kernels import pixels_of
from tofcut.tracker.compiled import B_2D, helper, kernel


@helper
def root(parent: I32 | I64, a: int) -> int:
    """The root of `a` in a union-find forest, halving the path on the way."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@helper
def number_sets(parent: I32 | I64, first: int, base: int) -> I64:
    """Each element from `first` on numbered by its set, from `base` up in the order of each
    set's first element (every set's root is its smallest element)."""
    out = np.zeros(parent.size, np.int64)
    count = 0
    for k in range(first, parent.size):
        r = root(parent, k)
        if r == k:
            out[k] = base + count
            count += 1
        else:
            out[k] = out[r]
    return out


@kernel((B_2D,))
def label_pieces(body: B) -> I32:
    """`scipy.ndimage.label(body)[0]`: the 4-connected pieces of `body`, numbered from 1 in
    the order of each one's first pixel in row-major order (0 elsewhere). Only `body`'s
    pixels are gone over, listed first."""
    h, w = body.shape
    out = np.zeros((h, w), np.int32)
    count, at_v, at_u = pixels_of(body)
    parent = np.zeros(count + 2, np.int32)
    n = 0  # labels so far
    for i in range(count):
        v, u = at_v[i], at_u[i]
        up = out[v - 1, u] if v > 0 else 0
        left = out[v, u - 1] if u > 0 else 0
        if up == 0 and left == 0:
            n += 1
            parent[n] = n
            out[v, u] = n
        elif up == 0 or left == 0 or up == left:
            out[v, u] = max(up, left)
        else:
            a, b = root(parent, up), root(parent, left)
            parent[max(a, b)] = min(a, b)  # a piece's root is its first label
            out[v, u] = left
    final = number_sets(parent[: n + 1], 1, 1)
    for i in range(count):
        v, u = at_v[i], at_u[i]
        out[v, u] = final[out[v, u]]
    return out


@helper
def parts(n: int, i: I64, j: I64) -> tuple[int, I64]:
    """Connected parts of n nodes joined by edges (i, j): how many, and each node's part,
    numbered in the order of each part's first node (as scipy's connected_components)."""
    parent = np.arange(n)
    for e in range(i.size):
        a, b = root(parent, i[e]), root(parent, j[e])
        if a != b:
            parent[max(a, b)] = min(a, b)
    part_of = number_sets(parent, 0, 0)
    return (int(part_of.max()) + 1 if n else 0), part_of
