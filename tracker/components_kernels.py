"""Connected components, compiled (see `tofcut.tracker.compiled`): a union-find forest, the
4-connected pieces of a mask (as `scipy.ndimage.label`), the 8-connected parts of every
track's mask at once, and the connected parts of a graph (as scipy's
`connected_components`). The paper's cut contracts its graph with the same
union-find (`tofcut.tracker.paper.contraction`).
"""

from __future__ import annotations

import numpy as np

from tofcut._types import I32, I64, U16, B
from tofcut.tracker.box_kernels import pixels_of
from tofcut.tracker.compiled import B_2D, U16_2D, helper, kernel


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


@kernel((U16_2D,))
def label_regions(labels: U16) -> I32:
    """Each label's 8-connected regions: `scipy.ndimage.label(labels == k, EIGHT)` for every
    k > 0 at once, numbered from 1 in the order of each region's first pixel in row-major
    order (0 where `labels` is 0): each track's mask in its parts."""
    h, w = labels.shape
    out = np.zeros((h, w), np.int32)
    parent = np.zeros(h * w + 1, np.int32)
    n = 0  # regions so far
    for v in range(h):
        for u in range(w):
            k = labels[v, u]
            if k == 0:
                continue
            here = 0
            # the neighbours gone over already: left, and the three above
            for dv, du in ((0, -1), (-1, -1), (-1, 0), (-1, 1)):
                vv, uu = v + dv, u + du
                if vv < 0 or uu < 0 or uu >= w or labels[vv, uu] != k:
                    continue
                r = out[vv, uu]
                if here == 0:
                    here = r
                else:
                    a, b = root(parent, here), root(parent, r)
                    if a != b:
                        parent[max(a, b)] = min(a, b)  # a region's root is its first label
            if here == 0:
                n += 1
                parent[n] = n
                here = n
            out[v, u] = here
    final = number_sets(parent[: n + 1], 1, 1)
    for v in range(h):
        for u in range(w):
            if out[v, u]:
                out[v, u] = final[out[v, u]]
    return out


@kernel((U16_2D,))
def region_sizes(labels: U16) -> tuple[I32, I64, I64]:
    """Each label's 8-connected regions (`label_regions`), numbered from 1, and of each the
    label it belongs to and its pixels (entry 0 is no region)."""
    regions = label_regions(labels)
    h, w = labels.shape
    n = 0
    for v in range(h):
        for u in range(w):
            n = max(n, regions[v, u])
    owner = np.zeros(n + 1, np.int64)
    sizes = np.zeros(n + 1, np.int64)
    for v in range(h):
        for u in range(w):
            r = regions[v, u]
            if r:
                owner[r] = labels[v, u]
                sizes[r] += 1
    return regions, owner, sizes


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
