"""Exact graph contraction: merge neighbouring pixels that no minimum of the energy separates.

For any labelling S, E(S) = unary(S) + cut(S) ≥ L + cut(S) with L = Σ_p min(cost1, cost0),
and the all-background and all-target labellings bound the minimum from above:
E* ≤ U = min(Σ cost0, Σ cost1). So every minimum cuts edges of total weight at most
U − L (the "slack"). If every cut separating neighbours p and q weighs more than the slack,
no minimum separates them, and merging them into one node (terminal capacities and edges
summed) leaves exactly the same set of minima.

The weight of every p–q cut is bounded from below by edge-disjoint paths (Menger): the
direct edge plus, through each common 8-neighbour c, min(w(p, c), w(c, q)). Merged pixels
are the connected components of the east and south pairs whose bound exceeds the slack
(diagonal pairs are not merged directly: fewer merges, never a wrong one), found in one
compiled raster scan with union-find; the bound's paths are only summed where the direct
edge alone does not already exceed the slack.

For the §4.2 energy (1/n to the background, the seed's link 1) the slack of a window of m
pixels is (m − 1)/n, at most 1 − 1/n, and
the edges inside a smooth surface (weights near exp(−1/2) with σs at the neighbour step) have
bounds of 2 or more: a whole surface becomes one node, and the max-flow no longer has to
push 1/n of flow to each of its pixels one by one.
"""

from __future__ import annotations

import functools

import maxflow
import numba
import numpy as np

from tofcut._types import F64, I64, B
from tofcut.tracker.components_kernels import number_sets, root
from tofcut.tracker.neighbours import DIRECTIONS, DU, DV, OFFSETS
from tofcut.tracker.paper.energy import edge_weight

MARGIN = 1e-9
"""Relative margin on the slack, so that rounding in the sums never merges a pair a minimum
could separate."""

AXIAL = (0, 1)
"""The OFFSETS along which pixels are merged (east, south): enough to join a surface, and
their merges are connected components of a 4-connected image (see `merged_nodes`)."""


@functools.cache
def _common_neighbours(k: int) -> tuple[tuple[int, int], ...]:
    """For the pair p, q = p + OFFSETS[k]: (index of e, index of q − c) over the common
    8-neighbours c = p + e of p and q."""
    dv, du = OFFSETS[k]
    out = []
    for i, (ev, eu) in enumerate(DIRECTIONS):
        rest = (dv - ev, du - eu)
        if rest in DIRECTIONS:
            out.append((i, DIRECTIONS.index(rest)))
    return tuple(out)


COMMONS = np.array([_common_neighbours(k) for k in AXIAL], dtype=np.int64)
"""(2, 4, 2): for the east and south pairs, the DIRECTIONS index of p → c and of c → q over
their four common neighbours c."""


@numba.njit(cache=True, inline="always")
def _pair_bound(weights: F64, v: int, u: int, slot: int, limit: float) -> float:
    """The lower bound of `cut_lower_bounds` for the pair of (v, u) along OFFSETS[AXIAL[slot]]
    (0 if the neighbour is off the grid), or the direct edge alone once that exceeds `limit`
    (the sum can only be larger)."""
    _, h, w = weights.shape
    if slot == 0 and 0 < v < h - 1 and u < w - 1:  # east, every common neighbour in the grid
        direct = weights[0, v, u]
        if direct > limit:
            return float(direct)
        paths = min(weights[1, v, u], weights[3, v, u + 1])
        paths += min(weights[2, v, u], weights[1, v, u + 1])
        paths += min(weights[1, v - 1, u], weights[2, v - 1, u])
        paths += min(weights[3, v - 1, u + 1], weights[1, v - 1, u + 1])
        return float(paths + direct)
    if slot == 1 and v < h - 1 and 0 < u < w - 1:  # south, likewise
        direct = weights[1, v, u]
        if direct > limit:
            return float(direct)
        paths = min(weights[0, v, u], weights[3, v, u + 1])
        paths += min(weights[2, v, u], weights[0, v + 1, u])
        paths += min(weights[3, v, u], weights[0, v + 1, u - 1])
        paths += min(weights[0, v, u - 1], weights[2, v, u - 1])
        return float(paths + direct)
    # near the border: the same sum (in the order of COMMONS), edges off the grid weigh 0
    k = AXIAL[slot]
    direct = edge_weight(weights, v, u, k)
    if direct > limit:
        return direct
    paths = 0.0
    for c in range(COMMONS.shape[1]):
        i, j = COMMONS[slot, c, 0], COMMONS[slot, c, 1]
        first = edge_weight(weights, v, u, i)
        if first > 0.0:
            paths += min(first, edge_weight(weights, v + DV[i], u + DU[i], j))
    return paths + direct


@numba.njit(cache=True)
def _lower_bounds(weights: F64) -> F64:
    _, h, w = weights.shape
    bounds = np.zeros((len(AXIAL), h, w))
    for slot in range(len(AXIAL)):
        for v in range(h):
            for u in range(w):
                bounds[slot, v, u] = _pair_bound(weights, v, u, slot, np.inf)
    return bounds


def cut_lower_bounds(weights: F64) -> F64:
    """(2, H, W): for each east and south edge of `weights`, a lower bound of the weight of
    every cut that separates its two pixels (the direct edge plus the two-edge paths through
    the four common neighbours, which are edge-disjoint); 0 where the neighbour is off the
    grid. Edges that leave the grid are on no path, whatever `weights` holds for them."""
    return _lower_bounds(weights)


@numba.njit(cache=True)
def slack(cost1: F64, cost0: F64) -> float:
    """U − L: the most any minimum's cut can weigh (module docstring)."""
    sum1 = sum0 = lower = 0.0
    for v in range(cost1.shape[0]):
        for u in range(cost1.shape[1]):
            sum1 += cost1[v, u]
            sum0 += cost0[v, u]
            lower += min(cost1[v, u], cost0[v, u])
    return min(sum0, sum1) - lower


def merged_nodes(cost1: F64, cost0: F64, weights: F64) -> tuple[int, I64]:
    """(number of nodes, (H, W) node of each pixel) after merging every pair of east or south
    neighbours that no minimum separates: the connected components of the pairs whose
    bound exceeds the slack, numbered in the order a raster scan meets them."""
    limit = slack(cost1, cost0)
    return _components(weights, limit + MARGIN * (abs(limit) + 1.0))


@numba.njit(cache=True)
def _components(weights: F64, limit: float) -> tuple[int, I64]:
    """Connected components of the pairs whose bound exceeds `limit`, in one raster scan
    (each pixel joins its west or north neighbour's set) with union-find."""
    _, h, w = weights.shape
    parent = np.empty(h * w, dtype=np.int64)
    for v in range(h):
        for u in range(w):
            p = v * w + u
            west = u > 0 and _pair_bound(weights, v, u - 1, 0, limit) > limit
            north = v > 0 and _pair_bound(weights, v - 1, u, 1, limit) > limit
            if west and north:
                a, b = root(parent, p - 1), root(parent, p - w)
                parent[p] = min(a, b)
                parent[max(a, b)] = min(a, b)
            elif west:
                parent[p] = root(parent, p - 1)
            elif north:
                parent[p] = root(parent, p - w)
            else:
                parent[p] = p
    node = number_sets(parent, 0, 0).reshape(h, w)
    return int(node.max()) + 1, node


def solve_merged(cost1: F64, cost0: F64, weights: F64) -> tuple[B, int]:
    """A minimum of the energy by graph cut on the merged nodes: (labels (H, W), nodes).
    Edges that leave the grid are ignored, whatever `weights` holds for them."""
    count, node = merged_nodes(cost1, cost0, weights)
    return cut_merged(cost1, cost0, weights, count, node), count


def cut_merged(cost1: F64, cost0: F64, weights: F64, count: int, node: I64) -> B:
    """The (H, W) labels of a minimum by graph cut on the nodes of `merged_nodes`."""
    cap1, cap0, heads, tails, caps = _merged_graph(cost1, cost0, weights, count, node)
    labels: B = min_cut(cap1, cap0, heads, tails, caps)[node]
    return labels


def min_cut(source: F64, sink: F64, heads: I64, tails: I64, caps: F64) -> B:
    """Which nodes end on the sink side of a minimum s-t cut (PyMaxflow), given each node's
    capacities from the source and to the sink and undirected edges heads–tails."""
    graph = maxflow.Graph[float](source.size, heads.size)
    ids = graph.add_nodes(source.size)
    if heads.size:
        graph.add_edges(heads, tails, caps, caps)
    graph.add_grid_tedges(ids, source, sink)
    graph.maxflow()
    return np.asarray(graph.get_grid_segments(ids), dtype=bool)


@numba.njit(cache=True)
def _merged_graph(
    cost1: F64, cost0: F64, weights: F64, count: int, node: I64
) -> tuple[F64, F64, I64, I64, F64]:
    """Terminal capacities (summed over each node's pixels) and edges of the merged graph:
    the in-grid edges between two nodes, parallel ones made one (far fewer augmenting
    paths), zero weights left out."""
    h, w = cost1.shape
    cap1, cap0 = np.zeros(count), np.zeros(count)
    for v in range(h):
        for u in range(w):
            cap1[node[v, u]] += cost1[v, u]
            cap0[node[v, u]] += cost0[v, u]
    # the edges between two nodes, as (lower node, higher node, weight), bucketed by the
    # lower node (stable: parallel edges are summed in the order met)
    lower = np.empty(len(OFFSETS) * h * w, dtype=np.int64)
    higher = np.empty(len(OFFSETS) * h * w, dtype=np.int64)
    values = np.empty(len(OFFSETS) * h * w)
    starts = np.zeros(count + 1, dtype=np.int64)
    n = 0
    for k in range(len(OFFSETS)):
        for v in range(h):
            for u in range(w):
                wt = edge_weight(weights, v, u, k)
                if wt == 0.0:
                    continue
                a, b = node[v, u], node[v + DV[k], u + DU[k]]
                if a != b:
                    lower[n], higher[n], values[n] = min(a, b), max(a, b), wt
                    starts[lower[n] + 1] += 1
                    n += 1
    starts = np.cumsum(starts)
    fill = starts[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[lower[i]]] = i
        fill[lower[i]] += 1
    # one edge per pair of nodes: `seen[b]` is the last lower node met with b, at `slot[b]`
    seen = np.full(count, -1, dtype=np.int64)
    slot = np.empty(count, dtype=np.int64)
    heads = np.empty(n, dtype=np.int64)
    tails = np.empty(n, dtype=np.int64)
    caps = np.empty(n)
    pairs = 0
    for a in range(count):
        for i in order[starts[a] : starts[a + 1]]:
            b = higher[i]
            if seen[b] == a:
                caps[slot[b]] += values[i]
            else:
                seen[b], slot[b] = a, pairs
                heads[pairs], tails[pairs], caps[pairs] = a, b, values[i]
                pairs += 1
    return cap1, cap0, heads[:pairs], tails[:pairs], caps[:pairs]
