"""The joint cut: each pixel to the background or to one track, all tracks at once.

All tracks and the background compete for the pixels in one Potts energy (α-expansion,
`tofcut.tracker.multicut`) whose data term is the paper's eq. (6): a pixel's cost for track k
grows with its 3D distance from the track's prediction, measured in the track's own shape
(so a person and a box are both "near" over their own extent) and from its predicted surface
(so two touching objects are told apart), and its cost for the background with how far it
stands out in front of the empty-scene range model; neighbours are tied by eq. (7)'s weights.

Before the cut, pixels are fixed to the background where no labelling of their neighbours
could make an object label pay (object cost minus background cost above the sum of the
pixel's ties), and so are runs of invalid pixels (no data cost either way) that touch no
pixel left free; the minimum over the rest is the minimum of the whole frame. A track's
distance from a pixel that it could not win even at its shape's distance alone is not
measured (it costs inf) unless the cut needs it. The per-pixel loops are compiled
(`cut_kernels`, `distance_kernels`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from tofcut._types import F64, I64, U16, B
from tofcut.driver.frames import Frame
from tofcut.tracker import cut_kernels, distance_kernels
from tofcut.tracker.background import MEDIAN_SHARES, BackgroundModel
from tofcut.tracker.live_track import LiveTrack, SortedSurface
from tofcut.tracker.multicut import PottsProblem, solve_binary, solve_potts
from tofcut.tracker.neighbours import EIGHT, FACTORS
from tofcut.tracker.params import TrackerParams

SQRT2 = math.sqrt(2.0)
CEILING_MARGIN = 1e-6
"""Slack on the cost a label may have and still win a pixel, against rounding."""
_NO_POINTS = np.zeros((0, 3))


@dataclass(frozen=True, eq=False)
class Ties:
    """Eq. (7)'s Potts weights of the neighbour pairs that can matter
    (`cut_kernels.tie_weights`)."""

    weights: F64
    """(4, H, W) by a pair's first pixel and its direction (`neighbours.OFFSETS`)."""
    total: F64
    """(H, W) the sum of each pixel's ties that can matter (0 elsewhere)."""


@dataclass(frozen=True, eq=False)
class FreePixels:
    """The pixels some labelling of their neighbours could give an object
    (`cut_kernels.free_pixels`)."""

    mask: B
    rows: I64
    cols: I64
    """Where they are, in row-major order."""
    points: F64
    """(N, 3) their 3D points."""
    noise: F64
    """Their range noise."""
    ceiling: F64
    """The most a label may cost at each and still win it."""


@dataclass(frozen=True, eq=False)
class CutNodes:
    """The cut's nodes: its free pixels, in row-major order (`cut_kernels.cut_nodes`)."""

    index: I64
    """(H, W) each pixel's node, −1 where it has none."""
    rows: I64
    cols: I64
    """The nodes' pixels."""
    unary: F64
    """(labels, nodes) each label's cost: 0 the background, k the k-th track."""
    least: F64
    """(tracks, nodes) a track's cost from its shape alone where its surface was not
    measured (its cost in `unary` is then inf), nan where it was."""
    ties: F64
    """The sum of each node's ties."""


@dataclass(frozen=True, eq=False)
class Distances:
    """Each point's distance cost from each track (`JointCut.distances_from`)."""

    distance: F64
    """(tracks, N) inf where not measured, or beyond the track's reach."""
    floor: F64
    """(tracks, N) the cost from the shape alone where the distance was not measured, nan
    where it was."""


@dataclass(frozen=True, eq=False)
class Surfaces:
    """The tracks' surfaces as `distance_kernels.track_distances` takes them."""

    clouds: F64
    """(N, 3) all the clouds, each arranged by `distance_kernels.sort_surfaces`."""
    starts: I64
    """Where each track's cloud starts (and, last, where the last ends)."""
    axes: I64
    """The axis each cloud is sorted along."""


@dataclass(frozen=True, eq=False)
class Part:
    """One part of the Potts problem that more than two labels may win."""

    nodes: I64
    edges: I64
    labels: I64
    """The labels that may win some node of it (the background first)."""


@dataclass(frozen=True, eq=False)
class PottsParts:
    """A Potts problem in parts: nodes no edge joins are independent problems, and in each part
    only the labels that could win some node there (its cost within the node's total ties of
    the cheapest) take part (`cut_kernels.split_parts`)."""

    part_of: I64
    """Each node's part."""
    order: I64
    bounds: I64
    """The nodes grouped by part: part k's are order[bounds[k]:bounds[k + 1]]."""
    edge_order: I64
    edge_bounds: I64
    """The edges grouped likewise."""
    cheapest: I64
    """Each node's cheapest label: the answer for every node without edges."""
    can_win: B
    """(labels, parts) whether a label may win some node of a part."""
    contenders: I64
    """How many labels may win each part an edge joins (0 in the others)."""

    @classmethod
    def of(cls, unary: F64, i: I64, j: I64, ties: F64) -> PottsParts:
        """The parts of the problem with costs `unary`, edges (i, j) and each node's `ties`."""
        return cls(*cut_kernels.split_parts(unary, i, j, ties))

    def contested(self) -> list[Part]:
        """The parts more than two labels may win."""
        return [
            Part(
                self.order[self.bounds[k] : self.bounds[k + 1]],
                self.edge_order[self.edge_bounds[k] : self.edge_bounds[k + 1]],
                np.nonzero(self.can_win[:, k])[0],
            )
            for k in np.nonzero(self.contenders > 2)[0]
        ]

    def solve(self, unary: F64, i: I64, j: I64, w: F64, contested: list[Part]) -> I64:
        """Each node's label at the minimum, part by part: a cut of the `contested` parts
        each (their costs exact wherever a cut of more than two labels may weigh them; a
        cost left inf is one the track cannot win whatever the neighbours hold), and one
        exact cut for all the parts where one track meets the background."""
        chosen = self.cheapest.copy()
        local = np.empty(unary.shape[1], np.int64)
        for part in contested:
            local[part.nodes] = np.arange(part.nodes.size)
            edges = part.edges
            problem = PottsProblem(
                unary[part.labels][:, part.nodes], local[i[edges]], local[j[edges]], w[edges]
            )
            chosen[part.nodes] = part.labels[solve_potts(problem)]
        binary = self.contenders == 2
        if binary.any():
            nodes, track, pair, bi, bj, bw = cut_kernels.binary_parts(
                unary, i, j, w, self.part_of, self.order, self.edge_order, binary, self.can_win
            )
            chosen[nodes] = np.where(solve_binary(PottsProblem(pair, bi, bj, bw)) == 1, track, 0)
        return chosen


class JointCut:
    """The joint cut of all tracks against the background (see the module's docstring)."""

    def __init__(self, params: TrackerParams) -> None:
        self.params = params
        p = params
        self._reach_per_sigma = math.sqrt(p.background_cap / max(p.surface_weight, 1e-12))
        """Farthest a track's surface can be from a point it could still win, in its spread."""
        self._most_ties = 2 * p.smoothness * float(FACTORS.sum())
        """The most a pixel's ties can add up to (all eight neighbours at its place)."""

    def labels(
        self,
        frame: Frame,
        noise: F64,
        tracks: list[LiveTrack],
        background: BackgroundModel,
        seen: F64,
    ) -> U16:
        """Labels (0 or a track id) of every pixel of `frame` (its range noise `noise`, its
        ranges as the scenery is compared with `seen`: `BackgroundModel.seen_range`)."""
        p = self.params
        h, w = frame.shape
        labels = np.zeros((h, w), np.uint16)
        if not tracks:
            return labels
        valid = frame.valid
        u0 = self.background_cost(frame, background, seen)
        u0[~valid] = 0.0
        # ties only where they can matter: where the pixel's own ties could free it, and
        # around invalid pixels (which a run of them may free)
        near = ~valid | (p.object_cost - u0 <= self._most_ties + CEILING_MARGIN)
        exps = cut_kernels.tie_exponents(frame.xyz, valid, near, 2 * p.smoothness_sigma_m**2)
        ties = Ties(*cut_kernels.tie_weights(np.exp(exps), valid, near, p.smoothness))
        free = FreePixels(
            *cut_kernels.free_pixels(valid, u0, ties.total, frame.xyz, noise, p.object_cost)
        )
        if not free.rows.size:
            return labels
        # the 3D distance term can only add cost: now fix what no track can win
        measured = self.distances_from(tracks, free.points, free.noise, free.ceiling)
        mask = free.mask  # fixed in place from here on
        cost = cut_kernels.object_costs(
            measured.distance, p.object_cost, p.beta, u0, ties.total, free.rows, free.cols, mask
        )
        if not mask.any():
            return labels
        if not valid.all():
            runs, _ = ndimage.label(mask | ~valid, structure=EIGHT)
            keep = np.unique(runs[mask])
            mask |= ~valid & np.isin(runs, keep[keep > 0])
        # invalid pixels have no data cost either way; where a track's surface was not
        # measured, `least` holds its cost from the shape alone
        nodes = CutNodes(
            *cut_kernels.cut_nodes(mask, free.rows, free.cols, u0, ties.total, cost, measured.floor)
        )
        cut_kernels.add_fixed_ties(nodes.unary, nodes.index, ties.weights, nodes.rows, nodes.cols)
        ei, ej, ew = cut_kernels.free_edges(nodes.index, ties.weights, nodes.rows, nodes.cols)
        parts = PottsParts.of(nodes.unary, ei, ej, nodes.ties)
        contested = parts.contested()
        if contested:
            self._make_exact(contested, nodes, ties, tracks, frame, noise)
        chosen = parts.solve(nodes.unary, ei, ej, ew, contested)
        ids = np.array([0] + [t.id for t in tracks], np.uint16)
        labels[nodes.rows, nodes.cols] = ids[chosen]
        return labels

    def background_cost(self, frame: Frame, background: BackgroundModel, seen: F64) -> F64:
        """Each pixel's cost for the background: half the square of how far it stands in
        front of the scenery, in noise sigmas, less the deadband, at most `background_cap`;
        `unknown_cost` where the scenery is not known (everywhere, before it is learned)."""
        p = self.params
        bg = background
        if not bg.ready:
            return np.full(frame.shape, p.unknown_cost)
        q = bg.params
        cost: F64 = cut_kernels.background_cost(
            bg.range, bg.sigma, bg.known, seen, frame.valid, q.noise_factor,
            q.min_height_sigmas * q.min_height_m, MEDIAN_SHARES, p.deadband,
            p.background_cap, p.unknown_cost,
        )  # fmt: skip
        return cost

    def distances(self, tracks: list[LiveTrack], points: F64, noise: F64) -> F64:
        """(tracks, N) each point's distance cost from each track's prediction: squared
        Mahalanobis distance in the track's shape, plus the squared distance from its
        predicted surface in units of `surface_sigma_m`, or of the noise of the difference
        between a point and the surface where that is more (`noise`, each point's range
        noise; inf beyond any track's reach)."""
        return self.distances_from(tracks, points, noise).distance

    def distances_from(
        self, tracks: list[LiveTrack], points: F64, noise: F64, ceiling: F64 | None = None
    ) -> Distances:
        """`distances`; given a `ceiling` per point (the most a label may cost there and still
        win it), the surface is only measured where the shape's distance alone leaves the
        cost below it: elsewhere the distance is inf, and `floor` holds the cost from the
        shape alone."""
        p = self.params
        if ceiling is None:
            ceiling = np.full(len(points), np.inf)
        surfaces = self._surfaces(tracks)
        spread = np.maximum(p.surface_sigma_m, SQRT2 * noise)
        distance, floor = distance_kernels.track_distances(
            points, ceiling + CEILING_MARGIN,
            np.array([t.filter.position for t in tracks]).reshape(-1, 3),
            np.linalg.inv(np.array([t.shape for t in tracks]).reshape(-1, 3, 3)),
            surfaces.clouds, surfaces.starts, surfaces.axes, p.object_cost, p.beta,
            p.surface_weight, spread, spread.max(initial=0.0) * self._reach_per_sigma,
        )  # fmt: skip
        return Distances(distance, floor)

    def _surfaces(self, tracks: list[LiveTrack]) -> Surfaces:
        """The tracks' surfaces, each track's arranged once while its cloud stays the same
        (`LiveTrack.surface`; those not arranged yet all in one call)."""
        stale = [t for t in tracks if t.surface is None]
        if stale:
            bounds = np.cumsum([0] + [len(t.cloud) for t in stale]).astype(np.int64)
            cloud, axis = distance_kernels.sort_surfaces(
                np.concatenate([t.cloud for t in stale]), bounds
            )
            for k, t in enumerate(stale):
                t.surface = SortedSurface(cloud[bounds[k] : bounds[k + 1]], int(axis[k]))
            if len(stale) == len(tracks):  # all of them, in order
                return Surfaces(cloud, bounds, axis)
        starts = np.cumsum([0] + [len(t.cloud) for t in tracks]).astype(np.int64)
        if not tracks:
            return Surfaces(_NO_POINTS, starts, np.zeros(0, np.int64))
        arranged = [t.surface for t in tracks if t.surface is not None]
        return Surfaces(
            np.concatenate([s.points for s in arranged]),
            starts,
            np.array([s.axis for s in arranged], np.int64),
        )

    def _make_exact(
        self,
        contested: list[Part],
        nodes: CutNodes,
        ties: Ties,
        tracks: list[LiveTrack],
        frame: Frame,
        noise: F64,
    ) -> None:
        """Every track's cost exact (in `nodes.unary`, in place) wherever a cut of the
        `contested` parts may weigh it. A node never takes a label that costs more than its
        ties above every label it could hold: it would do better back with that one
        whatever its neighbours hold; such a label's cost decides no cut (it may stay inf).
        Others are made exact, until the labels left are all of that kind."""
        p = self.params
        unary, least = nodes.unary, nodes.least
        # each (track label, node) of the contested parts
        labels = np.concatenate([np.repeat(c.labels[1:], c.nodes.size) for c in contested])
        cells = np.concatenate([np.tile(c.nodes, c.labels.size - 1) for c in contested])
        while True:
            # the labels a node may hold are exact and finite (an inf one never is)
            need = cut_kernels.unmeasured_needed(
                labels, cells, unary, least, nodes.ties, CEILING_MARGIN
            )
            if not need.any():
                return
            for label in np.unique(labels[need]):
                at = cells[need & (labels == label)]
                v, u = nodes.rows[at], nodes.cols[at]
                one = [tracks[label - 1]]
                value = (
                    p.object_cost
                    + p.beta * self.distances_from(one, frame.xyz[v, u], noise[v, u]).distance[0]
                )
                unary[label, at] = cut_kernels.add_fixed_ties_at(
                    value, nodes.index, ties.weights, v, u
                )
                least[label - 1, at] = np.nan
