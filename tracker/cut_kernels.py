"""The joint cut's per-pixel loops, compiled (see `tofcut.tracker.compiled`): the ties
between neighbours (eq. (7)'s Potts weights), the pixels left free and what each label costs
there, the cut's nodes and edges, the background's cost, and the parts of the Potts problem.

The one operation numba would round differently from numpy, `exp` (numpy has its own
vectorised one), is left to numpy: `tie_exponents` and `tie_weights` go either side of it.
"""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, I64, B
from tofcut.tracker.compiled import (
    B_1D,
    B_2D,
    F64_1D,
    F64_2D,
    F64_3D,
    I64_1D,
    I64_2D,
    helper,
    kernel,
)
from tofcut.tracker.components_kernels import parts
from tofcut.tracker.neighbours import DU, DV, FACTORS
from tofcut.tracker.stats_kernels import (
    insert_sorted,
    median3,
    median3_from_columns,
    sorted_column,
)


@kernel((F64_3D, B_2D, B_2D, 1.0))
def tie_exponents(xyz: F64, valid: B, near: B, two_sigma2: float) -> F64:
    """−|D_p − D_q|² / 2σ² of each pair of valid neighbours p, q (q along one of the
    neighbours' OFFSETS from p) with p or q in `near`, in the order `tie_weights` takes
    them."""
    h, w = valid.shape
    out = np.empty(4 * h * w)
    n = 0
    for v0 in range(h):
        for u0 in range(w):
            if not near[v0, u0]:
                continue
            for k in range(4):
                dv, du = DV[k], DU[k]
                for side in range(2):  # the pair where (v0, u0) is first, then second
                    v, u = (v0, u0) if side == 0 else (v0 - dv, u0 - du)
                    v2, u2 = v + dv, u + du
                    if not (v >= 0 and v2 < h and min(u, u2) >= 0 and max(u, u2) < w):
                        continue
                    if side == 1 and near[v, u]:
                        continue  # done from there
                    if valid[v, u] and valid[v2, u2]:
                        a = xyz[v, u, 0] - xyz[v2, u2, 0]
                        b = xyz[v, u, 1] - xyz[v2, u2, 1]
                        c = xyz[v, u, 2] - xyz[v2, u2, 2]
                        out[n] = -(a**2 + b**2 + c**2) / two_sigma2
                        n += 1
    return out[:n]


@kernel((F64_1D, B_2D, B_2D, 1.0))
def tie_weights(exps: F64, valid: B, near: B, smoothness: float) -> tuple[F64, F64]:
    """Eq. (7)'s Potts weight of every neighbour pair with an end in `near`, (4, H, W) by
    the first pixel and direction (λ·factor·exp of the pair's exponent where both pixels
    are valid, taken from `exps` in `tie_exponents`' order; λ·factor where either is
    invalid; unset elsewhere), and the sum of each `near` pixel's weights, added up in the
    order right, left, down, up, down-right, up-left, down-left, up-right (0 elsewhere)."""
    h, w = valid.shape
    wt = np.empty((4, h, w))
    total = np.zeros((h, w))
    n = 0
    # the pairs walked as `tie_exponents` walks them, on purpose: numpy's exp goes between
    # the two (see the module's docstring), and `exps` is read in that order
    for v0 in range(h):
        for u0 in range(w):
            if not near[v0, u0]:
                continue
            for k in range(4):
                sf = smoothness * FACTORS[k]
                dv, du = DV[k], DU[k]
                for side in range(2):
                    v, u = (v0, u0) if side == 0 else (v0 - dv, u0 - du)
                    v2, u2 = v + dv, u + du
                    if not (v >= 0 and v2 < h and min(u, u2) >= 0 and max(u, u2) < w):
                        continue
                    if side == 1 and near[v, u]:
                        continue  # done from there
                    if valid[v, u] and valid[v2, u2]:
                        wt[k, v, u] = sf * exps[n]
                        n += 1
                    else:
                        wt[k, v, u] = sf
    for v in range(h):
        for u in range(w):
            if not near[v, u]:
                continue
            acc = 0.0
            for k in range(4):
                dv, du = DV[k], DU[k]
                if v + dv < h and 0 <= u + du < w:
                    acc += wt[k, v, u]
                if v - dv >= 0 and 0 <= u - du < w:
                    acc += wt[k, v - dv, u - du]
            total[v, u] = acc
    return wt, total


@kernel((B_2D, F64_2D, F64_2D, F64_3D, F64_2D, 1.0))
def free_pixels(
    valid: B, u0: F64, total: F64, xyz: F64, noise: F64, object_cost: float
) -> tuple[B, I64, I64, F64, F64, F64]:
    """The pixels some labelling of their neighbours could give an object, valid with
    object_cost − u0 ≤ total (the sum of their ties): the mask, and in row-major order
    (`np.nonzero`) their rows, columns, 3D points, range noise and u0 + total."""
    h, w = valid.shape
    free = np.zeros((h, w), np.bool_)
    n = 0
    for v in range(h):
        for u in range(w):
            if valid[v, u] and object_cost - u0[v, u] <= total[v, u]:
                free[v, u] = True
                n += 1
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    points = np.empty((n, 3))
    at = np.empty(n)
    ceiling = np.empty(n)
    m = 0
    for v in range(h):
        for u in range(w):
            if free[v, u]:
                rows[m], cols[m] = v, u
                points[m, 0], points[m, 1], points[m, 2] = xyz[v, u, 0], xyz[v, u, 1], xyz[v, u, 2]
                at[m] = noise[v, u]
                ceiling[m] = u0[v, u] + total[v, u]
                m += 1
    return free, rows, cols, points, at, ceiling


@kernel((F64_2D, 1.0, 1.0, F64_2D, F64_2D, I64_1D, I64_1D, B_2D))
def object_costs(
    distance: F64, object_cost: float, beta: float, u0: F64, total: F64, rows: I64,
    cols: I64, free: B,
) -> F64:  # fmt: skip
    """Each track's cost at the pixels (rows, cols), object_cost + β·distance; a pixel stays
    `free` (in place) only where the cheapest is within its ties of u0:
    cost.min(axis=0) − u0 ≤ total (a nan anywhere is the minimum, as numpy's)."""
    k, n = distance.shape
    cost = np.empty((k, n))
    for m in range(n):
        best = np.inf
        for t in range(k):
            c = object_cost + beta * distance[t, m]
            cost[t, m] = c
            best = c if t == 0 else (best if (best <= c or best != best) else c)
        v, u = rows[m], cols[m]
        free[v, u] = best - u0[v, u] <= total[v, u]
    return cost


@kernel((B_2D, I64_1D, I64_1D, F64_2D, F64_2D, F64_2D, F64_2D))
def cut_nodes(
    free: B, rows: I64, cols: I64, u0: F64, total: F64, cost: F64, floor: F64
) -> tuple[I64, I64, I64, F64, F64, F64]:
    """The cut's nodes, every `free` pixel in row-major order: each pixel's node (−1 if
    none), the nodes' rows and columns, their costs (labels × nodes: u0 for the background,
    `cost` for the tracks where it was measured, at the pixels (rows, cols), else 0: an
    invalid pixel), the tracks' costs from the shape alone (`floor` there, else nan) and
    the nodes' total ties."""
    h, w = free.shape
    k = cost.shape[0]
    n = np.count_nonzero(free)
    index = np.empty((h, w), np.int64)
    where_v = np.empty(n, np.int64)
    where_u = np.empty(n, np.int64)
    a = 0
    for v in range(h):
        for u in range(w):
            index[v, u] = a if free[v, u] else -1
            if free[v, u]:
                where_v[a], where_u[a] = v, u
                a += 1
    unary = np.empty((k + 1, n))
    least = np.empty((k, n))
    ties = np.empty(n)
    measured = np.empty(n, np.int64)  # each node's place in (rows, cols), −1 if none
    c = 0  # the next of (rows, cols), both in row-major order
    for a in range(n):
        v, u = where_v[a], where_u[a]
        unary[0, a] = u0[v, u]
        ties[a] = total[v, u]
        while c < rows.size and (rows[c] < v or (rows[c] == v and cols[c] < u)):
            c += 1
        measured[a] = c if c < rows.size and rows[c] == v and cols[c] == u else -1
    for t in range(k):  # row by row: each a run through memory
        for a in range(n):
            c = measured[a]
            unary[t + 1, a] = cost[t, c] if c >= 0 else 0.0
            least[t, a] = floor[t, c] if c >= 0 else np.nan
    return index, where_v, where_u, unary, least, ties


@kernel((I64_2D, F64_3D, I64_1D, I64_1D))
def free_edges(index: I64, wt: F64, rows: I64, cols: I64) -> tuple[I64, I64, F64]:
    """Edges (i, j, weight) between neighbouring free pixels (`index` ≥ 0: their node
    number; node n at (rows[n], cols[n]), in row-major order), direction by direction."""
    h, w = index.shape
    ei = np.empty(4 * rows.size, np.int64)
    ej = np.empty(4 * rows.size, np.int64)
    ew = np.empty(4 * rows.size)
    n = 0
    for k in range(4):
        dv, du = DV[k], DU[k]
        for a in range(rows.size):
            v2, u2 = rows[a] + dv, cols[a] + du
            if v2 < h and 0 <= u2 < w and index[v2, u2] >= 0:
                ei[n] = a
                ej[n] = index[v2, u2]
                ew[n] = wt[k, rows[a], cols[a]]
                n += 1
    return ei[:n], ej[:n], ew[:n]


@helper
def _with_fixed_ties(value: float, index: I64, wt: F64, v: int, u: int) -> float:
    """`value` plus the tie of pixel (v, u) to each fixed neighbour, added one by one in the
    order of `tie_weights`' sums."""
    h, w = index.shape
    for k in range(4):
        dv, du = DV[k], DU[k]
        if v + dv < h and 0 <= u + du < w and index[v + dv, u + du] < 0:
            value += wt[k, v, u]
        if v - dv >= 0 and 0 <= u - du < w and index[v - dv, u - du] < 0:
            value += wt[k, v - dv, u - du]
    return value


@kernel((F64_2D, I64_2D, F64_3D, I64_1D, I64_1D))
def add_fixed_ties(unary: F64, index: I64, wt: F64, rows: I64, cols: I64) -> None:
    """A free pixel (`index` ≥ 0: its node; node n at (rows[n], cols[n])) beside a fixed
    one pays the tie for any object label: add each such tie to rows 1.. of `unary`, in the
    order of `_with_fixed_ties`."""
    h, w = index.shape
    ties = np.empty(8)
    for node in range(rows.size):
        v, u = rows[node], cols[node]
        count = 0
        for k in range(4):
            dv, du = DV[k], DU[k]
            if v + dv < h and 0 <= u + du < w and index[v + dv, u + du] < 0:
                ties[count] = wt[k, v, u]
                count += 1
            if v - dv >= 0 and 0 <= u - du < w and index[v - dv, u - du] < 0:
                ties[count] = wt[k, v - dv, u - du]
                count += 1
        for label in range(1, unary.shape[0]):
            value = unary[label, node]
            for t in range(count):
                value += ties[t]
            unary[label, node] = value


@kernel((F64_1D, I64_2D, F64_3D, I64_1D, I64_1D))
def add_fixed_ties_at(values: F64, index: I64, wt: F64, vs: I64, us: I64) -> F64:
    """`add_fixed_ties` for one label's costs `values` at the pixels (vs, us)."""
    out = np.empty_like(values)
    for n in range(values.size):
        out[n] = _with_fixed_ties(values[n], index, wt, vs[n], us[n])
    return out


@kernel((I64_1D, I64_1D, F64_2D, F64_2D, F64_1D, 1.0))
def unmeasured_needed(
    labels: I64, cells: I64, unary: F64, least: F64, ties: F64, margin: float
) -> B:
    """Of the (track label, node) pairs (`labels`, `cells`), those whose cost was not measured
    (`least` holds its cost from the shape alone, not nan) and may still win the node: that
    cost within the node's `ties` (and `margin`) of the most any label it may hold costs,
    the background's or a measured, finite track cost (`unary`) of these pairs: numpy's
    `maximum.at` of them over the background's, then `least <= top + ties + margin`."""
    top = unary[0].copy()
    for m in range(labels.size):
        label, c = labels[m], cells[m]
        x = unary[label, c]
        if np.isnan(least[label - 1, c]) and np.isfinite(x):
            a = top[c]
            top[c] = a if (a >= x or a != a) else x  # numpy's maximum: a nan stays
    need = np.zeros(labels.size, np.bool_)
    for m in range(labels.size):
        label, c = labels[m], cells[m]
        floor = least[label - 1, c]
        if not np.isnan(floor):
            need[m] = floor <= top[c] + ties[c] + margin
    return need


@kernel((F64_2D, F64_2D, B_2D, F64_2D, B_2D, 1.0, 1.0, F64_1D, 1.0, 1.0, 1.0))
def background_cost(
    model: F64, sigma: F64, known: B, seen: F64, valid: B, noise_factor: float,
    loud_sigma: float, shares: F64, deadband: float, cap: float, unknown: float,
) -> F64:  # fmt: skip
    """Each pixel's cost for the background (see `JointCut.background_cost`): half the
    square of how far it stands in front of the scenery, in noise sigmas, less the
    deadband, at most `cap`; `unknown` where the scenery is not known. How far and its
    noise are `reference.weighed_nearness`'s, by the same arithmetic: where
    `noise_factor` sigmas are more than `loud_sigma`, the median of the nearness over the
    (2r+1)² window round the pixel (edges repeated) and `shares[r]` of the noise, r the
    smallest radius (1 to len(shares) − 1) that brings `noise_factor` of that noise to
    `loud_sigma` or below (the largest where none does)."""
    h, w = model.shape
    nearer = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            nearer[v, u] = model[v, u] - seen[v, u] if valid[v, u] and known[v, u] else 0.0
    out = np.empty((h, w))
    top = shares.size - 1
    window = np.empty((2 * top + 1) ** 2)
    # a row's columns of three, sorted (`sorted_column`): each made once per row, for the
    # 3×3 medians of the loud pixels beside it (the median is the same one value either way)
    columns = np.empty((w, 3))
    sorted_ok = np.zeros(w, np.bool_)
    made_for = np.full(w, -1, np.int64)
    for v in range(h):
        for u in range(w):
            usable = valid[v, u] and known[v, u]
            near, s = nearer[v, u], sigma[v, u]
            if usable and noise_factor * s > loud_sigma:
                r = 1
                while r < top and noise_factor * s * shares[r] > loud_sigma:
                    r += 1
                if r == 1:
                    left, right = max(u - 1, 0), min(u + 1, w - 1)
                    for c in (left, u, right):
                        if made_for[c] != v:
                            sorted_ok[c] = sorted_column(nearer, v, c, columns[c])
                            made_for[c] = v
                    if sorted_ok[left] and sorted_ok[u] and sorted_ok[right]:
                        near = median3_from_columns(columns[left], columns[u], columns[right])
                    else:  # a nan among them: placed as the insertion sort places it
                        near = median3(nearer, v, u, window)
                else:
                    near = _median_at(nearer, v, u, r, window)
                s = s * shares[r]
            z = (model[v, u] - (model[v, u] - near)) / s if usable else 0.0
            z = z - deadband
            z = z if (z >= 0.0 or z != z) else 0.0
            cost = 0.5 * z * z
            cost = cost if (cost <= cap or cost != cost) else cap
            out[v, u] = cost if known[v, u] else unknown
    return out


@helper
def _median_at(values: F64, v: int, u: int, r: int, window: F64) -> float:
    """The median of the (2r+1)² window round (v, u) in `values`, edges repeated (`window`
    room for its values): `scipy.ndimage.median_filter(values, 2r + 1, mode="nearest")`
    there."""
    h, w = values.shape
    k = 0
    for dv in range(-r, r + 1):
        for du in range(-r, r + 1):
            insert_sorted(window, k, values[min(max(v + dv, 0), h - 1), min(max(u + du, 0), w - 1)])
            k += 1
    return float(window[k // 2])


@helper
def _grouped(keys: I64, count: int) -> tuple[I64, I64]:
    """`np.argsort(keys, kind="stable")` of keys in [0, count), and where each key's run
    starts in it (`np.searchsorted(sorted keys, np.arange(count + 1))`): a counting sort,
    of each half of the keys side by side (few keys, many of each: two chains of counts
    to wait on, not one)."""
    n = keys.size
    half = (n + 1) // 2
    first = np.zeros(count, np.int64)  # of each key, how many in the first half
    second = np.zeros(count, np.int64)
    for m in range(n - half):
        first[keys[m]] += 1
        second[keys[half + m]] += 1
    if n % 2:
        first[keys[half - 1]] += 1
    bounds = np.zeros(count + 1, np.int64)
    for k in range(count):
        bounds[k + 1] = bounds[k] + first[k] + second[k]
    fill = bounds[:-1].copy()
    fill2 = fill + first
    order = np.empty(n, np.int64)
    for m in range(n - half):
        order[fill[keys[m]]] = m
        fill[keys[m]] += 1
        order[fill2[keys[half + m]]] = half + m
        fill2[keys[half + m]] += 1
    if n % 2:
        order[fill[keys[half - 1]]] = half - 1
    return order, bounds


@kernel((F64_2D, I64_1D, I64_1D, F64_1D))
def split_parts(
    unary: F64, i: I64, j: I64, ties: F64
) -> tuple[I64, I64, I64, I64, I64, I64, B, I64]:
    """The parts of a Potts problem (nodes joined by edges i, j; see `parts`) and who may
    win them: each node's part, the nodes and the edges grouped by part (order, bounds, as
    `_grouped`), each node's cheapest label (`np.argmin(unary, axis=0)`), (labels, parts)
    whether a label may win some node of the part: its cost within the node's `ties` of
    the cheapest (the background always may), and how many labels may in each part an
    edge joins (0 in the others)."""
    n_labels, n = unary.shape
    count, part_of = parts(n, i, j)
    order, bounds = _grouped(part_of, count)
    edge_order, edge_bounds = _grouped(part_of[i], count)
    chosen = np.empty(n, np.int64)
    can_win = np.zeros((n_labels, count), np.bool_)
    can_win[0] = True
    for v in range(n):
        best, at = unary[0, v], 0
        if not np.isnan(best):  # numpy's argmin and min: the first nan, if any
            for r in range(1, n_labels):
                x = unary[r, v]
                if np.isnan(x):
                    best, at = x, r
                    break
                if x < best:
                    best, at = x, r
        chosen[v] = at
        limit = best + ties[v]
        for r in range(1, n_labels):
            if unary[r, v] <= limit:
                can_win[r, part_of[v]] = True
    contenders = np.zeros(count, np.int64)
    for e in range(i.size):
        contenders[part_of[i[e]]] = 1
    for k in range(count):
        if contenders[k]:
            contenders[k] = can_win[:, k].sum()
    return part_of, order, bounds, edge_order, edge_bounds, chosen, can_win, contenders


@kernel((F64_2D, I64_1D, I64_1D, F64_1D, I64_1D, I64_1D, I64_1D, B_1D, B_2D))
def binary_parts(
    unary: F64, i: I64, j: I64, w: F64, part_of: I64, order: I64, edge_order: I64,
    binary: B, can_win: B,
) -> tuple[I64, I64, F64, I64, I64, F64]:  # fmt: skip
    """The nodes of the `binary` parts (in `order`), the one track that meets the background
    there (the first that `can_win` the node's part), their costs for the background and
    that track (2, nodes), and the edges between them (in `edge_order`; i, j numbered
    among those nodes, w)."""
    track = np.ones(binary.size, np.int64)
    for k in range(binary.size):
        if binary[k]:
            for r in range(1, can_win.shape[0]):
                if can_win[r, k]:
                    track[k] = r
                    break
    local = np.full(part_of.size, -1, np.int64)
    m = 0
    for v in order:
        if binary[part_of[v]]:
            local[v] = m
            m += 1
    nodes = np.empty(m, np.int64)
    label = np.empty(m, np.int64)
    pair = np.empty((2, m))
    for v in order:
        if local[v] >= 0:
            a = local[v]
            nodes[a] = v
            label[a] = track[part_of[v]]
            pair[0, a] = unary[0, v]
            pair[1, a] = unary[label[a], v]
    ei = np.empty(i.size, np.int64)
    ej = np.empty(i.size, np.int64)
    ew = np.empty(i.size)
    k = 0
    for e in edge_order:
        if binary[part_of[i[e]]]:
            ei[k], ej[k], ew[k] = local[i[e]], local[j[e]], w[e]
            k += 1
    return nodes, label, pair, ei[:k], ej[:k], ew[:k]
