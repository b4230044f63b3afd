"""The tracker's per-pixel loops, compiled (numba, one thread): neighbour ties, the graph of
the pixels left free, distances in a track's shape, and the 3D steps that split surfaces.

Each kernel does the same floating-point operations in the same order as the numpy
expressions it replaces (`tofcut.tracker.reference` holds those), so the tracker's output
does not change. The one operation numba would round differently, `exp` (numpy has its
own vectorised one), is left to numpy: `tie_exponents` and `tie_weights` go either side.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]

NEIGHBOURS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, 1 / math.sqrt(2)), (1, -1, 1 / math.sqrt(2)))
"""Half of the 8-neighbourhood as (dv, du, weight factor); diagonals count 1/√2."""
_DV = np.array([d[0] for d in NEIGHBOURS], np.int64)
_DU = np.array([d[1] for d in NEIGHBOURS], np.int64)
FACTORS = np.array([d[2] for d in NEIGHBOURS])


@numba.njit(cache=True, nogil=True)
def tie_exponents(xyz: F64, valid: B, two_sigma2: float) -> F64:
    """(4, H, W) −|D_p − D_q|² / 2σ² of each pixel p and its neighbour q in each direction
    of NEIGHBOURS (0 where q is off the image or either pixel is invalid)."""
    h, w = valid.shape
    out = np.zeros((4, h, w))
    for k in range(4):
        dv, du = _DV[k], _DU[k]
        for v in range(h - dv):
            for u in range(max(0, -du), min(w, w - du)):
                v2, u2 = v + dv, u + du
                if valid[v, u] and valid[v2, u2]:
                    a = xyz[v, u, 0] - xyz[v2, u2, 0]
                    b = xyz[v, u, 1] - xyz[v2, u2, 1]
                    c = xyz[v, u, 2] - xyz[v2, u2, 2]
                    out[k, v, u] = -(a**2 + b**2 + c**2) / two_sigma2
    return out


@numba.njit(cache=True, nogil=True)
def tie_weights(exps: F64, valid: B, smoothness: float) -> tuple[F64, F64]:
    """Eq. (7)'s Potts weight of every neighbour pair, (4, H, W) by the first pixel and
    direction (λ·factor where either pixel is invalid), and each pixel's sum of weights,
    added up in the order right, left, down, up, down-right, up-left, down-left, up-right."""
    h, w = valid.shape
    wt = np.zeros((4, h, w))
    for k in range(4):
        sf = smoothness * FACTORS[k]
        dv, du = _DV[k], _DU[k]
        for v in range(h - dv):
            for u in range(max(0, -du), min(w, w - du)):
                if valid[v, u] and valid[v + dv, u + du]:
                    wt[k, v, u] = sf * exps[k, v, u]
                else:
                    wt[k, v, u] = sf
    total = np.zeros((h, w))
    for v in range(h):
        for u in range(w):
            acc = 0.0
            for k in range(4):
                dv, du = _DV[k], _DU[k]
                if v + dv < h and 0 <= u + du < w:
                    acc += wt[k, v, u]
                if v - dv >= 0 and 0 <= u - du < w:
                    acc += wt[k, v - dv, u - du]
            total[v, u] = acc
    return wt, total


@numba.njit(cache=True, nogil=True)
def free_edges(index: I64, wt: F64) -> tuple[I64, I64, F64]:
    """Edges (i, j, weight) between neighbouring free pixels (`index` ≥ 0: their node
    number), direction by direction, pixels in row-major order."""
    h, w = index.shape
    n = 0
    for k in range(4):
        dv, du = _DV[k], _DU[k]
        for v in range(h - dv):
            for u in range(max(0, -du), min(w, w - du)):
                if index[v, u] >= 0 and index[v + dv, u + du] >= 0:
                    n += 1
    ei = np.empty(n, np.int64)
    ej = np.empty(n, np.int64)
    ew = np.empty(n)
    n = 0
    for k in range(4):
        dv, du = _DV[k], _DU[k]
        for v in range(h - dv):
            for u in range(max(0, -du), min(w, w - du)):
                a, b = index[v, u], index[v + dv, u + du]
                if a >= 0 and b >= 0:
                    ei[n] = a
                    ej[n] = b
                    ew[n] = wt[k, v, u]
                    n += 1
    return ei, ej, ew


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def add_fixed_ties(unary: F64, index: I64, wt: F64) -> None:
    """A free pixel (`index` ≥ 0: its node) beside a fixed one pays the tie for any object
    label: add each such tie to rows 1.. of `unary`, in the order of `_with_fixed_ties`."""
    h, w = index.shape
    ties = np.empty(8)
    for v in range(h):
        for u in range(w):
            node = index[v, u]
            if node < 0:
                continue
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


@numba.njit(cache=True, nogil=True)
def add_fixed_ties_at(values: F64, index: I64, wt: F64, vs: I64, us: I64) -> F64:
    """`add_fixed_ties` for one label's costs `values` at the pixels (vs, us)."""
    out = np.empty_like(values)
    for n in range(values.size):
        out[n] = _with_fixed_ties(values[n], index, wt, vs[n], us[n])
    return out


@numba.njit(cache=True, nogil=True)
def _nearest(cloud: F64, axis: int, q: F64, bound2: float) -> float:
    """Distance from q to the nearest point of `cloud` (sorted along `axis`) if its square
    is below bound2, else inf; points are skipped only where the gap along `axis` alone
    already reaches the best square so far, so the minimum is the brute-force one."""
    best = bound2
    m = cloud.shape[0]
    lo, hi = 0, m
    while lo < hi:
        mid = (lo + hi) // 2
        if cloud[mid, axis] < q[axis]:
            lo = mid + 1
        else:
            hi = mid
    for step in (-1, 1):
        i = lo - 1 if step < 0 else lo
        while 0 <= i < m:
            gap = q[axis] - cloud[i, axis]
            if gap * gap >= best:
                break
            a = q[0] - cloud[i, 0]
            b = q[1] - cloud[i, 1]
            c = q[2] - cloud[i, 2]
            d = a * a + b * b + c * c
            if d < best:
                best = d
            i += step
    return math.sqrt(best) if best < bound2 else np.inf


@numba.njit(cache=True, nogil=True)
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
    surface_sigma: float,
    reach: float,
) -> tuple[F64, B]:
    """(tracks, N) each point's distance from each track: (D−µ)ᵀΣ⁻¹(D−µ) in the track's
    shape (summed as numpy's einsum sums it) plus surface_weight·(d/surface_sigma)², d the
    distance from the track's surface (`clouds[starts[k]:starts[k+1]]`, sorted along
    `axes[k]`; inf beyond `reach`); inf where not a number. Where a track's cost from its
    shape alone, object_cost + β·shape, is above the point's `ceiling`, the surface is not
    looked at: the distance is inf, and marked in the second array when the shape's was
    finite."""
    tracks, n_points = centres.shape[0], points.shape[0]
    out = np.empty((tracks, n_points))
    rough = np.zeros((tracks, n_points), np.bool_)
    bound2 = reach * reach
    d = np.empty(3)
    for k in range(tracks):
        cloud = clouds[starts[k] : starts[k + 1]]
        for n in range(n_points):
            for i in range(3):
                d[i] = points[n, i] - centres[k, i]
            shape = 0.0
            for i in range(3):
                for j in range(3):
                    shape += d[i] * inverses[k, i, j] * d[j]
            value = shape
            if surface_weight > 0:
                alone = object_cost + beta * shape
                if not alone <= ceiling[n]:
                    out[k, n] = np.inf
                    rough[k, n] = np.isfinite(alone)
                    continue
                near = np.inf
                q = points[n]
                if np.isfinite(q[0]) and np.isfinite(q[1]) and np.isfinite(q[2]):
                    near = _nearest(cloud, axes[k], q, bound2)
                value = shape + surface_weight * (near / surface_sigma) ** 2
            out[k, n] = np.inf if np.isnan(value) else value
    return out, rough


@numba.njit(cache=True, nogil=True)
def cut_at_steps(body: B, xyz: F64, rng: F64, step2: float) -> B:
    """`body` less every pixel on the far side of a 3D step of more than √step2 to its right
    or lower neighbour (of a step, the pixel with the larger range is the far one)."""
    h, w = body.shape
    out = body.copy()
    for dv, du in ((0, 1), (1, 0)):
        for v in range(h - dv):
            for u in range(w - du):
                v2, u2 = v + dv, u + du
                a = xyz[v, u, 0] - xyz[v2, u2, 0]
                b = xyz[v, u, 1] - xyz[v2, u2, 1]
                c = xyz[v, u, 2] - xyz[v2, u2, 2]
                if a**2 + b**2 + c**2 > step2:
                    if rng[v, u] > rng[v2, u2]:
                        out[v, u] = False
                    else:
                        out[v2, u2] = False
    return out


@numba.njit(cache=True, nogil=True)
def parts(n: int, i: I64, j: I64) -> tuple[int, I64]:
    """Connected parts of n nodes joined by edges (i, j): how many, and each node's part,
    numbered in the order of each part's first node (as scipy's connected_components)."""
    root = np.arange(n)
    for e in range(i.size):
        a, b = i[e], j[e]
        while root[a] != a:
            root[a] = root[root[a]]
            a = root[a]
        while root[b] != b:
            root[b] = root[root[b]]
            b = root[b]
        if a != b:
            root[max(a, b)] = min(a, b)
    part_of = np.empty(n, np.int64)
    count = 0
    for v in range(n):
        r = v
        while root[r] != r:
            r = root[r]
        if r == v:
            part_of[v] = count
            count += 1
        else:
            part_of[v] = part_of[r]
    return count, part_of


@numba.njit(cache=True, nogil=True)
def any_by_part(win: B, part_of: I64, count: int) -> B:
    """(rows, parts): whether any node of each part is True in each row of `win`."""
    out = np.zeros((win.shape[0], count), np.bool_)
    for v in range(win.shape[1]):
        for r in range(win.shape[0]):
            if win[r, v]:
                out[r, part_of[v]] = True
    return out


@numba.njit(cache=True, nogil=True)
def add_at(target: F64, index: I64, values: F64) -> None:
    """`np.add.at(target, index, values)`: added one by one, in order."""
    for e in range(index.size):
        target[index[e]] += values[e]


@numba.njit(cache=True, nogil=True)
def sort_surfaces(clouds: F64, starts: I64) -> tuple[F64, I64]:
    """Each cloud `clouds[starts[k]:starts[k + 1]]` sorted along its widest axis (as
    `track_distances` takes them), and those axes."""
    out = np.empty_like(clouds)
    axes = np.zeros(starts.size - 1, np.int64)
    for k in range(starts.size - 1):
        cloud = clouds[starts[k] : starts[k + 1]]
        widest = -1.0
        for a in range(3):
            spread = cloud[:, a].max() - cloud[:, a].min()
            if spread > widest:
                widest = spread
                axes[k] = a
        order = np.argsort(cloud[:, axes[k]])
        for n in range(order.size):
            out[starts[k] + n] = cloud[order[n]]
    return out, axes
