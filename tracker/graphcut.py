"""Minimising a binary energy (see `tofcut.tracker.energy`) by graph cut with PyMaxflow.

Three solvers with the same minima:

- `solve_reference`: the obvious one, a full-frame grid graph. It is the yardstick the fast
  solvers are tested and benchmarked against, and stays as such.
- `solve_reduced`, for the data-term energies: pixels whose label is forced by their unary
  cost are fixed without a graph; only the rest go into it.
- `solve_cropped`, for the §4.2 energies: the graph of a window around the seed, grown until
  a certificate shows that nothing outside it can change the minimum; inside the window,
  neighbours that no minimum separates are merged first (`tofcut.tracker.contraction`), so
  the max-flow no longer pushes 1/n of flow into each pixel of a surface one at a time.

Why `solve_reduced` is exact (persistency). Let δ_p = cost1[p] − cost0[p] and W_p the sum of
the weights of p's edges. If δ_p > W_p, relabelling p from target to background changes any
labelling's energy by at most −δ_p + W_p < 0, so no minimum has p in the target; likewise
δ_p < −W_p forces the target. Fixing such pixels and folding each edge to a fixed neighbour
into the free pixel's unary cost leaves an energy over the free pixels whose minima are
exactly the original minima restricted to them (all minima agree on the fixed pixels), so
the rule applies again to it, with W_p counting only edges to free pixels. The first pass
uses an upper bound of every W_p, which fixes fewer pixels but costs one comparison.

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

import functools
from dataclasses import dataclass

import maxflow
import numpy as np
import numpy.typing as npt

from tofcut.tracker.contraction import cut_merged, merged_nodes
from tofcut.tracker.energy import OFFSETS

F64 = npt.NDArray[np.float64]
BOOL = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]

FULL_GRAPH_SHARE = 0.5
"""`solve_reduced` cuts the full grid when more than this share of the pixels stays free."""
MIN_SETTLED_SHARE = 0.5
"""`solve_reduced` stops its rounds when one would settle less than this share of the free
pixels (a round costs about as much as cutting half of them, measured at 176×144)."""

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
    """(4, H, W) non-negative edge weights along `energy.OFFSETS` (see `tofcut.tracker.energy`)."""

    def __post_init__(self) -> None:
        shape = self.cost1.shape
        if len(shape) != 2 or self.cost0.shape != shape:
            raise ValueError(f"unary costs must be two equal (H, W) arrays, not {shape}")
        if self.weights.shape != (len(OFFSETS), *shape):
            raise ValueError(f"weights must be (4, H, W), not {self.weights.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return (self.cost1.shape[0], self.cost1.shape[1])


@dataclass(frozen=True, eq=False)
class Solution:
    """A minimising labelling and how much of the problem went into the graph."""

    labels: BOOL
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


def solve_reduced(problem: Problem, max_rounds: int = 20) -> Solution:
    """Fix every pixel whose label its unary cost forces (repeatedly), cut the rest; when
    most of the frame stays free, the full grid graph is the quicker way to cut it.

    Touches the whole frame only in a few vectorised passes (δ, the weight bound, the
    candidates, the labels); the rest works on the free pixels and their 8 neighbours.
    """
    h, w = problem.shape
    n = h * w
    delta = (problem.cost1 - problem.cost0).reshape(-1)
    bound = 2.0 * float(problem.weights.max(axis=(1, 2)).sum())  # ≥ every pixel's W_p
    free = np.flatnonzero(np.abs(delta) <= bound)
    if free.size > FULL_GRAPH_SHARE * n:
        return solve_reference(problem)
    labels = delta < 0
    if free.size == 0:
        return Solution(labels.reshape(h, w), 0)
    is_free = np.zeros(n, dtype=bool)
    is_free[free] = True
    nbr, wts = _neighbours(free, w, problem.weights.reshape(-1))
    nfree = is_free.take(nbr, mode="clip")
    for _ in range(max_rounds):
        # δ with fixed neighbours folded in, against the weight still free to pull either way
        fixed_w = np.where(nfree, 0.0, wts)
        pull = np.where(labels.take(nbr, mode="clip"), fixed_w, -fixed_w) @ _ONES
        d = delta[free] - pull
        slack = np.where(nfree, wts, 0.0) @ _ONES
        settled = np.abs(d) > slack
        count = int(np.count_nonzero(settled))
        if count < MIN_SETTLED_SHARE * free.size:
            break  # another round would cost more than the nodes it saves
        done = free[settled]
        labels[done] = d[settled] < 0
        is_free[done] = False
        keep = ~settled
        free, nbr, wts = free[keep], nbr[keep], wts[keep]
        if free.size == 0:
            return Solution(labels.reshape(h, w), 0)
        nfree = is_free.take(nbr, mode="clip")
    m = free.size
    fixed_w = np.where(nfree, 0.0, wts)
    to_target = np.where(labels.take(nbr, mode="clip"), fixed_w, 0.0) @ _ONES
    cost1 = problem.cost1.reshape(-1)[free] + (fixed_w @ _ONES - to_target)
    cost0 = problem.cost0.reshape(-1)[free] + to_target
    index = np.empty(n, dtype=np.int64)  # only read where is_free
    index[free] = np.arange(m)
    forward = len(OFFSETS)
    linked = np.flatnonzero(nfree[:, :forward] & (wts[:, :forward] > 0))
    rows = linked // forward
    graph = maxflow.Graph[float](m, linked.size)
    ids = graph.add_nodes(m)
    if linked.size:
        cap = wts[:, :forward].reshape(-1)[linked]
        graph.add_edges(rows, index[nbr[:, :forward].reshape(-1)[linked]], cap, cap)
    graph.add_grid_tedges(ids, cost1, cost0)
    graph.maxflow()
    labels[free] = graph.get_grid_segments(ids)
    return Solution(labels.reshape(h, w), m)


_ONES = np.ones(2 * len(OFFSETS))
"""Row sums over the 8 neighbours as a matrix product (quicker than sum(axis=1) on m × 8)."""


@functools.lru_cache(maxsize=4)
def _neighbour_offsets(width: int, n: int) -> tuple[I64, I64]:
    """Flat offsets of the 8 neighbours (forward OFFSETS, then backward) and, per neighbour,
    the offset from the pixel to its edge's weight in the flattened (4, H, W) weights."""
    forward = np.array([dv * width + du for dv, du in OFFSETS], dtype=np.int64)
    block = np.arange(len(OFFSETS), dtype=np.int64) * n
    return np.concatenate([forward, -forward]), np.concatenate([block, block - forward])


def _neighbours(pixels: I64, width: int, flat_weights: F64) -> tuple[I64, F64]:
    """(m, 8) flat indices of the 8 neighbours of the sorted flat `pixels` (forward OFFSETS,
    then backward) and the weights of the edges to them.

    A neighbour index may wrap round a row or fall outside the frame; its weight is then 0
    (a forward weight is stored at the pixel and is 0 for an edge leaving the frame; a
    backward one is stored at the wrapped-to pixel, whose edge in that direction leaves the
    frame too, or, before the first row, is set to 0 here), so callers need no mask as long
    as they look neighbours up with mode="clip".
    """
    n = flat_weights.size // len(OFFSETS)
    offsets, at = _neighbour_offsets(width, n)
    nbr = pixels[:, None] + offsets[None, :]
    wts = flat_weights.take(pixels[:, None] + at[None, :], mode="clip")
    if pixels.size and pixels[0] <= width:  # sorted: only the first pixels can look above row 0
        wts[nbr < 0] = 0.0
    return nbr, wts


def solve_cropped(problem: Problem, centre: tuple[int, int], half_size: int = 24) -> Solution:
    """Cut a window around `centre` (u, v), grown until certified (module docstring).

    A window is grown before its cut when the pixels merged with `centre` already reach a
    side that borders the rest of the frame: a target holding them would touch that side,
    and an empty one is found by the larger window as well."""
    h, w = problem.shape
    rows, cols = np.divmod(np.flatnonzero(problem.cost0 > problem.cost1), w)
    u, v = centre
    v0 = max(min(v, int(rows.min(initial=v))) - half_size, 0)
    v1 = min(max(v, int(rows.max(initial=v))) + half_size + 1, h)
    u0 = max(min(u, int(cols.min(initial=u))) - half_size, 0)
    u1 = min(max(u, int(cols.max(initial=u))) + half_size + 1, w)
    nodes = 0
    while True:
        window = (slice(v0, v1), slice(u0, u1))
        cost1, cost0 = problem.cost1[window], problem.cost0[window]
        weights = problem.weights[(slice(None), *window)]
        count, node = merged_nodes(cost1, cost0, weights)
        inner = node == node[v - v0, u - u0]
        if not _touched_sides(inner, (v0, v1, u0, u1), (h, w)):
            inner = cut_merged(cost1, cost0, weights, count, node)
            nodes += count
        grow = _touched_sides(inner, (v0, v1, u0, u1), (h, w))
        if not grow:
            labels = np.zeros((h, w), dtype=bool)
            labels[window] = inner
            return Solution(labels, nodes)
        grow_up, grow_down, grow_left, grow_right = (side in grow for side in "udlr")
        dv, du = v1 - v0, u1 - u0
        v0 = max(v0 - dv, 0) if grow_up else v0
        v1 = min(v1 + dv, h) if grow_down else v1
        u0 = max(u0 - du, 0) if grow_left else u0
        u1 = min(u1 + du, w) if grow_right else u1


def _touched_sides(inner: BOOL, bounds: tuple[int, int, int, int], shape: tuple[int, int]) -> str:
    """The sides of the window (u)p, (d)own, (l)eft, (r)ight that `inner` reaches and that
    border the rest of the frame."""
    v0, v1, u0, u1 = bounds
    h, w = shape
    return "".join(
        side
        for side, reached in (
            ("u", v0 > 0 and bool(inner[0].any())),
            ("d", v1 < h and bool(inner[-1].any())),
            ("l", u0 > 0 and bool(inner[:, 0].any())),
            ("r", u1 < w and bool(inner[:, -1].any())),
        )
        if reached
    )
