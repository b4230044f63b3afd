"""The energies of Arif et al. §4 as arrays: unary costs, pairwise weights, and their value.

A labelling w: P → {0, 1} (1 = target) of an H×W frame costs

    E(w) = Σ_p cost1[p]·w_p + cost0[p]·(1 − w_p) + Σ_{p,q} weight[p,q]·[w_p ≠ w_q]

over the 8-neighbour pairs. Pairwise weights are held as a (4, H, W) array: `weights[k, v, u]`
is the weight of the edge from pixel (v, u) to (v, u) + OFFSETS[k] (`tofcut.tracker.neighbours`;
zero where that falls outside the frame), so every undirected 8-neighbour edge appears
exactly once.

Intensities enter the energies as 8-bit grey levels, g = 255·I / I_ref, with I_ref the 99th
percentile of the frame's valid intensity: the scale of the images the paper (and Malcolm et
al., whose β it quotes) worked on, so that β and the Potts weight have the same meaning in
every frame whatever the exposure. Invalid pixels (saturated, low amplitude) get zero unary
cost and no range-based edges: their stored values never reach the energy.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from tofcut._types import F64, B
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.neighbours import DIAGONAL, DU, DV, OFFSETS, pair_slices
from tofcut.tracker.stats import robust_sigma

GREY_PERCENTILE = 99.0
"""The intensity percentile mapped to grey level 255."""


@numba.njit(cache=True, inline="always")
def edge_weight(weights: F64, v: int, u: int, k: int) -> float:
    """Weight of the edge from pixel (v, u) of a (4, H, W) `weights` along DIRECTIONS[k]:
    a forward one is stored at the pixel, a backward one at the neighbour; 0 off the grid
    (whatever `weights` holds there, so a window cut out of a frame is a grid of its own)."""
    _, h, w = weights.shape
    qv, qu = v + DV[k], u + DU[k]
    if qv < 0 or qv >= h or qu < 0 or qu >= w:
        return 0.0
    if k < len(OFFSETS):
        return float(weights[k, v, u])
    return float(weights[k - len(OFFSETS), qv, qu])


def energy_of(labels: B, cost1: F64, cost0: F64, weights: F64) -> float:
    """E(w) of a labelling (True = target): unary costs plus the weights of cut edges."""
    total = float(np.where(labels, cost1, cost0).sum())
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(labels.shape, k)
        total += float(weights[k][sp][labels[sp] != labels[sq]].sum())
    return total


# --- data terms (§4.1) ------------------------------------------------------------------------


def grey_levels(intensity: F64, valid: B, reference: float | None = None) -> F64:
    """Intensity as 8-bit grey levels (not clipped): 255·I / I_ref."""
    ref = intensity_reference(intensity, valid) if reference is None else reference
    return intensity * (255.0 / ref)


def intensity_reference(intensity: F64, valid: B) -> float:
    """I_ref: the 99th percentile of the valid intensity (1.0 if there is none above 0)."""
    values = intensity[valid]
    ref = percentile(values, GREY_PERCENTILE) if values.size else 0.0
    return ref if ref > 0.0 else 1.0


@numba.njit(cache=True)
def intensity_costs(grey: F64, valid: B, mu_t: float, mu_b: float) -> tuple[F64, F64]:
    """Eq. (5): (cost1, cost0) = ((g − µt)², (g − µb)²), zero at invalid pixels."""
    h, w = valid.shape
    cost1, cost0 = np.zeros((h, w)), np.zeros((h, w))
    for v in range(h):
        for u in range(w):
            if valid[v, u]:
                to_t, to_b = grey[v, u] - mu_t, grey[v, u] - mu_b
                cost1[v, u], cost0[v, u] = to_t * to_t, to_b * to_b
    return cost1, cost0


@numba.njit(cache=True)
def range_penalty(xyz: F64, valid: B, mu_d: F64, beta: float) -> F64:
    """Eq. (6)'s extra target cost β‖D_p − µd‖² (D_p the pixel's 3D point), zero at invalid."""
    h, w = valid.shape
    out = np.zeros((h, w))
    for v in range(h):
        for u in range(w):
            if valid[v, u]:
                out[v, u] = beta * _squared_distance(xyz, v, u, mu_d)
    return out


@numba.njit(cache=True, inline="always")
def _squared_distance(xyz: F64, v: int, u: int, point: F64) -> float:
    """‖xyz[v, u] − point‖², summed x, y, z in that order."""
    dx, dy, dz = xyz[v, u, 0] - point[0], xyz[v, u, 1] - point[1], xyz[v, u, 2] - point[2]
    return float(dx * dx + dy * dy + dz * dz)


@numba.njit(cache=True, inline="always")
def _pair_distance(xyz: F64, v: int, u: int, qv: int, qu: int) -> float:
    """‖xyz[v, u] − xyz[qv, qu]‖², summed x, y, z in that order."""
    dx = xyz[v, u, 0] - xyz[qv, qu, 0]
    dy = xyz[v, u, 1] - xyz[qv, qu, 1]
    dz = xyz[v, u, 2] - xyz[qv, qu, 2]
    return float(dx * dx + dy * dy + dz * dz)


def image_penalty(valid: B, centre: tuple[float, float], beta: float) -> F64:
    """Malcolm et al.'s target cost β‖x_p − µx‖² in the image plane (pixels), zero at invalid."""
    h, w = valid.shape
    uc, vc = centre
    du2 = (np.arange(w, dtype=np.float64) - uc) ** 2
    dv2 = (np.arange(h, dtype=np.float64) - vc) ** 2
    return np.where(valid, beta * (dv2[:, None] + du2[None, :]), 0.0)


def potts_weights(shape: tuple[int, int], smoothness: float) -> F64:
    """Potts interaction on 8 neighbours: λ per axial pair, λ/√2 per diagonal pair."""
    weights = np.zeros((len(OFFSETS), *shape))
    for k, diagonal in enumerate(DIAGONAL):
        sp, _ = pair_slices(shape, k)
        weights[k][sp] = smoothness / math.sqrt(2.0) if diagonal else smoothness
    return weights


def potts_bound(smoothness: float) -> float:
    """An upper bound of every pixel's total Potts weight W_p: 4λ + 4λ/√2, raised by a
    relative 1e-12 so that rounding in the stored weights never takes a sum above it."""
    return (4.0 * smoothness + 4.0 * (smoothness / math.sqrt(2.0))) * (1.0 + 1e-12)


# --- range in the smoothness term (§4.2) ------------------------------------------------------


def seed_costs(shape: tuple[int, int], seed: tuple[int, int]) -> tuple[F64, F64]:
    """§4.2's terminal links: every pixel to the background with 1/n, the seed to the target
    with 1 (as costs: cost1 = 1/n everywhere, cost0 = 1 at the seed (u, v), else 0)."""
    n = shape[0] * shape[1]
    cost1 = np.full(shape, 1.0 / n)
    cost0 = np.zeros(shape)
    u, v = seed
    cost0[v, u] = 1.0
    return cost1, cost0


def range_weights(
    xyz: F64,
    valid: B,
    sigma_s: float,
    grey: F64 | None = None,
    sigma_i: float | None = None,
    *,
    squared: bool = True,
) -> F64:
    """Eq. (7) exp(−D(p,q)/2σs²) on 8 neighbours, times eq. (8)'s exp(−(I_p − I_q)²/2σi²)
    when `grey` is given; D(p,q) is the squared 3D distance. Zero where either pixel is invalid.

    The paper writes D(p, q) for "the distance"; we read it squared, so that (7) is a Gaussian
    in the distance just as (8) is in the intensity difference (and D/σs² has no unit).
    `squared=False` takes the other reading, D the distance itself (σs² then in metres),
    which `tofcut reproduce` compares.
    """
    if (grey is None) != (sigma_i is None):
        raise SegmentError("give both grey and sigma_i, or neither")
    # the exponents (−inf where there is no edge) compiled, their exp by numpy's vector loop
    exponents = _range_exponents(
        xyz,
        valid,
        -2.0 * sigma_s**2,
        np.zeros(valid.shape) if grey is None else grey,  # a zero step: no intensity term
        0.0 if sigma_i is None else 2.0 * sigma_i**2,
        squared,
    )
    weights: F64 = np.exp(exponents, out=exponents)
    return weights


@numba.njit(cache=True)
def _range_exponents(
    xyz: F64, valid: B, scale_s: float, grey: F64, scale_i: float, squared: bool
) -> F64:
    """(4, H, W) exponents of `range_weights`: D(p, q)/scale_s − (g_p − g_q)²/scale_i (the
    intensity term left out when scale_i is 0), −inf where an edge has an invalid pixel or
    leaves the frame. Divided as products with the reciprocals (a division per edge would
    take most of the time; the exponents move by an ulp)."""
    h, w = valid.shape
    inv_s = 1.0 / scale_s
    inv_i = 1.0 / scale_i if scale_i != 0.0 else 0.0
    out = np.empty((len(OFFSETS), h, w))
    for k in range(len(OFFSETS)):
        dv, du = DV[k], DU[k]
        for v in range(h):
            for u in range(w):
                qv, qu = v + dv, u + du
                if qv >= h or qu < 0 or qu >= w or not (valid[v, u] and valid[qv, qu]):
                    out[k, v, u] = -np.inf
                    continue
                d2 = _pair_distance(xyz, v, u, qv, qu)
                step = grey[v, u] - grey[qv, qu]
                out[k, v, u] = (d2 if squared else math.sqrt(d2)) * inv_s - step * step * inv_i
    return out


# --- estimating the model from the frame ------------------------------------------------------


def window_median(values: F64, valid: B, centre: tuple[int, int], radius: int) -> float | None:
    """Median of the valid values in the (2r+1)² window around (u, v); None if none is valid."""
    u, v = centre
    window = (slice(max(v - radius, 0), v + radius + 1), slice(max(u - radius, 0), u + radius + 1))
    picked = values[window][valid[window]]
    return float(np.median(picked, axis=0)) if picked.size else None


def window_median_point(xyz: F64, valid: B, centre: tuple[int, int], radius: int) -> F64 | None:
    """Per-axis median of the valid 3D points in the window around (u, v); None if none."""
    u, v = centre
    window = (slice(max(v - radius, 0), v + radius + 1), slice(max(u - radius, 0), u + radius + 1))
    picked = xyz[window][valid[window]]
    return np.median(picked, axis=0) if picked.size else None


def target_intensity(
    grey: F64, valid: B, xyz: F64, mu_d: F64, extent_m: float, seed_grey: float, mu_b: float
) -> float:
    """µt: the seed's grey level where it is typical of the target, else the target's median.
    The target's pixels are the valid ones within its extent of µd whose grey level is nearer
    the seed's than µb; the seed's is typical between their 10th and 90th percentile. A seed
    on the target's brightest or darkest tenth (the face nearest the light, a highlight)
    would leave the rest of it nearer µb than µt."""
    own = _target_greys(
        grey, valid, xyz, np.asarray(mu_d, np.float64), extent_m**2, seed_grey, mu_b
    )
    if not own.size:
        return seed_grey
    low, mid, high = np.percentile(own, [10, 50, 90])
    return seed_grey if low <= seed_grey <= high else float(mid)


@numba.njit(cache=True)
def _target_greys(
    grey: F64, valid: B, xyz: F64, point: F64, limit: float, seed_grey: float, mu_b: float
) -> F64:
    """`target_intensity`'s pixels' grey levels, in one pass over the frame."""
    h, w = valid.shape
    out = np.empty(h * w)
    n = 0
    for v in range(h):
        for u in range(w):
            g = grey[v, u]
            if (
                valid[v, u]
                and _squared_distance(xyz, v, u, point) <= limit
                and abs(g - seed_grey) < abs(g - mu_b)
            ):
                out[n] = g
                n += 1
    return out[:n]


def window_range_noise(xyz: F64, valid: B, centre: tuple[int, int], radius: int) -> float:
    """σr round (u, v): the robust σ of the range's second differences along the rows of the
    (2r+1)² window, over √6 (a second difference of three independent ranges has σ·√6; a
    surface's slope cancels, and the few that straddle an edge do not move the median).
    0 when the window has no three valid pixels in a row."""
    u, v = centre
    rows = slice(max(v - radius, 0), v + radius + 1)
    cols = slice(max(u - radius, 0), u + radius + 1)
    rng, ok = np.linalg.norm(xyz[rows, cols], axis=-1), valid[rows, cols]
    second = rng[:, :-2] - 2.0 * rng[:, 1:-1] + rng[:, 2:]
    both = ok[:, :-2] & ok[:, 1:-1] & ok[:, 2:]
    return robust_sigma(second[both]) / math.sqrt(6.0) if both.any() else 0.0


def background_intensity(grey: F64, valid: B, xyz: F64, mu_d: F64, margin_m: float) -> float:
    """µb: median grey level of the valid pixels farther than `margin_m` from µd, or from
    every row of a (K, 3) array of µd (all valid pixels if none is that far)."""
    return float(_background_intensity(grey, valid, xyz, np.atleast_2d(mu_d), margin_m**2))


@numba.njit(cache=True)
def _background_intensity(grey: F64, valid: B, xyz: F64, points: F64, limit: float) -> float:
    h, w = valid.shape
    far = np.zeros((h, w), dtype=np.bool_)
    count = 0
    for v in range(h):
        for u in range(w):
            if valid[v, u]:
                far[v, u] = True
                for i in range(points.shape[0]):
                    if not _squared_distance(xyz, v, u, points[i]) > limit:
                        far[v, u] = False
                        break
                count += far[v, u]
    pick = far if count else valid
    return median(grey.ravel()[pick.ravel()])


def nearest_pixel(xyz: F64, valid: B, point: F64) -> tuple[int, int]:
    """(u, v) of the valid pixel whose ray passes closest to a 3D point (its image position)."""
    v, u = _nearest_pixel(xyz, valid, point, float(np.linalg.norm(point)))
    return int(u), int(v)


@numba.njit(cache=True)
def _nearest_pixel(xyz: F64, valid: B, point: F64, point_norm: float) -> tuple[int, int]:
    """(v, u) of the largest cosine between the pixel's point and `point` (first if equal)."""
    h, w = valid.shape
    best, at_v, at_u = -np.inf, 0, 0
    for v in range(h):
        for u in range(w):
            x, y, z = xyz[v, u, 0], xyz[v, u, 1], xyz[v, u, 2]
            norm = math.sqrt(x * x + y * y + z * z)
            if not (valid[v, u] and norm > 0.0):
                continue
            dot = x * point[0] + y * point[1] + z * point[2]
            cosine = dot / max(norm * point_norm, 1e-12)
            if cosine > best:
                best, at_v, at_u = cosine, v, u
    return at_v, at_u


@numba.njit(cache=True)
def neighbour_distance(xyz: F64, valid: B) -> float:
    """Median 3D distance between valid horizontal and vertical neighbours: the frame's scale
    of "the same surface" (pixel footprint plus range noise)."""
    h, w = valid.shape
    steps = np.empty(2 * h * w)
    n = 0
    for k in (0, 1):
        dv, du = DV[k], DU[k]
        for v in range(h - dv):
            for u in range(w - du):
                if valid[v, u] and valid[v + dv, u + du]:
                    steps[n] = _pair_distance(xyz, v, u, v + dv, u + du)
                    n += 1
    if not n:
        return 0.0
    # the middle distances are the square roots of the middle squared distances
    a, b = middle(steps[:n])
    return math.sqrt(a) if n % 2 else (math.sqrt(a) + math.sqrt(b)) / 2.0


@numba.njit(cache=True)
def neighbour_step(grey: F64, valid: B) -> float:
    """Median |g_p − g_q| between valid horizontal and vertical neighbours, grey levels."""
    # walks the pairs as `neighbour_distance` does, on purpose: a compiled loop each, each
    # with its own step in the innermost loop, rather than a call per pair into one walk
    h, w = valid.shape
    steps = np.empty(2 * h * w)
    n = 0
    for k in (0, 1):
        dv, du = DV[k], DU[k]
        for v in range(h - dv):
            for u in range(w - du):
                if valid[v, u] and valid[v + dv, u + du]:
                    steps[n] = abs(grey[v, u] - grey[v + dv, u + du])
                    n += 1
    return median(steps[:n]) if n else 0.0


# --- exact order statistics without a sort: medians and percentiles ---------------------------
# `median` repeats `tracker.stats_kernels.median` on purpose: both give np.median's value (they
# differ only in which sign a median of +0.0 and -0.0 takes), but this one bins a whole
# frame's values (2.4x as fast as the tracker's quickselect on 25,000 values, 3.4x on 50,000),
# and the tracker's is the faster on the few hundred values it takes at a time (1.9x on 500).

MEDIAN_BINS = 4096
"""Bins of `_order_pair`'s histograms."""
MEDIAN_SORT = 256
"""`_order_pair` sorts what is left once it is this few values."""


@numba.njit(cache=True)
def _order_pair(values: F64, k0: int, k1: int, lo: float, hi: float) -> tuple[float, float]:
    """The k0-th and k1-th smallest (from 0, k0 ≤ k1 ≤ k0 + 1) of `values`, all finite in
    [lo, hi], exactly: a histogram finds the bins they fall in (the binning is monotone),
    the values in those bins are kept, and so on until few are left."""
    kept = values
    while lo < hi:
        scale = MEDIAN_BINS / (hi - lo)
        counts = np.zeros(MEDIAN_BINS, dtype=np.int64)
        for x in kept:
            counts[min(int((x - lo) * scale), MEDIAN_BINS - 1)] += 1
        below, first = 0, 0
        while below + counts[first] <= k0:
            below += counts[first]
            first += 1
        last, upto = first, below + counts[first]
        while upto <= k1:
            last += 1
            upto += counts[last]
        picked = np.empty(upto - below)
        at = 0
        for x in kept:
            if first <= min(int((x - lo) * scale), MEDIAN_BINS - 1) <= last:
                picked[at] = x
                at += 1
        k0, k1 = k0 - below, k1 - below
        if picked.size <= MEDIAN_SORT or picked.size == kept.size:
            picked.sort()
            return float(picked[k0]), float(picked[k1])
        kept, lo, hi = picked, picked.min(), picked.max()
    return lo, lo


@numba.njit(cache=True)
def order_pair(values: F64, k0: int, k1: int) -> tuple[float, float]:
    """The k0-th and k1-th smallest of a non-empty array (k0 ≤ k1 ≤ k0 + 1; NaN if one is
    NaN), by exact selection (`_order_pair`) when all are finite."""
    lo, hi = values.min(), values.max()
    if np.isnan(lo) or np.isnan(hi):
        return np.nan, np.nan
    if np.isinf(lo) or np.isinf(hi):
        ordered = np.sort(values)
        return float(ordered[k0]), float(ordered[k1])
    return _order_pair(values, k0, k1, lo, hi)


@numba.njit(cache=True)
def middle(values: F64) -> tuple[float, float]:
    """The two middle values of the sorted non-empty `values` (the same one twice if their
    number is odd; NaN if one is NaN)."""
    return order_pair(values, (values.size - 1) // 2, values.size // 2)


@numba.njit(cache=True)
def percentile(values: F64, q: float) -> float:
    """np.percentile(values, q) of a non-empty array, bit for bit: numpy's linear
    interpolation between the two order statistics around (n − 1)·q/100."""
    n = values.size
    index = (n - 1) * (q / 100.0)
    if index >= n - 1:
        a, _ = order_pair(values, n - 1, n - 1)
        return a
    below = math.floor(index)
    a, b = order_pair(values, int(below), int(below) + 1)
    t = index - below
    step = b - a
    return a + step * t if t < 0.5 else b - step * (1.0 - t)


@numba.njit(cache=True)
def median(values: F64) -> float:
    """np.median of a non-empty array, bit for bit: the middle value, or the mean of the two."""
    a, b = middle(values)
    return a if values.size % 2 else (a + b) / 2.0
