"""The tracker's per-pixel loops, compiled (numba, one thread): neighbour ties, the graph of
the pixels left free, distances from the tracks, the 3D steps that split surfaces, the
background model's arithmetic, and the graphs of the α-expansion moves.

Each kernel does the same floating-point operations in the same order as the numpy
expressions it replaces (`tofcut.tracker.reference` holds those), with numpy's rules for
division by zero, so the tracker's output does not change. The one operation numba would
round differently, `exp` (numpy has its own vectorised one), is left to numpy:
`tie_exponents` and `tie_weights` go either side.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from tofcut._types import F64

B = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]
F32 = npt.NDArray[np.float32]

NEIGHBOURS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, 1 / math.sqrt(2)), (1, -1, 1 / math.sqrt(2)))
"""Half of the 8-neighbourhood as (dv, du, weight factor); diagonals count 1/√2."""
_DV = np.array([d[0] for d in NEIGHBOURS], np.int64)
_DU = np.array([d[1] for d in NEIGHBOURS], np.int64)
FACTORS = np.array([d[2] for d in NEIGHBOURS])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def tie_exponents(xyz: F64, valid: B, near: B, two_sigma2: float) -> F64:
    """−|D_p − D_q|² / 2σ² of each pair of valid neighbours p, q (q in a direction of
    NEIGHBOURS from p) with p or q in `near`, in the order `tie_weights` takes them."""
    h, w = valid.shape
    out = np.empty(4 * h * w)
    n = 0
    for v0 in range(h):
        for u0 in range(w):
            if not near[v0, u0]:
                continue
            for k in range(4):
                dv, du = _DV[k], _DU[k]
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
    for v0 in range(h):
        for u0 in range(w):
            if not near[v0, u0]:
                continue
            for k in range(4):
                sf = smoothness * FACTORS[k]
                dv, du = _DV[k], _DU[k]
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
                dv, du = _DV[k], _DU[k]
                if v + dv < h and 0 <= u + du < w:
                    acc += wt[k, v, u]
                if v - dv >= 0 and 0 <= u - du < w:
                    acc += wt[k, v - dv, u - du]
            total[v, u] = acc
    return wt, total


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
    index = np.full((h, w), -1, np.int64)
    n = 0
    for v in range(h):
        for u in range(w):
            if free[v, u]:
                index[v, u] = n
                n += 1
    where_v = np.empty(n, np.int64)
    where_u = np.empty(n, np.int64)
    unary = np.zeros((k + 1, n))
    least = np.full((k, n), np.nan)
    ties = np.empty(n)
    c = 0  # the next of (rows, cols), both in row-major order
    for v in range(h):
        for u in range(w):
            a = index[v, u]
            if a < 0:
                continue
            where_v[a], where_u[a] = v, u
            unary[0, a] = u0[v, u]
            ties[a] = total[v, u]
            while c < rows.size and (rows[c] < v or (rows[c] == v and cols[c] < u)):
                c += 1
            if c < rows.size and rows[c] == v and cols[c] == u:
                for t in range(k):
                    unary[t + 1, a] = cost[t, c]
                    least[t, a] = floor[t, c]
    return index, where_v, where_u, unary, least, ties


@numba.njit(cache=True, nogil=True, error_model="numpy")
def free_edges(index: I64, wt: F64, rows: I64, cols: I64) -> tuple[I64, I64, F64]:
    """Edges (i, j, weight) between neighbouring free pixels (`index` ≥ 0: their node
    number; node n at (rows[n], cols[n]), in row-major order), direction by direction."""
    h, w = index.shape
    ei = np.empty(4 * rows.size, np.int64)
    ej = np.empty(4 * rows.size, np.int64)
    ew = np.empty(4 * rows.size)
    n = 0
    for k in range(4):
        dv, du = _DV[k], _DU[k]
        for a in range(rows.size):
            v2, u2 = rows[a] + dv, cols[a] + du
            if v2 < h and 0 <= u2 < w and index[v2, u2] >= 0:
                ei[n] = a
                ej[n] = index[v2, u2]
                ew[n] = wt[k, rows[a], cols[a]]
                n += 1
    return ei[:n], ej[:n], ew[:n]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _with_fixed_ties(value: float, index: I64, wt: F64, v: int, u: int) -> float:
    """`value` plus the tie of pixel (v, u) to each fixed neighbour, added one by one in the
    order of `tie_weights`' sums."""
    h, w = index.shape
    for k in range(4):
        dv, du = _DV[k], _DU[k]
        if v + dv < h and 0 <= u + du < w and index[v + dv, u + du] < 0:
            value += wt[k, v, u]
        if v - dv >= 0 and 0 <= u - du < w and index[v - dv, u - du] < 0:
            value += wt[k, v - dv, u - du]
    return value


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
            dv, du = _DV[k], _DU[k]
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def add_fixed_ties_at(values: F64, index: I64, wt: F64, vs: I64, us: I64) -> F64:
    """`add_fixed_ties` for one label's costs `values` at the pixels (vs, us)."""
    out = np.empty_like(values)
    for n in range(values.size):
        out[n] = _with_fixed_ties(values[n], index, wt, vs[n], us[n])
    return out


BUCKET = 8
"""Points of a surface cloud boxed together for `_nearest` to pass over at once."""
SLAB = 32
"""Points in a slab: a run of the cloud sorted along its widest axis (see `sort_surfaces`)."""


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _boxes(cloud: F64) -> F64:
    """(buckets, 2, 3) the low and high corner of each run of BUCKET points of `cloud`."""
    m = cloud.shape[0]
    out = np.empty(((m + BUCKET - 1) // BUCKET, 2, 3))
    for b in range(out.shape[0]):
        for a in range(3):
            lo, hi = np.inf, -np.inf
            for i in range(b * BUCKET, min(m, (b + 1) * BUCKET)):
                lo = min(lo, cloud[i, a])
                hi = max(hi, cloud[i, a])
            out[b, 0, a] = lo
            out[b, 1, a] = hi
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _slabs(boxes: F64, axis: int) -> F64:
    """(slabs, 2) the low and high end along `axis` of each slab's boxes."""
    per = SLAB // BUCKET
    out = np.empty(((boxes.shape[0] + per - 1) // per, 2))
    for s in range(out.shape[0]):
        out[s, 0] = boxes[s * per : (s + 1) * per, 0, axis].min()
        out[s, 1] = boxes[s * per : (s + 1) * per, 1, axis].max()
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _nearest(
    cloud: F64, boxes: F64, slabs: F64, axis: int, q: F64, bound2: float, hint: int
) -> tuple[float, int]:
    """Distance from q to the nearest point of `cloud` (in slabs along `axis`, as
    `sort_surfaces` leaves it, boxed by `_boxes` and `_slabs`) if its square is below
    bound2, else inf. Slabs are walked outward from q along the axis until their gap alone
    reaches the best square so far; a box is passed over where its distance from q, a
    lower bound of each of its points' (rounding included), does. So the minimum is the
    brute-force one. The walk starts from the square distance to point `hint` (the last
    query's nearest: queries come in pixel order); the nearest point's index comes back."""
    m = cloud.shape[0]
    x = q[0] - cloud[hint, 0]
    y = q[1] - cloud[hint, 1]
    z = q[2] - cloud[hint, 2]
    best = min(bound2, x * x + y * y + z * z)
    found = hint
    per = SLAB // BUCKET
    lo, hi = 0, slabs.shape[0] - 1
    while lo < hi:  # the first slab reaching up to q along the axis (or the last)
        mid = (lo + hi) // 2
        if slabs[mid, 1] < q[axis]:
            lo = mid + 1
        else:
            hi = mid
    for step in (1, -1):
        s = lo if step > 0 else lo - 1
        while 0 <= s < slabs.shape[0]:
            gap = slabs[s, 0] - q[axis] if step > 0 else q[axis] - slabs[s, 1]
            if gap > 0 and gap * gap >= best:
                break  # so are all slabs farther on along the axis
            for b in range(s * per, min(boxes.shape[0], (s + 1) * per)):
                floor = 0.0
                for a in range(3):
                    g = max(boxes[b, 0, a] - q[a], q[a] - boxes[b, 1, a], 0.0)
                    floor += g * g
                if floor < best:
                    for i in range(b * BUCKET, min(m, (b + 1) * BUCKET)):
                        x = q[0] - cloud[i, 0]
                        y = q[1] - cloud[i, 1]
                        z = q[2] - cloud[i, 2]
                        d = x * x + y * y + z * z
                        if d < best:
                            best = d
                            found = i
            s += step
    return (math.sqrt(best) if best < bound2 else np.inf), found


@numba.njit(cache=True, nogil=True, error_model="numpy")
def track_distances(
    points: F64,
    ceiling: F64,
    centres: F64,
    inverses: F64,
    clouds: F64,
    starts: I64,
    axes: I64,
    object_cost: float,
    beta: float,
    surface_weight: float,
    spread: F64,
    reach: float,
) -> tuple[F64, F64]:
    """(tracks, N) each point's distance from each track: (D−µ)ᵀΣ⁻¹(D−µ) in the track's
    shape (summed as numpy's einsum sums it) plus surface_weight·(d/spread)², d the
    distance from the track's surface (`clouds[starts[k]:starts[k+1]]`, sorted along
    `axes[k]`; inf beyond `reach`); inf where not a number. Where a track's cost from its
    shape alone, object_cost + β·shape, is above the point's `ceiling`, the surface is not
    looked at: the distance is inf, and the second array holds that cost from the shape
    alone (a lower bound of the point's cost; nan where the distance was measured)."""
    tracks, n_points = centres.shape[0], points.shape[0]
    out = np.empty((tracks, n_points))
    rough = np.full((tracks, n_points), np.nan)
    bound2 = reach * reach
    px, py, pz = points[:, 0].copy(), points[:, 1].copy(), points[:, 2].copy()
    shapes = np.empty(n_points)
    for k in range(tracks):
        cloud = clouds[starts[k] : starts[k + 1]]
        boxes = _boxes(cloud)
        slabs = _slabs(boxes, axes[k])
        hint = 0
        cx, cy, cz = centres[k, 0], centres[k, 1], centres[k, 2]
        m = inverses[k]
        m00, m01, m02, m10, m11, m12 = m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2]
        m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
        for n in range(n_points):  # a loop without branches, for the compiler to vectorise
            x, y, z = px[n] - cx, py[n] - cy, pz[n] - cz
            # term by term in einsum's order: i outer, j inner
            shape = 0.0
            shape += x * m00 * x
            shape += x * m01 * y
            shape += x * m02 * z
            shape += y * m10 * x
            shape += y * m11 * y
            shape += y * m12 * z
            shape += z * m20 * x
            shape += z * m21 * y
            shape += z * m22 * z
            shapes[n] = shape
        for n in range(n_points):
            shape = shapes[n]
            value = shape
            if surface_weight > 0:
                alone = object_cost + beta * shape
                if not alone <= ceiling[n]:
                    out[k, n] = np.inf
                    if np.isfinite(alone):
                        rough[k, n] = alone
                    continue
                near = np.inf
                q = points[n]
                if np.isfinite(q[0]) and np.isfinite(q[1]) and np.isfinite(q[2]):
                    near, hint = _nearest(cloud, boxes, slabs, axes[k], q, bound2, hint)
                value = shape + surface_weight * (near / spread[n]) ** 2
            out[k, n] = np.inf if np.isnan(value) else value
    return out, rough


@numba.njit(cache=True, nogil=True, error_model="numpy")
def label_points(
    labels: npt.NDArray[np.uint16], xyz: F64, ids: I64
) -> tuple[I64, I64, F64]:  # fmt: skip
    """Each id's pixels in `labels`: (ids, 4) their box (first row, row past the last, first
    column, column past the last, as `ndimage.find_objects`; 0s where none), where each
    id's points start (ids + 1) in the (N, 3) 3D points of them all, each id's in
    row-major order (`xyz[box][labels[box] == id]`)."""
    h, w = labels.shape
    top = 0
    for k in range(ids.size):
        top = max(top, ids[k])
    slot = np.full(top + 1, -1, np.int64)
    for k in range(ids.size):
        slot[ids[k]] = k
    boxes = np.zeros((ids.size, 4), np.int64)
    starts = np.zeros(ids.size + 1, np.int64)
    which = np.full((h, w), -1, np.int64)  # each pixel's id's index, for the second pass
    for v in range(h):
        for u in range(w):
            lab = labels[v, u]
            k = slot[lab] if lab <= top else -1
            if k < 0:
                continue
            which[v, u] = k
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
    for v in range(h):
        for u in range(w):
            k = which[v, u]
            if k < 0:
                continue
            points[fill[k], 0], points[fill[k], 1] = xyz[v, u, 0], xyz[v, u, 1]
            points[fill[k], 2] = xyz[v, u, 2]
            fill[k] += 1
    return boxes, starts, points


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def cut_at_steps(body: B, xyz: F64, rng: F64, step2: float, spread2: F64) -> B:
    """`body` less every pixel on the far side of a 3D step to its right or lower neighbour
    of more than √step2 and more than √(spread2 of the one + spread2 of the other) (of a
    step, the pixel with the larger range is the far one)."""
    h, w = body.shape
    out = body.copy()
    for v0 in range(h):
        for u0 in range(w):
            if not body[v0, u0]:
                continue  # only pairs with an end in the body can leave something out
            # its pairs right, down, left and up, each with its upper-left pixel first (the
            # one left out on a tie); a pair left or up from the body is met from there
            for v, u, v2, u2 in (
                (v0, u0, v0, u0 + 1), (v0, u0, v0 + 1, u0),
                (v0, u0 - 1, v0, u0), (v0 - 1, u0, v0, u0),
            ):  # fmt: skip
                if v < 0 or u < 0 or v2 >= h or u2 >= w or (v2 == v0 and u2 == u0 and body[v, u]):
                    continue
                a = xyz[v, u, 0] - xyz[v2, u2, 0]
                b = xyz[v, u, 1] - xyz[v2, u2, 1]
                c = xyz[v, u, 2] - xyz[v2, u2, 2]
                allowed = max(step2, spread2[v, u] + spread2[v2, u2])
                if a**2 + b**2 + c**2 > allowed:
                    if rng[v, u] > rng[v2, u2]:
                        out[v, u] = False
                    else:
                        out[v2, u2] = False
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def root(parent: npt.NDArray[np.int32] | I64, a: int) -> int:
    """The root of `a` in a union-find forest, halving the path on the way."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@numba.njit(cache=True, nogil=True, error_model="numpy")
def number_sets(parent: npt.NDArray[np.int32] | I64, first: int, base: int) -> I64:
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def label_pieces(body: B) -> npt.NDArray[np.int32]:
    """`scipy.ndimage.label(body)[0]`: the 4-connected pieces of `body`, numbered from 1 in
    the order of each one's first pixel in row-major order (0 elsewhere)."""
    h, w = body.shape
    out = np.zeros((h, w), np.int32)
    parent = np.zeros(h * w // 2 + 2, np.int32)
    n = 0  # labels so far
    for v in range(h):
        for u in range(w):
            if not body[v, u]:
                continue
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
    for v in range(h):
        for u in range(w):
            out[v, u] = final[out[v, u]]
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def held_pieces(
    labels: npt.NDArray[np.uint16], pieces: npt.NDArray[np.int32], row: I64, rows: int,
    n_pieces: int,
) -> I64:  # fmt: skip
    """(rows, n_pieces) how many pixels of each piece each label holds, by the label's row
    (`row[label]`): the bincount of row[labels]·n_pieces + pieces."""
    out = np.zeros((rows, n_pieces), np.int64)
    h, w = labels.shape
    for v in range(h):
        for u in range(w):
            out[row[labels[v, u]], pieces[v, u]] += 1
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ascending(keys: F64, lo: float, hi: float) -> I64:
    """An order that sorts `keys` (within [lo, hi], no nan), ties in any order: a counting
    sort into as many buckets as keys, then an insertion sort for the few it leaves out
    of order (keys sharing a bucket)."""
    n = keys.size
    scale = n / (hi - lo) if hi > lo else 0.0
    bounds = np.zeros(n + 1, np.int64)
    bucket = np.empty(n, np.int64)
    for i in range(n):
        b = min(int((keys[i] - lo) * scale), n - 1)
        bucket[i] = b
        bounds[b + 1] += 1
    for b in range(n):
        bounds[b + 1] += bounds[b]
    order = np.empty(n, np.int64)
    for i in range(n):
        order[bounds[bucket[i]]] = i
        bounds[bucket[i]] += 1
    for i in range(1, n):
        j = order[i]
        key = keys[j]
        m = i - 1
        while m >= 0 and keys[order[m]] > key:
            order[m + 1] = order[m]
            m -= 1
        order[m + 1] = j
    return order


@numba.njit(cache=True, nogil=True, error_model="numpy")
def sort_surfaces(clouds: F64, starts: I64) -> tuple[F64, I64]:
    """Each cloud `clouds[starts[k]:starts[k + 1]]` sorted along its widest axis, then each
    slab of SLAB points along the widest of the other two (as `track_distances` takes
    them), and the first axes."""
    out = np.empty_like(clouds)
    axes = np.zeros(starts.size - 1, np.int64)
    for k in range(starts.size - 1):
        cloud = clouds[starts[k] : starts[k + 1]]
        widest, lo, hi = -1.0, 0.0, 0.0
        for a in range(3):
            spread = cloud[:, a].max() - cloud[:, a].min()
            if spread > widest:
                widest, lo, hi = spread, cloud[:, a].min(), cloud[:, a].max()
                axes[k] = a
        order = _ascending(cloud[:, axes[k]], lo, hi)
        for n in range(order.size):
            out[starts[k] + n] = cloud[order[n]]
        # within each slab, along the next widest axis: its boxes are then small both ways
        for s in range(starts[k], starts[k + 1], SLAB):
            end = min(starts[k + 1], s + SLAB)
            across, widest = 0, -1.0
            for a in range(3):
                spread = out[s:end, a].max() - out[s:end, a].min()
                if a != axes[k] and spread > widest:
                    widest = spread
                    across = a
            for n in range(s + 1, end):  # insertion sort: a slab is short
                x, y, z = out[n, 0], out[n, 1], out[n, 2]
                key = out[n, across]
                m = n - 1
                while m >= s and out[m, across] > key:
                    out[m + 1, 0], out[m + 1, 1], out[m + 1, 2] = out[m, 0], out[m, 1], out[m, 2]
                    m -= 1
                out[m + 1, 0], out[m + 1, 1], out[m + 1, 2] = x, y, z
    return out, axes


@numba.njit(cache=True, nogil=True, error_model="numpy")
def follow_scene(
    model: F64, sigma: F64, known: B, farther: npt.NDArray[np.int32], farther_min: F64,
    unknown_seen: npt.NDArray[np.int32], unknown_reads: F64, seen: F64, valid: B, usable: B,
    hold: B, noise: F64, noise_factor: float, rate: float, min_sigma: float,
    reveal_frames: int, blend_sigmas: float, variance_share: float,
) -> None:  # fmt: skip
    """`BackgroundModel.update`'s per-pixel arithmetic, in place, in one pass (see there):
    `valid` marks the pixels read, `usable` those free to follow, `hold` those not to be
    learned yet, `noise` the frame's range noise; `unknown_reads` (reveal_frames, H, W)
    the last free readings of each pixel not known yet."""
    h, w = model.shape
    run = np.empty(reveal_frames)
    for v in range(h):
        for u in range(w):
            deviation = seen[v, u] - model[v, u]
            use = usable[v, u]
            if valid[v, u] and deviation > noise_factor * sigma[v, u]:
                farther[v, u] += 1
                farther_min[v, u] = min(farther_min[v, u], seen[v, u])
            else:
                farther[v, u] = 0
                farther_min[v, u] = np.inf
            if use and not known[v, u]:
                unknown_reads[unknown_seen[v, u] % reveal_frames, v, u] = seen[v, u]
                unknown_seen[v, u] += 1
            else:
                unknown_seen[v, u] = 0
            newly = unknown_seen[v, u] >= reveal_frames and not hold[v, u]
            revealed = farther[v, u] >= reveal_frames
            # follow only what looks like the same scenery; anything farther off than
            # blend_sigmas is an object's edge or a flying pixel and would widen the noise
            # estimate until real objects no longer stand out of it
            if use and known[v, u] and abs(deviation) <= blend_sigmas * sigma[v, u]:
                model[v, u] += rate * deviation
                var = sigma[v, u] ** 2
                # the spread of a normal cut at ±2.5σ is 0.91 of the whole: undo that bias
                var += rate * (deviation**2 / variance_share - var)
                spread = math.sqrt(var)
                sigma[v, u] = min_sigma if spread < min_sigma else spread
            # back to the nearest of the farther readings: flying pixels only ever read too far
            if revealed:
                model[v, u] = farther_min[v, u]
            if newly:
                # the median of its last free readings: one may be a flying pixel
                for k in range(reveal_frames):
                    run[k] = unknown_reads[k, v, u]
                run.sort()
                half = reveal_frames // 2
                middle = run[half] if reveal_frames % 2 else (run[half - 1] + run[half]) / 2
                model[v, u] = middle
                sigma[v, u] = noise[v, u]
            if revealed or newly:
                farther[v, u] = 0
                farther_min[v, u] = np.inf
            if newly:
                unknown_seen[v, u] = 0
                known[v, u] = True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def settled(unary: F64, i: I64, j: I64, w: F64) -> B:
    """Nodes whose cheapest label is cheaper than any other by more than all their edges
    weigh: from there no labelling of their neighbours makes another label pay, so no
    expansion move ever takes them off it."""
    n = unary.shape[1]
    weigh = np.zeros(n)
    for e in range(i.size):
        weigh[i[e]] += w[e]
        weigh[j[e]] += w[e]
    out = np.zeros(n, np.bool_)
    for p in range(n):
        best, second = np.inf, np.inf
        for label in range(unary.shape[0]):
            u = unary[label, p]
            if u < best:
                best, second = u, best
            elif u < second:
                second = u
        if np.isfinite(best):
            out[p] = second > best + weigh[p] + 1e-9 * (1.0 + abs(best) + weigh[p])
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def moving_graph(move: B, i: I64, j: I64, w: F64) -> tuple[I64, I64, I64, I64, F64]:
    """The nodes that `move` (in order), each node's number among them (−1 for the others)
    and the edges (i, j, w) with an end among them, in order."""
    local = np.full(move.size, -1, np.int64)
    m = 0
    for p in range(move.size):
        if move[p]:
            local[p] = m
            m += 1
    nodes = np.empty(m, np.int64)
    for p in range(move.size):
        if move[p]:
            nodes[local[p]] = p
    ri = np.empty(i.size, np.int64)
    rj = np.empty(i.size, np.int64)
    rw = np.empty(i.size)
    k = 0
    for e in range(i.size):
        if move[i[e]] or move[j[e]]:
            ri[k], rj[k], rw[k] = i[e], j[e], w[e]
            k += 1
    return nodes, local, ri[:k], rj[:k], rw[:k]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def cheapest_where(unary: F64, where: B) -> I64:
    """`np.argmin(unary[:, where], axis=0)` (the first nan, if any) at the nodes `where`,
    0 elsewhere."""
    out = np.zeros(unary.shape[1], np.int64)
    for p in range(unary.shape[1]):
        if not where[p]:
            continue
        best, at = unary[0, p], 0
        if not np.isnan(best):
            for label in range(1, unary.shape[0]):
                x = unary[label, p]
                if np.isnan(x):
                    at = label
                    break
                if x < best:
                    best, at = x, label
        out[p] = at
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def expansion_terms(
    unary: F64, labels: I64, alpha: int, i: I64, j: I64, w: F64, local: I64, nodes: I64
) -> tuple[F64, F64, I64, I64, F64]:
    """The α-expansion move's graph from `labels` (see `multicut._expand`) over the nodes
    that may move (`nodes`; `local` ≥ 0: their number in the graph; the others keep their
    label): each one's capacity from the source and to the sink, and the edges between
    them (i, j, capacity from i to j). An edge to a node that keeps its label is a unary
    term; edges between two such nodes may be left out of i, j, w.

    With x_p = 1 for "take α", an edge's E(x_p, x_q) has A = E00, B = E01, C = E10 and
    D = E11 = 0, so E = A + (C−A)·x_p + (D−C)·x_q + (B+C−A−D)·(1−x_p)·x_q."""
    n = nodes.size
    unary1 = np.empty(n)
    for p in nodes:
        unary1[local[p]] = unary[alpha, p] - unary[labels[p], p]
    ri = np.empty(i.size, np.int64)
    rj = np.empty(i.size, np.int64)
    pair = np.empty(i.size)
    m = 0
    for e in range(i.size):
        li, lj = labels[i[e]], labels[j[e]]
        a = w[e] * (1.0 if li != lj else 0.0)
        b = w[e] * (1.0 if li != alpha else 0.0)
        c = w[e] * (1.0 if alpha != lj else 0.0)
        p, q = local[i[e]], local[j[e]]
        if p >= 0 and q >= 0:
            unary1[p] += c - a
            ri[m], rj[m] = p, q
            pair[m] = b + c - a
            m += 1
        elif p >= 0:
            unary1[p] += c - a  # x_q = 0
        elif q >= 0:
            unary1[q] += b - a  # x_p = 0
    for e in range(i.size):
        p, q = local[i[e]], local[j[e]]
        if p >= 0 and q >= 0:
            c = w[e] * (1.0 if alpha != labels[j[e]] else 0.0)
            unary1[q] += -c
    source = np.empty(n)
    sink = np.empty(n)
    for p in range(n):
        x = unary1[p]
        source[p] = x if (x >= 0.0 or x != x) else 0.0
        y = -x
        sink[p] = y if (y >= 0.0 or y != y) else 0.0
    return source, sink, ri[:m], rj[:m], pair[:m]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def background_cost(
    model: F64, sigma: F64, known: B, seen: F64, valid: B, deadband: float, cap: float,
    unknown: float,
) -> F64:  # fmt: skip
    """Each pixel's cost for the background (see `Tracker._background_cost`): half the
    square of how far it stands in front of the scenery, in noise sigmas, less the
    deadband, at most `cap`; `unknown` where the scenery is not known."""
    h, w = model.shape
    out = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            z = (model[v, u] - seen[v, u]) / sigma[v, u] if valid[v, u] and known[v, u] else 0.0
            z = z - deadband
            z = z if (z >= 0.0 or z != z) else 0.0
            cost = 0.5 * z * z
            cost = cost if (cost <= cap or cost != cost) else cap
            out[v, u] = cost if known[v, u] else unknown
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def standing_out(
    model: F64, sigma: F64, known: B, seen: F64, valid: B, labels: npt.NDArray[np.uint16],
    noise_factor: float, min_height: float,
) -> B:  # fmt: skip
    """`BackgroundModel.standing_out` where `labels` is 0 (what no track took)."""
    h, w = model.shape
    out = np.zeros((h, w), np.bool_)
    for v in range(h):
        for u in range(w):
            if labels[v, u] == 0 and valid[v, u] and known[v, u]:
                nearer = model[v, u] - seen[v, u]
                out[v, u] = nearer > noise_factor * sigma[v, u] and nearer > min_height
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def noise_fit(intensity: F64, amplitude: F64, valid: B, rng: F64, stride: int) -> tuple[F64, F64]:
    """`tofcut.tracker.noise.range_noise`'s per-pixel shape of the noise, √max(B, 0) / A
    (inf where invalid or not finite), and its fit's ratios: along every stride-th row,
    each second difference of the range over its spread from the shape, where that spread
    is finite and positive (in row-major order)."""
    h, w = valid.shape
    shape = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            b = intensity[v, u]
            b = b if (b >= 0.0 or b != b) else 0.0
            x = math.sqrt(b) / amplitude[v, u]
            shape[v, u] = x if valid[v, u] and np.isfinite(x) else np.inf
    ratios = np.empty(((h + stride - 1) // stride) * max(w - 2, 0))
    n = 0
    for v in range(0, h, stride):
        for u in range(w - 2):
            s0, s1, s2 = shape[v, u], shape[v, u + 1], shape[v, u + 2]
            spread = math.sqrt(s0**2 + 4.0 * s1**2 + s2**2)
            if np.isfinite(spread) and spread > 0:
                second = rng[v, u] - 2.0 * rng[v, u + 1] + rng[v, u + 2]
                ratios[n] = abs(second) / spread
                n += 1
    return shape, ratios[:n]


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def median(values: F64) -> float:
    """`np.median(values)` of a 1-D array (at least one value): the middle value, or the
    mean of the middle two, (a + b) / 2; nan if any is."""
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def noise_scaled(shape: F64, scale: float, floor: float) -> F64:
    """`np.maximum(scale * shape, floor)`."""
    h, w = shape.shape
    out = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            x = scale * shape[v, u]
            out[v, u] = x if (x >= floor or x != x) else floor
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def standing_regions(
    model: F64, sigma: F64, usable: B, seen: F64, side: int, sigmas: float, low_share: float,
    min_height: float,
) -> B:  # fmt: skip
    """`tofcut.tracker.background.standing_regions`: the `usable` pixels whose side × side
    neighbourhood (its usable pixels, at least half of it) stands nearer than the scenery
    on average by `sigmas` times that mean's noise, by `low_share` of its pixels' mean noise
    and by `min_height`; summed over the window by running sums (integral images)."""
    h, w = model.shape
    s_n = np.zeros((h + 1, w + 1))
    s_v = np.zeros((h + 1, w + 1))
    s_c = np.zeros((h + 1, w + 1))
    for v in range(h):
        rn = rv = rc = 0.0
        for u in range(w):
            if usable[v, u]:
                rn += model[v, u] - seen[v, u]
                rv += sigma[v, u] * sigma[v, u]
                rc += 1.0
            s_n[v + 1, u + 1] = s_n[v, u + 1] + rn
            s_v[v + 1, u + 1] = s_v[v, u + 1] + rv
            s_c[v + 1, u + 1] = s_c[v, u + 1] + rc
    out = np.zeros((h, w), np.bool_)
    r = side // 2
    for v in range(h):
        v0, v1 = max(v - r, 0), min(v + r + 1, h)
        for u in range(w):
            if not usable[v, u]:
                continue
            u0, u1 = max(u - r, 0), min(u + r + 1, w)
            count = s_c[v1, u1] - s_c[v0, u1] - s_c[v1, u0] + s_c[v0, u0]
            if count < side * side / 2:
                continue
            mean = (s_n[v1, u1] - s_n[v0, u1] - s_n[v1, u0] + s_n[v0, u0]) / count
            mean_var = (s_v[v1, u1] - s_v[v0, u1] - s_v[v1, u0] + s_v[v0, u0]) / count
            out[v, u] = (
                mean > sigmas * math.sqrt(mean_var / count)
                and mean > low_share * math.sqrt(mean_var)
                and mean > min_height
            )
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
                    j = k  # insertion sort as it fills
                    while j > 0 and window[j - 1] > x:
                        window[j] = window[j - 1]
                        j -= 1
                    window[j] = x
                    k += 1
            out[v, u] = window[4]
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
                    z = values[y, x]
                    j = k  # insertion sort as it fills
                    while j > 0 and window[j - 1] > z:
                        window[j] = window[j - 1]
                        j -= 1
                    window[j] = z
                    k += 1
            out[v, u] = window[k // 2] if k % 2 else 0.5 * (window[k // 2 - 1] + window[k // 2])
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def steep_pixels(
    where: B, xyz: F64, noise: F64, normal: F64, baseline: int, max_slope: float
) -> tuple[B, F64, F64]:
    """`tofcut.tracker.tops.facing_up`'s arithmetic: of `where`'s points averaged over 3×3,
    the pixels on a span of `baseline` pixels (along a row or a column) whose rise along
    `normal` is more than `max_slope` times their spacing across it; and, per direction,
    each pair's slope noise (a 3×3 mean's noise twice, over the spacing)."""
    h, w = where.shape
    pts = np.full((h, w, 3), np.nan)
    for v in range(h):
        for u in range(w):
            if not where[v, u]:
                continue
            n = 0
            sx = sy = sz = 0.0
            for v2 in range(max(v - 1, 0), min(v + 2, h)):
                for u2 in range(max(u - 1, 0), min(u + 2, w)):
                    if where[v2, u2]:
                        sx += xyz[v2, u2, 0]
                        sy += xyz[v2, u2, 1]
                        sz += xyz[v2, u2, 2]
                        n += 1
            pts[v, u, 0], pts[v, u, 1], pts[v, u, 2] = sx / n, sy / n, sz / n
    steep = np.zeros((h, w), np.bool_)
    ratios = np.empty((2, h * w))
    counts = np.zeros(2, np.int64)
    share = math.sqrt(2.0) / 3.0
    for axis in range(2):
        dv, du = (baseline, 0) if axis == 0 else (0, baseline)
        for v in range(h - dv):
            for u in range(w - du):
                if not (where[v, u] and where[v + dv, u + du]):
                    continue
                d0 = pts[v + dv, u + du, 0] - pts[v, u, 0]
                d1 = pts[v + dv, u + du, 1] - pts[v, u, 1]
                d2 = pts[v + dv, u + du, 2] - pts[v, u, 2]
                rise = d0 * normal[0] + d1 * normal[1] + d2 * normal[2]
                a0, a1, a2 = d0 - rise * normal[0], d1 - rise * normal[1], d2 - rise * normal[2]
                spacing = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
                ratios[axis, counts[axis]] = noise[v, u] * share / max(spacing, 1e-6)
                counts[axis] += 1
                if abs(rise) > max_slope * spacing:
                    for k in range(baseline + 1):
                        steep[v + k * dv // baseline, u + k * du // baseline] = True
    return steep, ratios[0, : counts[0]].copy(), ratios[1, : counts[1]].copy()


@numba.njit(cache=True, nogil=True, error_model="numpy")
def top_stats(
    tops: npt.NDArray[np.int32], n: int, pieces: npt.NDArray[np.int32], xyz: F64,
    noise: F64, origin: F64, normal: F64,
) -> tuple[I64, F64, F64, I64]:  # fmt: skip
    """Per top 1..n (index 0 unused): its pixels, mean height along `normal` above `origin`,
    the mean of its pixels' noise², and the piece it lies in."""
    size = np.zeros(n + 1, np.int64)
    height = np.zeros(n + 1)
    noise2 = np.zeros(n + 1)
    home = np.zeros(n + 1, np.int64)
    h, w = tops.shape
    for v in range(h):
        for u in range(w):
            t = tops[v, u]
            if t == 0:
                continue
            size[t] += 1
            height[t] += (
                (xyz[v, u, 0] - origin[0]) * normal[0] + (xyz[v, u, 1] - origin[1]) * normal[1]
                + (xyz[v, u, 2] - origin[2]) * normal[2]
            )  # fmt: skip
            noise2[t] += noise[v, u] ** 2
            home[t] = pieces[v, u]
    for t in range(1, n + 1):
        if size[t]:
            height[t] /= size[t]
            noise2[t] /= size[t]
    return size, height, noise2, home


@numba.njit(cache=True, nogil=True, error_model="numpy")
def sweep_scores(
    heights: F32, ok: B, reach: F32, band: F32, offsets: F64, min_times: int
) -> tuple[I64, I64, F64]:  # fmt: skip
    """For each layer (`offsets`, n·p) over (samples, pixels) heights: the pixels seen on it
    (within `band`), above it (by more than `reach`) in at least `min_times` samples each and
    below it in fewer; and the count and sum of squares of the heights seen on it."""
    samples, pixels = heights.shape
    layers = offsets.size
    swept = np.zeros(layers, np.int64)
    on = np.zeros(layers, np.int64)
    squares = np.zeros(layers)
    at = np.zeros(layers, np.int64)
    up = np.zeros(layers, np.int64)
    down = np.zeros(layers, np.int64)
    for i in range(pixels):
        at[:] = 0
        up[:] = 0
        down[:] = 0
        for t in range(samples):
            if not ok[t, i]:
                continue
            for k in range(layers):
                d = heights[t, i] - offsets[k]
                if abs(d) < band[t, i]:
                    at[k] += 1
                    squares[k] += d * d
                elif d > reach[t, i]:
                    up[k] += 1
                elif d < -reach[t, i]:
                    down[k] += 1
        for k in range(layers):
            on[k] += at[k]
            if at[k] >= min_times and up[k] >= min_times and down[k] < min_times:
                swept[k] += 1
    return swept, on, squares


def warm_up() -> None:
    """Load (or compile) every kernel for the argument types the tracker calls it with, so
    the first frames of a live run do not stall on it (about a second, once per process)."""
    global _warm
    if _warm:
        return
    f64, i64, yes = np.zeros((2, 2)), np.zeros((2, 2), np.int64), np.ones((2, 2), bool)
    xyz, wt = np.zeros((2, 2, 3)), np.zeros((4, 2, 2))
    one = np.zeros(1, np.int64)
    tie_weights(tie_exponents(xyz, yes, yes, 1.0), yes, yes, 1.0)
    free, rows, cols, _, _, _ = free_pixels(yes, f64, f64, xyz, f64, 0.0)  # all four free
    cost = object_costs(np.zeros((1, 4)), 1.0, 1.0, f64, f64, rows, cols, free)
    cut_nodes(free, rows, cols, f64, f64, cost, cost)
    free_edges(i64, wt, rows, cols)
    add_fixed_ties(np.zeros((2, 4)), i64, wt, rows, cols)
    add_fixed_ties_at(np.zeros(1), i64, wt, one, one)
    points, ceiling = np.zeros((1, 3)), np.zeros(1)
    starts = np.array([0, 1])
    cloud, axes = sort_surfaces(points, starts)
    track_distances(
        points, ceiling, points, np.eye(3)[None], cloud, starts, axes, 1.0, 1.0, 1.0,
        np.ones(1), 1.0,
    )  # fmt: skip
    label_pieces(cut_at_steps(yes, xyz, f64, 1.0, f64))
    point_stats(points)
    label_points(np.zeros((2, 2), np.uint16), xyz, one)
    held_pieces(np.zeros((2, 2), np.uint16), np.zeros((2, 2), np.int32), one, 1, 1)
    moving_graph(np.ones(1, bool), one, one, np.zeros(1))
    part_of, order, _, edge_order, _, _, can_win, _ = split_parts(f64, one, one, np.zeros(2))
    binary_parts(f64, one, one, np.zeros(1), part_of, order, edge_order, can_win[0], can_win)
    unary = np.zeros((2, 3))
    for layout in (unary, np.asfortranarray(unary)):  # a stack, and columns taken out of one
        settled(layout, one, one, np.zeros(1))
        cheapest_where(layout, np.ones(3, bool))
        expansion_terms(layout, np.zeros(3, np.int64), 1, one, one, np.zeros(1), one, one)
    background_cost(f64, f64, yes, f64, yes, 1.0, 1.0, 1.0)
    noise_scaled(noise_fit(f64, f64, yes, f64, 1)[0], 1.0, 1.0)
    median(np.zeros(2))
    f32 = np.zeros((2, 2), np.float32)
    sweep_scores(f32, yes, f32, f32, np.zeros(1), 2)
    standing_out(f64, f64, yes, f64, yes, np.zeros((2, 2), np.uint16), 1.0, 1.0)
    counts = np.zeros((2, 2), np.int32)
    follow_scene(
        f64, f64, yes, counts, f64, counts, np.zeros((1, 1, 1)), f64, yes, yes, yes, f64, 1.0,
        1.0, 1.0, 1, 1.0, 1.0,
    )  # fmt: skip
    median3_at(f64, yes)
    median3_within(f64, yes, yes)
    standing_regions(f64, f64, yes, f64, 1, 1.0, 1.0, 1.0)
    steep_pixels(yes, xyz, f64, np.ones(3), 1, 1.0)
    top_stats(np.ones((2, 2), np.int32), 1, np.ones((2, 2), np.int32), xyz, f64, np.zeros(3),
              np.ones(3))  # fmt: skip
    _warm = True


_warm = False
