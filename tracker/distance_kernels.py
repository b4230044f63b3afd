"""The distances of the cut's data term, compiled (see `tofcut.tracker.compiled`): each
point's distance from each track, in the track's shape and from its predicted surface (a
nearest-point search over the surface's points, sorted and boxed by `sort_surfaces`).
"""

from __future__ import annotations

import math

import numpy as np

from tofcut._types import F64, I64
from tofcut.tracker.compiled import F64_1D, F64_2D, F64_3D, I64_1D, helper, kernel

BUCKET = 8
"""Points of a surface cloud boxed together for `_nearest` to pass over at once."""
SLAB = 32
"""Points in a slab: a run of the cloud sorted along its widest axis (see `sort_surfaces`)."""


@helper
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


@helper
def _slabs(boxes: F64, axis: int) -> F64:
    """(slabs, 2) the low and high end along `axis` of each slab's boxes."""
    per = SLAB // BUCKET
    out = np.empty(((boxes.shape[0] + per - 1) // per, 2))
    for s in range(out.shape[0]):
        out[s, 0] = boxes[s * per : (s + 1) * per, 0, axis].min()
        out[s, 1] = boxes[s * per : (s + 1) * per, 1, axis].max()
    return out


@helper
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


@kernel((F64_2D, F64_1D, F64_2D, F64_3D, F64_2D, I64_1D, I64_1D, 1.0, 1.0, 1.0, F64_1D, 1.0))
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


@helper
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


@helper
def _extent(points: F64) -> tuple[F64, F64]:
    """The smallest and largest of each coordinate of (N ≥ 1, 3) points, as numpy's `min`
    and `max` take them (a nan is both)."""
    low, high = points[0].copy(), points[0].copy()
    for n in range(1, points.shape[0]):
        for a in range(3):
            x = points[n, a]
            low[a] = low[a] if (low[a] <= x or low[a] != low[a]) else x
            high[a] = high[a] if (high[a] >= x or high[a] != high[a]) else x
    return low, high


@kernel((F64_2D, I64_1D))
def sort_surfaces(clouds: F64, starts: I64) -> tuple[F64, I64]:
    """Each cloud `clouds[starts[k]:starts[k + 1]]` sorted along its widest axis, then each
    slab of SLAB points along the widest of the other two (as `track_distances` takes
    them), and the first axes."""
    out = np.empty_like(clouds)
    axes = np.zeros(starts.size - 1, np.int64)
    keys = np.empty(SLAB)
    for k in range(starts.size - 1):
        cloud = clouds[starts[k] : starts[k + 1]]
        low, high = _extent(cloud)
        widest, lo, hi = -1.0, 0.0, 0.0
        for a in range(3):
            spread = high[a] - low[a]
            if spread > widest:
                widest, lo, hi = spread, low[a], high[a]
                axes[k] = a
        order = _ascending(cloud[:, axes[k]], lo, hi)
        pts = out[starts[k] : starts[k + 1]]  # the cloud in that order, sorted on in place
        for n in range(order.size):
            pts[n, 0], pts[n, 1], pts[n, 2] = (
                cloud[order[n], 0],
                cloud[order[n], 1],
                cloud[order[n], 2],
            )
        # within each slab, along the next widest axis: its boxes are then small both ways
        for s in range(0, order.size, SLAB):
            end = min(order.size, s + SLAB)
            low, high = _extent(pts[s:end])
            across, widest = 0, -1.0
            for a in range(3):
                if a != axes[k] and high[a] - low[a] > widest:
                    widest = high[a] - low[a]
                    across = a
            for n in range(s, end):
                keys[n - s] = pts[n, across]
            for n in range(1, end - s):  # insertion sort, keys alongside: a slab is short
                key, x, y, z = keys[n], pts[s + n, 0], pts[s + n, 1], pts[s + n, 2]
                m = n - 1
                while m >= 0 and keys[m] > key:
                    keys[m + 1] = keys[m]
                    pts[s + m + 1, 0] = pts[s + m, 0]
                    pts[s + m + 1, 1] = pts[s + m, 1]
                    pts[s + m + 1, 2] = pts[s + m, 2]
                    m -= 1
                keys[m + 1] = key
                pts[s + m + 1, 0], pts[s + m + 1, 1], pts[s + m + 1, 2] = x, y, z
    return out, axes
