"""Exact graph contraction: merge neighbouring pixels that no minimum of the energy separates.

For any labelling S, E(S) = unary(S) + cut(S) ≥ L + cut(S) with L = Σ_p min(cost1, cost0),
and the all-background and all-target labellings bound the minimum from above:
E* ≤ U = min(Σ cost0, Σ cost1). So every minimum cuts edges of total weight at most
U − L (the "slack"). If every cut separating neighbours p and q weighs more than the slack,
no minimum separates them, and merging them into one node (terminal capacities and edges
summed) leaves exactly the same set of minima.

The weight of every p–q cut is bounded from below by edge-disjoint paths (Menger): the
direct edge plus, through each common 8-neighbour c, min(w(p, c), w(c, q)). Computed for
every east and south pair of the grid in a few dozen array operations; merged pixels are
the connected components of the pairs whose bound exceeds the slack (diagonal pairs are not
merged directly: fewer merges, never a wrong one).

For the §4.2 energy (1/n to the background, the seed's link 1) the slack is 1 − 1/n, and
the edges inside a smooth surface (weights near exp(−1/2) with σs at the neighbour step) have
bounds of 2 or more: a whole surface becomes one node, and the max-flow no longer has to
push 1/n of flow to each of its pixels one by one.
"""

from __future__ import annotations

import functools

import maxflow
import numpy as np
import numpy.typing as npt
from scipy import ndimage

from tofcut.tracker.energy import OFFSETS, pair_slices

F64 = npt.NDArray[np.float64]
BOOL = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]

DIRECTIONS: tuple[tuple[int, int], ...] = OFFSETS + tuple((-dv, -du) for dv, du in OFFSETS)
"""All 8 neighbour directions: OFFSETS (forward), then their opposites (backward)."""

MARGIN = 1e-9
"""Relative margin on the slack, so that rounding in the sums never merges a pair a minimum
could separate."""


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


def all_directions(weights: F64) -> F64:
    """(8, H+2, W+2): the weight of the edge from each pixel (padded by one) in each of
    DIRECTIONS; zero in the padding, so an edge that leaves the grid (whatever `weights`
    holds for it, e.g. in a window cut out of a frame) is on no path between two pixels."""
    _, h, w = weights.shape
    out = np.zeros((len(DIRECTIONS), h + 2, w + 2))
    out[: len(OFFSETS), 1:-1, 1:-1] = weights
    for k, (dv, du) in enumerate(OFFSETS):
        # the edge q → q − off at q = p + off is the edge p → p + off, stored at p
        out[len(OFFSETS) + k, 1 + dv : 1 + dv + h, 1 + du : 1 + du + w] = weights[k]
    out[:, (0, -1), :] = 0.0
    out[:, :, (0, -1)] = 0.0
    return out


AXIAL = (0, 1)
"""The OFFSETS along which pixels are merged (east, south): enough to join a surface, and
their merges are connected components of a 4-connected image (see `merged_nodes`)."""


def cut_lower_bounds(weights: F64) -> F64:
    """(2, H, W): for each east and south edge of `weights`, a lower bound of the weight of
    every cut that separates its two pixels (the direct edge plus the two-edge paths through
    the four common neighbours, which are edge-disjoint)."""
    _, h, w = weights.shape
    w8 = all_directions(weights)
    bounds = np.empty((len(AXIAL), h, w))
    for slot, k in enumerate(AXIAL):
        commons = _common_neighbours(k)
        to_c = w8[[i for i, _ in commons], 1:-1, 1:-1]
        c_to_q = np.stack(
            [
                w8[j, 1 + DIRECTIONS[i][0] : 1 + DIRECTIONS[i][0] + h, 1 + DIRECTIONS[i][1] :][
                    :, :w
                ]
                for i, j in commons
            ]
        )
        np.minimum(to_c, c_to_q, out=to_c)
        np.add(to_c.sum(axis=0), weights[k], out=bounds[slot])
    return bounds


def slack(cost1: F64, cost0: F64) -> float:
    """U − L: the most any minimum's cut can weigh (module docstring)."""
    upper = min(float(cost0.sum()), float(cost1.sum()))
    return upper - float(np.minimum(cost1, cost0).sum())


def merged_nodes(cost1: F64, cost0: F64, weights: F64) -> tuple[int, I64]:
    """(number of nodes, (H, W) node of each pixel) after merging every pair of east or south
    neighbours that no minimum separates.

    The merges are the 4-connected components of a (2H−1, 2W−1) image with the pixels at
    even places and, between two of them, the pair's "merge" flag.
    """
    h, w = cost1.shape
    limit = slack(cost1, cost0)
    limit += MARGIN * (abs(limit) + 1.0)
    joined = cut_lower_bounds(weights) > limit
    image = np.zeros((2 * h - 1, 2 * w - 1), dtype=bool)
    image[::2, ::2] = True
    image[::2, 1::2] = joined[0][:, : w - 1]
    image[1::2, ::2] = joined[1][: h - 1, :]
    labelled, count = ndimage.label(image)
    return int(count), labelled[::2, ::2].astype(np.int64) - 1


@functools.lru_cache(maxsize=16)
def _edge_index(h: int, w: int) -> tuple[I64, I64, I64]:
    """Flat (p, q, weight index) of every in-frame 8-neighbour edge of an H×W grid, the
    weight index into the flattened (4, H, W) weights."""
    index = np.arange(h * w).reshape(h, w)
    heads, tails, at = [], [], []
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices((h, w), k)
        heads.append(index[sp].reshape(-1))
        tails.append(index[sq].reshape(-1))
        at.append(index[sp].reshape(-1) + k * h * w)
    return np.concatenate(heads), np.concatenate(tails), np.concatenate(at)


def solve_merged(cost1: F64, cost0: F64, weights: F64) -> tuple[BOOL, int]:
    """A minimum of the energy by graph cut on the merged nodes: (labels (H, W), nodes).
    Edges that leave the grid are ignored, whatever `weights` holds for them."""
    count, node = merged_nodes(cost1, cost0, weights)
    return cut_merged(cost1, cost0, weights, count, node), count


def cut_merged(cost1: F64, cost0: F64, weights: F64, count: int, node: I64) -> BOOL:
    """The (H, W) labels of a minimum by graph cut on the nodes of `merged_nodes`."""
    h, w = cost1.shape
    flat = node.reshape(-1)
    cap1 = np.bincount(flat, cost1.reshape(-1), minlength=count)
    cap0 = np.bincount(flat, cost0.reshape(-1), minlength=count)
    heads, tails, at = _edge_index(h, w)
    a, b = flat[heads], flat[tails]
    between = np.flatnonzero(a != b)  # (a zero weight makes a harmless zero-capacity edge)
    a, b = a[between], b[between]
    # parallel edges between two merged nodes become one: far fewer augmenting paths
    pairs, where = np.unique(np.minimum(a, b) * count + np.maximum(a, b), return_inverse=True)
    graph = maxflow.Graph[float](count, pairs.size)
    ids = graph.add_nodes(count)
    if pairs.size:
        cap = np.bincount(where, weights.reshape(-1)[at[between]], minlength=pairs.size)
        graph.add_edges(pairs // count, pairs % count, cap, cap)
    graph.add_grid_tedges(ids, cap1, cap0)
    graph.maxflow()
    target = np.asarray(graph.get_grid_segments(ids), dtype=bool)
    labels: BOOL = target[node]
    return labels
