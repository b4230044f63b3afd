"""Beyond the paper: segmenting an object that touches its support (floor, belt, table).

Where an object stands on a surface the range is continuous across the contact, so §4.2's
weights tie the object to its support as strongly as to itself (docs/reproduce/report.md).
The support energy adds what the frame says about that surface: the large planes of the
frame are found by RANSAC, the support is the nearest plane in front of which the seed
lies, and each pixel's height z above it, in units of the plane's own range noise σ, gives
a unary cost:

    cost0 = min(C, max(z, 0)² / 2)          (background: on the support, or behind it)
    cost1 = min(C, max(z_t − z, 0)² / 2)    (target: at least the seed's height z_t)

with z_t the median height round the seed, at most `SegmentParams.support_height`; the
edges are eq. (8)'s, times `support_weight`, and the seed is tied to the target. The mask is
the part of the minimum that reaches the seed through neighbours whose 3D distance is below
`connect_factor` × σs: the energy says "above the support", the range says "which object".
The pixels of the minimum on that part's outline which the step cut off are mixed pixels
(they see the object and what is behind it) and are kept when most of them is the object,
as their range and amplitude tell (`with_mixed_outline`).

Given the target's extent, objects that touch it are cut off where they meet it: there the
surface folds concavely, while an object's own faces meet at convex edges
(`apart_at_creases`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tofcut._types import F64, I64, B
from tofcut.tracker.neighbours import EIGHT, OFFSETS, pair_slices
from tofcut.tracker.paper.energy import range_weights
from tofcut.tracker.paper.graphcut import Problem, solve_reduced
from tofcut.tracker.stats import robust_sigma

MIN_SHARE = 0.08
"""A plane holds at least this share of the valid pixels to count as a support."""
MAX_PLANES = 3
"""At most this many planes are looked for (floor, wall and a table, say)."""
TRIES = 200
"""RANSAC hypotheses per plane."""
SAMPLE = 1000
"""Hypotheses are scored on this many points."""
INLIER_SIGMAS = 3.0
"""A point is on a plane when its distance is below this many σ of the plane's noise."""
MIN_COHERENCE = 0.5
"""Share of a plane's pixels whose four neighbours are on it too: a plane that only slices
through several objects' faces (thin stripes) is no support."""
MAX_NOISE_RATIO = 1.5
"""A plane whose noise is more than this times the largest plane's is no support: a band that
thick holds slices of several surfaces (or a far, dark one no object stands on)."""
RANSAC_SEED = 0
"""RANSAC's random numbers: the same frame gives the same planes."""
NORMAL_WINDOW = 2
"""Half-size of the window of points whose plane gives a pixel's surface normal (5×5)."""
TWO_STEPS = np.ones((5, 5), bool)
"""The pixels within two steps of one (what lies behind an outline pixel hemmed in by the
mask)."""


@dataclass(frozen=True)
class Plane:
    """n·p = offset, n a unit normal towards the camera (at the origin)."""

    normal: tuple[float, float, float]
    offset: float
    share: float
    """Share of the valid pixels on the plane."""
    sigma_m: float
    """Robust σ of the inliers' distances from the plane, metres: the range noise on it."""

    def height(self, points: F64) -> F64:
        """Signed distance of points (..., 3) in front of the plane (towards the camera)."""
        out: F64 = points @ np.asarray(self.normal) - self.offset
        return out


def fit_plane(points: F64) -> tuple[F64, float]:
    """Least-squares plane of (N, 3) points: unit normal towards the origin, and offset."""
    centre = points.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((points - centre).T))
    n = vecs[:, 0]
    if float(n @ centre) > 0:
        n = -n
    return n, float(n @ centre)


def find_planes(xyz: F64, valid: B, scale_m: float) -> list[Plane]:
    """The large, coherent planes of a frame, largest first. `scale_m` (the median distance
    between neighbours' points) sets the first inlier band; each plane's own noise the next."""
    points = xyz[valid]
    total = len(points)
    rng = np.random.default_rng(RANSAC_SEED)
    left = np.ones(total, dtype=bool)
    planes: list[Plane] = []
    for _ in range(MAX_PLANES):
        idx = np.nonzero(left)[0]
        if idx.size < max(MIN_SHARE * total, 3):
            break
        n, off = _ransac(points, idx, INLIER_SIGMAS * scale_m, rng)
        band = INLIER_SIGMAS * scale_m
        near = left & (np.abs(points @ n - off) < band)
        for _ in range(2):  # refit, and measure the plane's own noise
            if np.count_nonzero(near) < 3:
                break
            n, off = fit_plane(points[near])
            sigma = robust_sigma(points[near] @ n - off)
            band = INLIER_SIGMAS * max(sigma, 1e-6)
            near = left & (np.abs(points @ n - off) < band)
        if np.count_nonzero(near) < MIN_SHARE * total:
            break
        left &= ~near
        on = np.zeros(valid.shape, dtype=bool)
        on[valid] = near
        if _coherence(on) < MIN_COHERENCE:
            continue
        sigma = robust_sigma(points[near] @ n - off)
        if planes and sigma > MAX_NOISE_RATIO * planes[0].sigma_m:
            continue
        normal = (float(n[0]), float(n[1]), float(n[2]))
        planes.append(Plane(normal, off, float(near.mean()), sigma))
    return planes


def _ransac(points: F64, idx: I64, band: float, rng: np.random.Generator) -> tuple[F64, float]:
    """The plane through three of the points `idx` that holds most of a sample of them."""
    picks = idx[rng.integers(0, idx.size, (TRIES, 3))]
    a, b, c = points[picks[:, 0]], points[picks[:, 1]], points[picks[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    good = lengths > 1e-12
    normals = normals[good] / lengths[good, None]
    offsets = (normals * a[good]).sum(axis=1)
    scored = points[idx[rng.integers(0, idx.size, min(SAMPLE, idx.size))]]
    counts = (np.abs(scored @ normals.T - offsets) < band).sum(axis=0)
    k = int(np.argmax(counts))
    return normals[k], float(offsets[k])


def _coherence(on: B) -> float:
    """Share of the True pixels whose four neighbours are True too."""
    inner = on.copy()
    inner[1:] &= on[:-1]
    inner[:-1] &= on[1:]
    inner[:, 1:] &= on[:, :-1]
    inner[:, :-1] &= on[:, 1:]
    return float(np.count_nonzero(inner)) / max(int(np.count_nonzero(on)), 1)


def supports_of(planes: list[Plane], point: F64) -> tuple[Plane, ...]:
    """The planes in front of which `point` lies: what it may stand on or against."""
    return tuple(p for p in planes if float(p.height(point)) > 0.0)


def heights(xyz: F64, planes: tuple[Plane, ...]) -> F64:
    """(H, W) height in front of the nearest plane, in σ of that plane's noise (the least
    over the planes, negative behind one); +inf with no plane."""
    z = np.full(xyz.shape[:2], np.inf)
    for p in planes:
        z = np.minimum(z, p.height(xyz) / max(p.sigma_m, 1e-9))
    return z


def support_costs(
    z: F64, valid: B, seed: tuple[int, int], z_target: float, cap: float
) -> tuple[F64, F64]:
    """(cost1, cost0) from heights z in σ (module docstring); the seed (u, v) is tied to the
    target, invalid pixels cost nothing."""
    cost0 = np.where(valid, np.minimum(cap, np.maximum(z, 0.0) ** 2 / 2.0), 0.0)
    cost1 = np.where(valid, np.minimum(cap, np.maximum(z_target - z, 0.0) ** 2 / 2.0), 0.0)
    u, v = seed
    cost1[v, u] = 0.0
    cost0[v, u] = cap * z.size  # more than any cut could save
    return cost1, cost0


def reached(mask: B, xyz: F64, valid: B, seed: tuple[int, int], reach_m: float) -> B:
    """The pixels of `mask` joined to the seed (u, v) by 8-neighbour steps within the mask
    whose 3D distance is below `reach_m`."""
    h, w = mask.shape
    index = np.arange(h * w).reshape(h, w)
    heads, tails = [], []
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(mask.shape, k)
        near = ((xyz[sp] - xyz[sq]) ** 2).sum(axis=-1) < reach_m**2
        keep = mask[sp] & mask[sq] & valid[sp] & valid[sq] & near
        heads.append(index[sp][keep])
        tails.append(index[sq][keep])
    i, j = np.concatenate(heads), np.concatenate(tails)
    graph = coo_matrix((np.ones(i.size), (i, j)), shape=(h * w, h * w))
    _, parts = connected_components(graph, directed=False)
    u, v = seed
    out: B = mask & (parts.reshape(h, w) == parts[v * w + u])
    return out


def surface_normals(xyz: F64, where: B, half: int = NORMAL_WINDOW) -> tuple[F64, F64]:
    """(H, W, 3) mean point and unit normal (towards the camera) of the plane fitted to the
    points of `where` in the (2·half + 1)² window round each pixel (the normal is +z where
    the window holds fewer than three of them)."""
    size = 2 * half + 1
    share = ndimage.uniform_filter(where.astype(np.float64), size, mode="constant")
    inv = 1.0 / np.maximum(share, 1e-12)
    pts = np.where(where[..., None], xyz, 0.0)
    mean = np.stack(
        [ndimage.uniform_filter(pts[..., i], size, mode="constant") * inv for i in range(3)], -1
    )
    cov = np.empty((*where.shape, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            prod = ndimage.uniform_filter(pts[..., i] * pts[..., j], size, mode="constant")
            cov[..., i, j] = cov[..., j, i] = prod * inv - mean[..., i] * mean[..., j]
    few = share * size**2 < 2.5
    cov[few] = np.diag([1.0, 1.0, 0.0])
    normal = np.linalg.eigh(cov)[1][..., :, 0]
    normal *= np.where((normal * mean).sum(axis=-1) > 0.0, -1.0, 1.0)[..., None]
    return mean, normal


def concavity(mean: F64, normal: F64) -> F64:
    """(4, H, W) along `OFFSETS`: (n_q − n_p)·(x_q − x_p) / |x_q − x_p| of neighbours p, q
    (mean points x, normals n towards the camera): positive where the surface bends away
    from the camera between them (a convex edge, or a curved face), negative at a concave
    crease, where one surface meets another (the local convexity criterion of Stein et
    al., "Object partitioning using local convexity", CVPR 2014); 0 off the frame."""
    out = np.zeros((len(OFFSETS), *mean.shape[:2]))
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(mean.shape[:2], k)
        step = mean[sq] - mean[sp]
        turn = ((normal[sq] - normal[sp]) * step).sum(axis=-1)
        out[k][sp] = turn / np.maximum(np.linalg.norm(step, axis=-1), 1e-12)
    return out


def apart_at_creases(
    part: B,
    xyz: F64,
    seed: tuple[int, int],
    centre: F64,
    extent_m: float,
    reach_m: float,
    crease_scale: float,
    weight: float,
    inside_cost: float,
) -> B:
    """The pixels of `part` that stay with the seed (u, v) when objects that touch it are
    cut off where they meet it, at concave creases.

    Objects that touch, a box beside a taller one or before one behind it, are joined in
    range and above the support alike; where the surface passes from one to the other it
    folds concavely, while an object's own faces meet at convex edges (faces of two objects
    that meet flush, in one plane, show no crease and stay joined). A cut on `part`
    alone: edges weigh `weight` × exp(−D²/2(reach/2)²) × exp(−c²/2τ²) at a concavity c < 0
    (`concavity`, τ = `crease_scale`), so a crease costs little to cut along; a pixel
    within the target's extent R of its centre costs `inside_cost` to drop, and one beyond
    costs up to 1 to keep, reached at 2R (no point of the object can lie farther from its
    centroid than its own size). An object's own concave joints (an arm's elbow) lie
    within 2R, and what lies there is kept unless it is cheaper to cut off."""
    rows, cols = np.nonzero(part)
    margin = NORMAL_WINDOW + 1  # the windows round the part's pixels, and their neighbours
    v0, u0 = max(int(rows.min()) - margin, 0), max(int(cols.min()) - margin, 0)
    box = np.s_[v0 : int(rows.max()) + margin + 1, u0 : int(cols.max()) + margin + 1]
    inner, points = part[box], xyz[box]
    mean, normal = surface_normals(points, inner)
    fold = np.exp(-(np.minimum(concavity(mean, normal), 0.0) ** 2) / (2.0 * crease_scale**2))
    weights = weight * range_weights(points, inner, reach_m / 2.0) * fold
    distance = np.linalg.norm(points - centre, axis=-1)
    beyond = np.clip((distance - extent_m) / extent_m, 0.0, 1.0)
    cost1 = np.where(inner, beyond, 0.0)
    cost0 = np.where(inner & (distance <= extent_m), inside_cost, 0.0)
    forced = float(weights.sum() + cost1.sum() + cost0.sum()) + 1.0  # more than any cut saves
    cost1[~inner] = forced
    u, v = seed
    cost1[v - v0, u - u0], cost0[v - v0, u - u0] = 0.0, forced
    labels: B = np.zeros_like(part)
    labels[box] = solve_reduced(Problem(cost1, cost0, weights)).labels & inner
    return labels


def with_mixed_outline(part: B, mask: B, xyz: F64, valid: B, strength: F64) -> B:
    """`part` and the pixels of `mask` round it that are mostly `part`'s object.

    A pixel on the outline of an object in front of something else sees both: its signal is
    the sum of the two returns, a·A_in + (1 − a)·A_out, a the object's share of the pixel,
    and its range their mix weighted by those strengths. With r_in the mean range of its
    neighbours in `part` and r_out, A_out the mean range and strength of what is behind (its
    neighbours outside `mask`; if none, the pixels two steps from `part` round it), t = (r −
    r_out) / (r_in − r_out) is the object's weight in the mix, so the background's share is
    1 − a = (1 − t)·A / A_out, A the pixel's own strength: the object's own strength at the
    pixel, which falls where its surface turns away at the outline, is never needed. The
    pixel is kept when a > 1/2. `strength` is the frame's amplitude (or a stand-in for it)."""
    rng = np.where(valid, np.linalg.norm(xyz, axis=-1), 0.0)  # invalid ranges never count
    near = ndimage.binary_dilation(part, EIGHT)
    r_in, _, _ = _neighbour_means(part & valid, rng, strength, EIGHT)
    r_out, a_out, n_out = _neighbour_means(~mask & valid, rng, strength, EIGHT)
    r_far, a_far, n_far = _neighbour_means(~near & valid, rng, strength, TWO_STEPS)
    alone = n_out == 0
    r_out = np.where(alone, r_far, r_out)
    a_out = np.where(alone, a_far, a_out)
    step = r_in - r_out
    t = np.clip((rng - r_out) / np.where(step != 0.0, step, 1.0), 0.0, 1.0)
    seen_behind = (n_out > 0) | (n_far > 0)
    mostly_in = 2.0 * (1.0 - t) * strength < a_out
    ring = near & mask & valid & ~part
    out: B = part | (ring & seen_behind & mostly_in)
    return out


def _neighbour_means(where: B, rng: F64, strength: F64, window: B) -> tuple[F64, F64, F64]:
    """Each pixel's mean range and strength over the pixels of `where` in `window` round it,
    and their number (the means are 0 where there is none)."""
    kernel = window.astype(np.float64)
    count = ndimage.convolve(where.astype(np.float64), kernel, mode="constant")
    share = 1.0 / np.maximum(count, 1.0)
    r = ndimage.convolve(np.where(where, rng, 0.0), kernel, mode="constant") * share
    a = ndimage.convolve(np.where(where, strength, 0.0), kernel, mode="constant") * share
    return r, a, count
