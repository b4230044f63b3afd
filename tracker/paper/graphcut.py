"""Minimising a binary energy (see `tofcut.tracker.paper.energy`) by graph cut with PyMaxflow.

Three solvers with the same minima:

- `solve_reference`: the obvious one, a full-frame grid graph. It is the yardstick the fast
  solvers are tested and benchmarked against, and stays as such.
- `solve_reduced`, for the data-term energies: pixels whose label is forced by their unary
  cost are fixed without a graph; only the rest go into it.
- `solve_cropped`, for the §4.2 energies: the graph of a window around the seed, grown until
  a certificate shows that nothing outside it can change the minimum; inside the window,
  neighbours that no minimum separates are merged first (`tofcut.tracker.paper.contraction`), so
  the max-flow no longer pushes 1/n of flow into each pixel of a surface one at a time.

Why `solve_reduced` is exact (persistency). Let δ_p = cost1[p] − cost0[p] and W_p the sum of
the weights of p's edges. If δ_p > W_p, relabelling p from target to background changes any
labelling's energy by at most −δ_p + W_p < 0, so no minimum has p in the target; likewise
δ_p < −W_p forces the target. Fixing such pixels and folding each edge to a fixed neighbour
into the free pixel's unary cost leaves an energy over the free pixels whose minima are
exactly the original minima restricted to them (all minima agree on the fixed pixels), so
the rule applies again to it, with W_p counting only edges to free pixels; it is applied
until no free pixel is forced (the order does not matter: every pixel fixed is fixed in
every minimum). The first pass compares |δ_p| with W_p, or with a bound of every W_p
when the energy gives one (`Problem.weight_bound`: then only the unary costs are read);
pixels it leaves free but the exact W_p would have fixed are fixed by the next passes, so
the result is the same. The per-pixel work is compiled (numba); the graph is PyMaxflow's.

Why `solve_cropped` is exact (a lower bound met). For a window Q, dropping the non-negative
weights of the edges that leave Q and bounding each outside pixel's unary cost from below
gives, for every labelling w,
    E(w) ≥ E_Q(w restricted to Q) + Σ_{p∉Q} min(cost1[p], cost0[p]),
so E* ≥ min E_Q + Σ_{p∉Q} min(cost1, cost0). Take a minimiser of E_Q and label everything
outside Q background. If every outside pixel prefers the background (cost0 ≤ cost1; for §4.2
every pixel but the seed, which starts inside Q) and no pixel on a side of Q that borders the
rest of the frame is labelled target (so no edge leaving Q is cut), its energy equals that
lower bound: it is a global minimum. Otherwise the sides the target touches are pushed out
and the window is solved again, at worst up to the whole frame. Parts of the frame the
weights disconnect from the seed are thus never put into a graph. E_Q has only the edges
inside Q: merging within the window ignores the edges that leave it.
"""

from __future__ import annotations

from dataclasses import dataclass

import maxflow
import numba
import numpy as np
import numpy.typing as npt

from tofcut._types import F64, I64, B
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.neighbours import DIRECTIONS, DU, DV, OFFSETS
from tofcut.tracker.paper.contraction import cut_merged, merged_nodes, min_cut
from tofcut.tracker.paper.energy import edge_weight

FULL_GRAPH_SHARE = 0.5
"""`solve_reduced` cuts the full grid when more than this share of the pixels stays free."""
STRUCTURES = [np.pad(np.array([[1]]), ((1 + dv, 1 - dv), (1 + du, 1 - du))) for dv, du in OFFSETS]
"""PyMaxflow grid structures, one per direction of OFFSETS (a 1 at the neighbour's place)."""


@dataclass(frozen=True, eq=False)
class Problem:
    """A binary energy on an H×W grid: unary costs of each label and 8-neighbour weights."""

    cost1: F64
    """(H, W) cost of labelling the pixel target."""
    cost0: F64
    """(H, W) cost of labelling the pixel background."""
    weights: F64
    """(4, H, W) non-negative edge weights along `energy.OFFSETS` (see
    `tofcut.tracker.paper.energy`)."""
    weight_bound: float | None = None
    """An upper bound of every pixel's total edge weight W_p, when the energy knows one in
    closed form (Potts: `energy.potts_bound`); `solve_reduced` then reads only the unary
    costs in its pass over the frame. None: it sums each pixel's weights instead."""

    def __post_init__(self) -> None:
        shape = self.cost1.shape
        if len(shape) != 2 or self.cost0.shape != shape:
            raise SegmentError(f"unary costs must be two equal (H, W) arrays, not {shape}")
        if self.weights.shape != (len(OFFSETS), *shape):
            raise SegmentError(f"weights must be (4, H, W), not {self.weights.shape}")
        if self.weight_bound is not None and not self.weight_bound >= 0.0:
            raise SegmentError(f"weight_bound must be ≥ 0, not {self.weight_bound!r}")

    @property
    def shape(self) -> tuple[int, int]:
        return (self.cost1.shape[0], self.cost1.shape[1])


@dataclass(frozen=True, eq=False)
class Solution:
    """A minimising labelling and how much of the problem went into the graph."""

    labels: B
    """(H, W), True = target."""
    graph_nodes: int
    """Nodes of the graph(s) cut: pixels, or groups of merged pixels (summed over the windows
    of `solve_cropped`); pixels decided without a graph do not count."""


def solve_reference(problem: Problem) -> Solution:
    """The full-frame graph: one node per pixel, every edge, every terminal link."""
    h, w = problem.shape
    graph = maxflow.Graph[float](h * w, len(OFFSETS) * h * w)
    nodes = graph.add_grid_nodes((h, w))
    for k, structure in enumerate(STRUCTURES):
        graph.add_grid_edges(nodes, weights=problem.weights[k], structure=structure, symmetric=True)
    graph.add_grid_tedges(nodes, problem.cost1, problem.cost0)
    graph.maxflow()
    return Solution(np.asarray(graph.get_grid_segments(nodes), dtype=bool), h * w)


def solve_reduced(problem: Problem) -> Solution:
    """Fix every pixel whose label its unary cost forces (to a fixed point), cut the rest;
    when most of the frame stays free, the full grid graph is the quicker way to cut it.

    One compiled pass over the frame computes δ_p and the exact W_p of every pixel; the
    rest (propagating the fixed labels, folding their edges into unary costs, the edge list
    of the graph) works on the free pixels and their 8 neighbours only.
    """
    h, w = problem.shape
    labels, pixels, cost1, cost0, heads, tails, caps = _reduce(
        problem.cost1,
        problem.cost0,
        np.ascontiguousarray(problem.weights),
        -1.0 if problem.weight_bound is None else problem.weight_bound,
        int(FULL_GRAPH_SHARE * h * w),
    )
    if pixels.size > FULL_GRAPH_SHARE * h * w:
        return solve_reference(problem)
    m = pixels.size
    if m:
        labels.reshape(-1)[pixels] = min_cut(cost1, cost0, heads, tails, caps)
    return Solution(labels, m)


@numba.njit(cache=True)
def _first_pass(cost1: F64, cost0: F64, weights: F64, bound: float, labels: B, free: B) -> None:
    """labels = δ < 0 and free = |δ| ≤ W_p for every pixel, or |δ| ≤ `bound` if that is
    ≥ 0 (a bound of every W_p: the weights are not read). W_p is summed for the interior in
    one loop that the compiler vectorises, at the border through `edge_weight`."""
    h, w = cost1.shape
    if bound >= 0.0:
        for v in range(h):
            for u in range(w):
                d = float(cost1[v, u]) - float(cost0[v, u])
                labels[v, u] = d < 0.0
                free[v, u] = abs(d) <= bound
        return
    for v in range(1, h - 1):
        for u in range(1, w - 1):
            d = float(cost1[v, u]) - float(cost0[v, u])
            labels[v, u] = d < 0.0
            total = (
                weights[0, v, u]
                + weights[1, v, u]
                + weights[2, v, u]
                + weights[3, v, u]
                + weights[0, v, u - 1]
                + weights[1, v - 1, u]
                + weights[2, v - 1, u - 1]
                + weights[3, v - 1, u + 1]
            )
            free[v, u] = abs(d) <= total
    for v in range(h):
        step = 1 if v == 0 or v == h - 1 else max(w - 1, 1)
        for u in range(0, w, step):
            d = float(cost1[v, u]) - float(cost0[v, u])
            labels[v, u] = d < 0.0
            total = 0.0
            for k in range(len(DIRECTIONS)):
                total += edge_weight(weights, v, u, k)
            free[v, u] = abs(d) <= total


@numba.njit(cache=True)
def _flat_true(flags: B) -> I64:
    """np.flatnonzero of a flat bool array, quicker when few are True: skips 8 at a time."""
    n = flags.size
    words = n // 8
    packed = flags[: words * 8].view(np.uint64)
    count = 0
    for i in range(words):
        if packed[i]:
            count += flags[8 * i : 8 * i + 8].sum()
    count += flags[words * 8 :].sum()
    out = np.empty(count, dtype=np.int64)
    at = 0
    for i in range(words):
        if packed[i]:
            for j in range(8 * i, 8 * i + 8):
                if flags[j]:
                    out[at] = j
                    at += 1
    for j in range(words * 8, n):
        if flags[j]:
            out[at] = j
            at += 1
    return out


@numba.njit(cache=True)
def _reduce(
    cost1: F64, cost0: F64, weights: F64, bound: float, max_free: int
) -> tuple[B, I64, F64, F64, I64, I64, F64]:
    """(labels, free pixels (flat), their cost1 and cost0 with the fixed neighbours' edges
    folded in, and the edges (heads, tails, weights, as indices into the free pixels)
    between them); past `max_free` free pixels after the first pass, stops and returns
    those pixels alone."""
    h, w = cost1.shape
    labels2 = np.empty((h, w), dtype=np.bool_)
    free2 = np.empty((h, w), dtype=np.bool_)
    _first_pass(cost1, cost0, weights, bound, labels2, free2)
    labels, free = labels2.reshape(-1), free2.reshape(-1)
    pixels = _flat_true(free)
    count = pixels.size
    empty_f, empty_i = np.empty(0), np.empty(0, dtype=np.int64)
    if count > max_free:
        return labels2, pixels, empty_f, empty_f, empty_i, empty_i, empty_f
    # each free pixel's edge weights to its 8 neighbours (flat index p + step[k]; 0 where
    # there is no edge), δ with its fixed neighbours' edges folded in, and the weight of its
    # edges to free ones
    wts = np.empty((count, len(DIRECTIONS)))
    d = np.empty(count)
    slack = np.empty(count)
    place = np.empty(h * w, dtype=np.int64)  # read only at free pixels
    flat_weights = weights.reshape(-1)
    step = DV * w + DU  # flat offset to the neighbour
    at = np.empty(len(DIRECTIONS), dtype=np.int64)  # flat offset to the edge's weight
    for k in range(len(DIRECTIONS)):
        kk = k % len(OFFSETS)
        at[k] = kk * h * w if k < len(OFFSETS) else kk * h * w - step[kk]
    for i in range(count):
        p = pixels[i]
        v, u = p // w, p % w
        place[p] = i
        inner = 0 < v < h - 1 and 0 < u < w - 1
        di, si = float(cost1[v, u]) - float(cost0[v, u]), 0.0
        for k in range(len(DIRECTIONS)):
            wt = flat_weights[p + at[k]] if inner else edge_weight(weights, v, u, k)
            wts[i, k] = wt
            if wt == 0.0:
                continue
            q = p + step[k]
            if free[q]:
                si += wt
            elif labels[q]:
                di -= wt
            else:
                di += wt
        d[i], slack[i] = di, si
    # fix every free pixel whose δ beats its slack, and update its free neighbours
    stack = np.empty(count, dtype=np.int64)
    for i in range(count):
        if not free[pixels[i]] or abs(d[i]) <= slack[i]:
            continue
        labels[pixels[i]], free[pixels[i]] = d[i] < 0.0, False
        stack[0], top = i, 1
        while top:
            top -= 1
            j = stack[top]
            target = labels[pixels[j]]
            for k in range(len(DIRECTIONS)):
                wt, q = wts[j, k], pixels[j] + step[k]
                if wt == 0.0 or not free[q]:
                    continue
                iq = place[q]
                slack[iq] -= wt
                d[iq] += -wt if target else wt
                if abs(d[iq]) > slack[iq]:
                    labels[q], free[q] = d[iq] < 0.0, False
                    stack[top] = iq
                    top += 1
    # the graph over the pixels still free
    m = 0
    for i in range(count):
        if free[pixels[i]]:
            place[pixels[i]] = m
            m += 1
    out = np.empty(m, dtype=np.int64)
    out1, out0 = np.empty(m), np.empty(m)
    heads = np.empty(len(OFFSETS) * m, dtype=np.int64)
    tails = np.empty(len(OFFSETS) * m, dtype=np.int64)
    caps = np.empty(len(OFFSETS) * m)
    edges = 0
    for i in range(count):
        p = pixels[i]
        if not free[p]:
            continue
        a = place[p]
        out[a] = p
        c1, c0 = float(cost1.flat[p]), float(cost0.flat[p])
        for k in range(len(DIRECTIONS)):
            wt, q = wts[i, k], p + step[k]
            if wt == 0.0:
                continue
            if free[q]:
                if k < len(OFFSETS):
                    heads[edges], tails[edges], caps[edges] = a, place[q], wt
                    edges += 1
            elif labels[q]:
                c0 += wt
            else:
                c1 += wt
        out1[a], out0[a] = c1, c0
    return labels2, out, out1, out0, heads[:edges], tails[:edges], caps[:edges]


def solve_cropped(problem: Problem, centre: tuple[int, int], half_size: int = 24) -> Solution:
    """Cut a window around `centre` (u, v), grown until certified (module docstring).

    A window is grown before its cut when the pixels merged with `centre` already reach a
    side that borders the rest of the frame: a target holding them would touch that side,
    and an empty one is found by the larger window as well."""
    h, w = problem.shape
    u, v = centre
    v0, v1, u0, u1 = _preferring_target(problem.cost1, problem.cost0, v, u)
    v0, v1 = max(v0 - half_size, 0), min(v1 + half_size + 1, h)
    u0, u1 = max(u0 - half_size, 0), min(u1 + half_size + 1, w)
    nodes = 0
    while True:
        window = (slice(v0, v1), slice(u0, u1))
        cost1, cost0 = problem.cost1[window], problem.cost0[window]
        weights = problem.weights[(slice(None), *window)]
        count, node = merged_nodes(cost1, cost0, weights)
        grow, *bounds = _grown(node, node[v - v0, u - u0], v0, v1, u0, u1, h, w)
        if not grow:
            inner = cut_merged(cost1, cost0, weights, count, node)
            nodes += count
            grow, *bounds = _grown(inner, True, v0, v1, u0, u1, h, w)
            if not grow:
                labels = np.zeros((h, w), dtype=bool)
                labels[window] = inner
                return Solution(labels, nodes)
        v0, v1, u0, u1 = bounds


@numba.njit(cache=True)
def _preferring_target(cost1: F64, cost0: F64, v: int, u: int) -> tuple[int, int, int, int]:
    """(v0, v1, u0, u1), inclusive: the bounding box of (v, u) and every pixel whose unary
    cost prefers the target (cost0 > cost1)."""
    v0, v1, u0, u1 = v, v, u, u
    for r in range(cost1.shape[0]):
        for c in range(cost1.shape[1]):
            if cost0[r, c] > cost1[r, c]:
                v0, v1, u0, u1 = min(v0, r), max(v1, r), min(u0, c), max(u1, c)
    return v0, v1, u0, u1


@numba.njit(cache=True)
def _grown(
    marked: npt.NDArray[np.generic],
    value: object,
    v0: int,
    v1: int,
    u0: int,
    u1: int,
    h: int,
    w: int,
) -> tuple[bool, int, int, int, int]:
    """(grew, v0, v1, u0, u1): the window [v0, v1) × [u0, u1) of an H×W frame pushed out by
    its own height or width on every side where `marked == value` reaches the window's edge
    and the window does not already reach the frame's."""
    rows, cols = v1 - v0, u1 - u0
    up = v0 > 0 and (marked[0] == value).any()
    down = v1 < h and (marked[rows - 1] == value).any()
    left = u0 > 0 and (marked[:, 0] == value).any()
    right = u1 < w and (marked[:, cols - 1] == value).any()
    return (
        up or down or left or right,
        max(v0 - rows, 0) if up else v0,
        min(v1 + rows, h) if down else v1,
        max(u0 - cols, 0) if left else u0,
        min(u1 + cols, w) if right else u1,
    )
