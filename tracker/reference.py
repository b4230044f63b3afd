"""The tracker's numpy reference: `ReferenceTracker` is the tracker made of parts that compute
the cut (`ReferenceCut`), the pieces (`ReferencePieces`), the scenery's following
(`ReferenceBackground`) and the range noise with the plain numpy code the compiled kernels
(`tofcut.tracker.compiled`) replaced. Tests run both trackers over the same frames and require
the same labels and tracks; it is not fast. Each part replaces steps of the tracker's own by
name, and says so at import where one of them is no longer a step there."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tofcut._types import F64, I32, I64, U16, B
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.frames import Frame
from tofcut.tracker import stats_kernels
from tofcut.tracker.background import (
    BLEND_SIGMAS,
    BLEND_VARIANCE_SHARE,
    MEDIAN_SHARES,
    BackgroundModel,
    near_any,
    on_belt_height,
    standing_regions,
)
from tofcut.tracker.cut import JointCut
from tofcut.tracker.live_track import LiveTrack
from tofcut.tracker.multicut import PottsProblem, solve_binary, solve_potts
from tofcut.tracker.neighbours import EIGHT, FACTORS, Region, pair_slices
from tofcut.tracker.noise import FIT_STRIDE
from tofcut.tracker.params import TrackerParams
from tofcut.tracker.pieces import STEP_APART, Pieces, Quietened
from tofcut.tracker.stats import MAD_TO_SIGMA
from tofcut.tracker.tracker import Tracker

T = TypeVar("T")


def range_noise(frame: Frame, floor_m: float) -> F64:
    """`tofcut.tracker.noise.range_noise` in plain numpy."""
    with np.errstate(divide="ignore", invalid="ignore"):
        shape = np.sqrt(np.maximum(frame.intensity, 0.0)) / frame.amplitude
    shape[~frame.valid | ~np.isfinite(shape)] = np.inf
    r, s = frame.range[::FIT_STRIDE], shape[::FIT_STRIDE]
    second = r[:, :-2] - 2.0 * r[:, 1:-1] + r[:, 2:]
    spread = np.sqrt(s[:, :-2] ** 2 + 4.0 * s[:, 1:-1] ** 2 + s[:, 2:] ** 2)
    usable = np.isfinite(spread) & (spread > 0)
    if not usable.any():
        return np.where(frame.valid, floor_m, np.inf)
    scale = MAD_TO_SIGMA * float(np.median(np.abs(second[usable]) / spread[usable]))
    return np.maximum(scale * shape, floor_m)


def _replacing(base: type) -> Callable[[type[T]], type[T]]:
    """A reference part replaces steps of `base` by name: fail at once, on import, where one
    of them is not a step of `base` (renamed or removed there, the reference's version
    would go unused, and the equivalence tests would compare the compiled path with
    itself)."""

    def check(cls: type[T]) -> type[T]:
        replaced = [name for name, value in vars(cls).items() if callable(value)]
        missing = [name for name in replaced if not callable(getattr(base, name, None))]
        if missing:
            raise TypeError(f"{cls.__name__} replaces {missing}, which {base.__name__} lacks")
        return cls

    return check


@_replacing(BackgroundModel)
class ReferenceBackground(BackgroundModel):
    """The empty-scene model following the scene in plain numpy."""

    def update(
        self,
        frame: Frame,
        free: B,
        noise: F64,
        occupied: F64,
        reach: float,
        seen: F64 | None = None,
    ) -> None:
        p = self.params
        usable = free & frame.valid
        seen = self.seen_range(frame) if seen is None else seen
        with np.errstate(invalid="ignore"):
            deviation = seen - self.range
            farther = frame.valid & (deviation > p.noise_factor * self.sigma)
        self._farther = np.where(farther, self._farther + 1, 0)
        self._farther_min = np.where(farther, np.fmin(self._farther_min, seen), np.inf)
        unknown = usable & ~self.known
        slot = self._unknown_seen % p.reveal_frames
        rows, cols = np.nonzero(unknown)
        self._unknown_reads[slot[rows, cols], rows, cols] = seen[rows, cols]
        self._unknown_seen = np.where(unknown, self._unknown_seen + 1, 0)
        newly = self._unknown_seen >= p.reveal_frames
        newly &= ~near_any(frame.xyz, newly, occupied, reach)
        revealed = self._farther >= p.reveal_frames
        blend = usable & self.known & (np.abs(deviation) <= BLEND_SIGMAS * self.sigma)
        self.range[blend] += p.rate * deviation[blend]
        var = self.sigma[blend] ** 2
        var += p.rate * (deviation[blend] ** 2 / BLEND_VARIANCE_SHARE - var)
        self.sigma[blend] = np.maximum(np.sqrt(var), p.min_sigma_m)
        self.range[revealed] = self._farther_min[revealed]
        self.range[newly] = np.median(self._unknown_reads, axis=0)[newly]
        self.sigma[newly] = noise[newly]
        jump = revealed | newly
        self._farther[jump] = 0
        self._farther_min[jump] = np.inf
        self._unknown_seen[newly] = 0
        self.known |= newly

    def hold_belt(self, frame: Frame, belt: BeltGeometry, noise: F64) -> None:
        self._find_held_surface(frame, belt)
        p = self.params
        over = self.known & np.isfinite(self._held_surface)
        then = np.where(np.isnan(self._cleared_range), self._held_surface, self._cleared_range)
        cap = np.maximum(noise, p.min_sigma_m)
        with np.errstate(invalid="ignore"):
            loud = over & (self.sigma > cap)
            self.sigma[loud] = cap[loud]
            came = over & (then - self.range > np.maximum(3.0 * self.sigma, p.min_height_m))
        self.range[came] = then[came]


@_replacing(JointCut)
class ReferenceCut(JointCut):
    """The joint cut in plain numpy over the whole frame. Its steps repeat `JointCut`'s on
    purpose (the same signatures, the same order), in the numpy the tests hold it to."""

    def labels(
        self,
        frame: Frame,
        noise: F64,
        tracks: list[LiveTrack],
        background: BackgroundModel,
        seen: F64,
    ) -> U16:
        p = self.params
        h, w = frame.shape
        labels = np.zeros((h, w), np.uint16)
        if not tracks:
            return labels
        valid = frame.valid
        u0 = self.background_cost(frame, background, seen)
        u0[~valid] = 0.0
        ties, total = _ties(frame, p)
        free = valid & (p.object_cost - u0 <= total)
        if not free.any():
            return labels
        # the 3D distance term can only add cost: now fix what no track can win
        first = np.nonzero(free)
        cost = p.object_cost + p.beta * self.distances(tracks, frame.xyz[first], noise[first])
        free[first] = cost.min(axis=0) - u0[first] <= total[first]
        if not free.any():
            return labels
        column = np.full((h, w), -1, np.int64)
        column[first] = np.arange(first[0].size)
        runs, _ = ndimage.label(free | ~valid, structure=EIGHT)
        keep = np.unique(runs[free])
        free |= ~valid & np.isin(runs, keep[keep > 0])
        n = int(free.sum())
        index = np.full((h, w), -1, np.int64)
        index[free] = np.arange(n)
        where = np.nonzero(free)
        unary = np.zeros((len(tracks) + 1, n))
        unary[0] = u0[where]
        known = column[where]  # invalid pixels have no column: no data cost either way
        unary[1:, known >= 0] = cost[:, known[known >= 0]]
        ei, ej, ew = [], [], []
        for a, b, wt in ties:
            ia, ib = index[a], index[b]
            both = (ia >= 0) & (ib >= 0)
            ei.append(ia[both])
            ej.append(ib[both])
            ew.append(wt[both])
            # a free pixel beside a fixed one pays the tie for any object label
            for mine, other in ((ia, ib), (ib, ia)):
                edge = (mine >= 0) & (other < 0)
                unary[1:] += np.bincount(mine[edge], wt[edge], minlength=n)
        chosen = _solve_by_parts(
            unary, np.concatenate(ei), np.concatenate(ej), np.concatenate(ew), total[where]
        )
        ids = np.array([0] + [t.id for t in tracks], np.uint16)
        labels[where] = ids[chosen]
        return labels

    def distances(self, tracks: list[LiveTrack], points: F64, noise: F64) -> F64:
        p = self.params
        spread = np.maximum(p.surface_sigma_m, np.sqrt(2.0) * noise)
        reach = spread.max(initial=0.0) * np.sqrt(p.background_cap / max(p.surface_weight, 1e-12))
        out = np.empty((len(tracks), len(points)))
        finite = np.isfinite(points).all(axis=1)
        for k, t in enumerate(tracks):
            d = points - t.filter.position
            out[k] = np.einsum("ni,ij,nj->n", d, np.linalg.inv(t.shape), d)
            if p.surface_weight > 0:
                near = np.full(len(points), np.inf)
                near[finite], _ = cKDTree(t.cloud).query(points[finite], distance_upper_bound=reach)
                out[k] += p.surface_weight * (near / spread) ** 2
        return np.where(np.isnan(out), np.inf, out)

    def background_cost(self, frame: Frame, background: BackgroundModel, seen: F64) -> F64:
        p = self.params
        bg = background
        if not bg.ready:
            return np.full(frame.shape, p.unknown_cost)
        nearer, sigma = weighed_nearness(bg, frame, seen)
        z = np.maximum(nearer / sigma - p.deadband, 0.0)
        cost = np.minimum(0.5 * z * z, p.background_cap)
        return np.where(bg.known, cost, p.unknown_cost)


def weighed_nearness(bg: BackgroundModel, frame: Frame, seen: F64) -> tuple[F64, F64]:
    """What the background's cost weighs (`cut_kernels.background_cost` does it in one
    pass): each pixel's nearness (metres in front of the scenery, 0 where unknown or
    invalid; `seen`: the frame's `BackgroundModel.seen_range`) and its noise; where the noise
    is so loud that the lowest object (`min_height_sigmas`) would not stand out pixel by
    pixel, the median of the smallest window round it (3×3 to 7×7, edges repeated) whose
    median's noise is quiet enough, or the largest (a step's edge stays where it is), with
    that median's smaller noise."""
    usable = frame.valid & bg.known
    with np.errstate(invalid="ignore"):
        nearer = np.where(usable, bg.range - seen, 0.0)
    p = bg.params
    limit = p.min_height_sigmas * p.min_height_m
    loud = usable & (p.noise_factor * bg.sigma > limit)
    if not loud.any():
        return nearer, bg.sigma
    radius = np.where(loud, 1, 0)
    for r in range(2, MEDIAN_SHARES.size):
        radius[loud & (p.noise_factor * bg.sigma * MEDIAN_SHARES[r - 1] > limit)] = r
    median = stats_kernels.median3_at(nearer, radius == 1)
    for r in range(2, MEDIAN_SHARES.size):
        wide = radius == r
        if wide.any():
            median[wide] = ndimage.median_filter(nearer, 2 * r + 1, mode="nearest")[wide]
    return median, np.where(loud, bg.sigma * MEDIAN_SHARES[radius], bg.sigma)


@_replacing(Pieces)
class ReferencePieces(Pieces):
    """Masks cut into pieces in plain numpy over the whole frame, repeating `Pieces`' steps
    on purpose (the same signatures, the same order)."""

    def loose(
        self,
        frame: Frame,
        labels: U16,
        noise: F64,
        background: BackgroundModel,
        belt: BeltGeometry | None,
        seen: F64,
    ) -> I32:
        bg = background
        usable = frame.valid & bg.known & (labels == 0)
        body = bg.standing_out(frame) & (labels == 0)
        body |= standing_regions(bg.range, bg.sigma, usable, seen, bg.params)
        if self.params.rigid and belt is not None:
            body &= on_belt_height(frame.xyz, belt)
        return self.split(frame, body, noise, belt)

    def split(
        self,
        frame: Frame,
        body: B,
        noise: F64,
        belt: BeltGeometry | None,
        step_noise: bool = True,
    ) -> I32:
        h, w = frame.shape
        body = body.copy()
        quiet = quietened(frame, body, noise, self.params.connect_m)
        xyz, rng, noise = quiet.xyz, quiet.range, quiet.noise
        spread2 = 9.0 * noise**2 if step_noise else np.zeros(frame.shape)
        for k in (0, 1):  # right, down
            a, b = pair_slices((h, w), k)
            allowed = np.maximum(self.params.connect_m**2, spread2[a] + spread2[b])
            jump = np.sum((xyz[a] - xyz[b]) ** 2, axis=-1) > allowed
            far_a = jump & (rng[a] > rng[b])
            far_b = jump & ~far_a
            body[a] &= ~far_a
            body[b] &= ~far_b
        pieces, _ = ndimage.label(body)
        return self.by_tops(xyz, body, np.asarray(pieces, np.int32), noise, belt)


class ReferenceTracker(Tracker):
    """The tracker with every per-pixel step in plain numpy over the whole frame: the same
    tracker, made of the reference's parts."""

    background_model = ReferenceBackground
    cut_model = ReferenceCut
    pieces_model = ReferencePieces


def _ties(frame: Frame, p: TrackerParams) -> tuple[list[tuple[Region, Region, F64]], F64]:
    """Potts weight of every neighbour pair, λ·exp(−|D_p − D_q|² / 2σ²) (eq. 7), and the sum
    of the weights at each pixel."""
    h, w = frame.shape
    valid = frame.valid
    xyz = frame.xyz
    ties = []
    total = np.zeros((h, w))
    for k, factor in enumerate(FACTORS):
        a, b = pair_slices((h, w), k)
        d2 = np.sum((xyz[a] - xyz[b]) ** 2, axis=-1)
        wt = p.smoothness * factor * np.exp(-d2 / (2 * p.smoothness_sigma_m**2))
        wt[~(valid[a] & valid[b])] = p.smoothness * factor
        ties.append((a, b, wt))
        total[a] += wt
        total[b] += wt
    return ties, total


def _solve_by_parts(unary: F64, i: I64, j: I64, w: F64, ties: F64) -> I64:
    """Minimise the Potts energy part by part (see `tofcut.tracker.cut.PottsParts`)."""
    n = unary.shape[1]
    graph = coo_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    parts, part_of = connected_components(graph, directed=False)
    order = np.argsort(part_of, kind="stable")
    bounds = np.searchsorted(part_of[order], np.arange(parts + 1))
    edge_part = part_of[i]
    edge_order = np.argsort(edge_part, kind="stable")
    edge_bounds = np.searchsorted(edge_part[edge_order], np.arange(parts + 1))
    local = np.empty(n, np.int64)
    chosen: I64 = np.argmin(unary, axis=0)  # right for every node without edges
    cheapest = unary.min(axis=0)
    binary: list[tuple[I64, I64, int]] = []
    for k in np.unique(edge_part):
        nodes = order[bounds[k] : bounds[k + 1]]
        edges = edge_order[edge_bounds[k] : edge_bounds[k + 1]]
        local[nodes] = np.arange(nodes.size)
        sub = unary[:, nodes]
        can_win = (sub <= cheapest[nodes] + ties[nodes]).any(axis=1)
        can_win[0] = True
        labels = np.nonzero(can_win)[0]
        if labels.size == 2:
            binary.append((nodes, edges, int(labels[1])))
        elif labels.size > 2:
            problem = PottsProblem(sub[labels], local[i[edges]], local[j[edges]], w[edges])
            chosen[nodes] = labels[solve_potts(problem)]
    if binary:
        nodes = np.concatenate([b[0] for b in binary])
        edges = np.concatenate([b[1] for b in binary])
        track = np.concatenate([np.full(b[0].size, b[2]) for b in binary])
        local[nodes] = np.arange(nodes.size)
        pair = np.stack([unary[0, nodes], unary[track, nodes]])
        problem = PottsProblem(pair, local[i[edges]], local[j[edges]], w[edges])
        chosen[nodes] = np.where(solve_binary(problem) == 1, track, 0)
    return chosen


def quietened(frame: Frame, body: B, noise: F64, step_m: float) -> Quietened:
    """`tofcut.tracker.pieces.quietened` in plain numpy (each window's median by numpy)."""
    loud = body & (noise * 3.0 >= step_m)
    if not loud.any():
        return Quietened(frame.xyz, frame.range, noise)
    radius = np.where(loud, 1, 0)
    for r in range(2, MEDIAN_SHARES.size):
        radius[loud & (noise * MEDIAN_SHARES[r - 1] * STEP_APART >= step_m)] = r
    rng = frame.range.copy()
    for v, u in zip(*np.nonzero(loud), strict=True):
        r = radius[v, u]
        rows, cols = slice(max(v - r, 0), v + r + 1), slice(max(u - r, 0), u + r + 1)
        rng[v, u] = np.median(frame.range[rows, cols][body[rows, cols]])
    moved = loud & (frame.range != 0)
    xyz = frame.xyz.copy()
    xyz[moved] *= (rng[moved] / frame.range[moved])[:, None]
    quiet = noise.copy()
    quiet[loud] *= MEDIAN_SHARES[radius[loud]]
    return Quietened(xyz, rng, quiet)


def rims(labels: U16, seen: F64, valid: B, scenery: F64, known: B) -> U16:
    """`tofcut.tracker.rims_kernels.rims`'s labels in plain numpy: the image shifted by each
    neighbour in turn."""
    h, w = labels.shape
    out = labels.copy()
    free = (labels == 0) & valid & known
    best = np.full((h, w), np.inf)
    for dv, du in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        there = (slice(max(dv, 0), h + min(dv, 0)), slice(max(du, 0), w + min(du, 0)))
        here = (slice(max(-dv, 0), h + min(-dv, 0)), slice(max(-du, 0), w + min(-du, 0)))
        k, r_k, r, bg = labels[there], seen[there], seen[here], scenery[here]
        with np.errstate(invalid="ignore"):
            near = free[here] & (k > 0) & valid[there] & (r_k < bg) & (bg - r > 0.5 * (bg - r_k))
        gap = np.where(near, np.abs(r - r_k), np.inf)
        take = gap < best[here]
        best[here] = np.where(take, gap, best[here])
        out[here] = np.where(take, k, out[here])
    # the notches: five of the eight neighbours held by one track
    padded = np.pad(out, 1)
    around = np.stack([
        padded[1 + dv : 1 + dv + h, 1 + du : 1 + du + w]
        for dv in (-1, 0, 1) for du in (-1, 0, 1) if dv or du
    ])  # fmt: skip
    notched = out.copy()
    for k in np.unique(out[out > 0]):
        notched[(out == 0) & ((around == k).sum(axis=0) >= 5)] = k
    return notched
