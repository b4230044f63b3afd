"""The energies of Arif et al. §4 as arrays: unary costs, pairwise weights, and their value.

A labelling w: P → {0, 1} (1 = target) of an H×W frame costs

    E(w) = Σ_p cost1[p]·w_p + cost0[p]·(1 − w_p) + Σ_{p,q} weight[p,q]·[w_p ≠ w_q]

over the 8-neighbour pairs. Pairwise weights are held as a (4, H, W) array: `weights[k, v, u]`
is the weight of the edge from pixel (v, u) to (v, u) + OFFSETS[k] (zero where that falls
outside the frame), so every undirected 8-neighbour edge appears exactly once.

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
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
BOOL = npt.NDArray[np.bool_]

OFFSETS: tuple[tuple[int, int], ...] = ((0, 1), (1, 0), (1, 1), (1, -1))
"""(dv, du) of the four forward 8-neighbour directions: east, south, south-east, south-west."""

DIRECTIONS: tuple[tuple[int, int], ...] = OFFSETS + tuple((-dv, -du) for dv, du in OFFSETS)
"""All 8 neighbour directions: OFFSETS (forward), then their opposites (backward)."""
DV = np.array([dv for dv, _ in DIRECTIONS], dtype=np.int64)
DU = np.array([du for _, du in DIRECTIONS], dtype=np.int64)

DIAGONAL = (False, False, True, True)
"""Which of OFFSETS are diagonal (their pixel centres are √2 apart)."""

GREY_PERCENTILE = 99.0
"""The intensity percentile mapped to grey level 255."""


Region = tuple[slice, slice]


def pair_slices(shape: tuple[int, int], k: int) -> tuple[Region, Region]:
    """Slices (p, q) selecting every pixel p whose neighbour q = p + OFFSETS[k] is in frame."""
    h, w = shape
    dv, du = OFFSETS[k]
    rows_p, rows_q = slice(0, h - dv), slice(dv, h)
    if du >= 0:
        cols_p, cols_q = slice(0, w - du), slice(du, w)
    else:
        cols_p, cols_q = slice(-du, w), slice(0, w + du)
    return (rows_p, cols_p), (rows_q, cols_q)


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


def energy_of(labels: BOOL, cost1: F64, cost0: F64, weights: F64) -> float:
    """E(w) of a labelling (True = target): unary costs plus the weights of cut edges."""
    total = float(np.where(labels, cost1, cost0).sum())
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(labels.shape, k)
        total += float(weights[k][sp][labels[sp] != labels[sq]].sum())
    return total


# --- data terms (§4.1) ------------------------------------------------------------------------


def grey_levels(intensity: F64, valid: BOOL, reference: float | None = None) -> F64:
    """Intensity as 8-bit grey levels (not clipped): 255·I / I_ref."""
    ref = intensity_reference(intensity, valid) if reference is None else reference
    return intensity * (255.0 / ref)


def intensity_reference(intensity: F64, valid: BOOL) -> float:
    """I_ref: the 99th percentile of the valid intensity (1.0 if there is none above 0)."""
    values = intensity[valid]
    ref = float(np.percentile(values, GREY_PERCENTILE)) if values.size else 0.0
    return ref if ref > 0.0 else 1.0


def intensity_costs(grey: F64, valid: BOOL, mu_t: float, mu_b: float) -> tuple[F64, F64]:
    """Eq. (5): (cost1, cost0) = ((g − µt)², (g − µb)²), zero at invalid pixels."""
    cost1 = np.where(valid, (grey - mu_t) ** 2, 0.0)
    cost0 = np.where(valid, (grey - mu_b) ** 2, 0.0)
    return cost1, cost0


def range_penalty(xyz: F64, valid: BOOL, mu_d: F64, beta: float) -> F64:
    """Eq. (6)'s extra target cost β‖D_p − µd‖² (D_p the pixel's 3D point), zero at invalid."""
    d2 = ((xyz - mu_d) ** 2).sum(axis=-1)
    return np.where(valid, beta * d2, 0.0)


def image_penalty(valid: BOOL, centre: tuple[float, float], beta: float) -> F64:
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
    valid: BOOL,
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
        raise ValueError("give both grey and sigma_i, or neither")
    weights = np.zeros((len(OFFSETS), *valid.shape))
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(valid.shape, k)
        d2 = ((xyz[sp] - xyz[sq]) ** 2).sum(axis=-1)
        exponent = (d2 if squared else np.sqrt(d2)) / (-2.0 * sigma_s**2)
        if grey is not None and sigma_i is not None:
            exponent -= (grey[sp] - grey[sq]) ** 2 / (2.0 * sigma_i**2)
        both = valid[sp] & valid[sq]
        weights[k][sp] = np.where(both, np.exp(np.where(both, exponent, 0.0)), 0.0)
    return weights


# --- estimating the model from the frame ------------------------------------------------------


def window_median(values: F64, valid: BOOL, centre: tuple[int, int], radius: int) -> float | None:
    """Median of the valid values in the (2r+1)² window around (u, v); None if none is valid."""
    u, v = centre
    window = (slice(max(v - radius, 0), v + radius + 1), slice(max(u - radius, 0), u + radius + 1))
    picked = values[window][valid[window]]
    return float(np.median(picked, axis=0)) if picked.size else None


def window_median_point(xyz: F64, valid: BOOL, centre: tuple[int, int], radius: int) -> F64 | None:
    """Per-axis median of the valid 3D points in the window around (u, v); None if none."""
    u, v = centre
    window = (slice(max(v - radius, 0), v + radius + 1), slice(max(u - radius, 0), u + radius + 1))
    picked = xyz[window][valid[window]]
    return np.median(picked, axis=0) if picked.size else None


def background_intensity(grey: F64, valid: BOOL, xyz: F64, mu_d: F64, margin_m: float) -> float:
    """µb: median grey level of the valid pixels farther than `margin_m` from µd, or from
    every row of a (K, 3) array of µd (all valid pixels if none is that far)."""
    points = np.atleast_2d(mu_d)
    d2 = ((xyz[..., None, :] - points) ** 2).sum(axis=-1)
    far = valid & (d2 > margin_m**2).all(axis=-1)
    pick = far if far.any() else valid
    return float(np.median(grey[pick]))


def nearest_pixel(xyz: F64, valid: BOOL, point: F64) -> tuple[int, int]:
    """(u, v) of the valid pixel whose ray passes closest to a 3D point (its image position)."""
    norm = np.linalg.norm(xyz, axis=-1)
    cosine = (xyz @ point) / np.maximum(norm * float(np.linalg.norm(point)), 1e-12)
    cosine = np.where(valid & (norm > 0), cosine, -np.inf)
    v, u = np.unravel_index(int(np.argmax(cosine)), cosine.shape)
    return int(u), int(v)


def neighbour_distance(xyz: F64, valid: BOOL) -> float:
    """Median 3D distance between valid horizontal and vertical neighbours: the frame's scale
    of "the same surface" (pixel footprint plus range noise)."""
    steps = []
    for k in (0, 1):
        sp, sq = pair_slices(valid.shape, k)
        both = valid[sp] & valid[sq]
        steps.append(np.sqrt(((xyz[sp] - xyz[sq]) ** 2).sum(axis=-1))[both])
    joined = np.concatenate(steps)
    return float(np.median(joined)) if joined.size else 0.0


def neighbour_step(grey: F64, valid: BOOL) -> float:
    """Median |g_p − g_q| between valid horizontal and vertical neighbours, grey levels."""
    steps = []
    for k in (0, 1):
        sp, sq = pair_slices(valid.shape, k)
        both = valid[sp] & valid[sq]
        steps.append(np.abs(grey[sp] - grey[sq])[both])
    joined = np.concatenate(steps)
    return float(np.median(joined)) if joined.size else 0.0
