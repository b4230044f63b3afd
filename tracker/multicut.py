"""Several labels competing for pixels: a Potts energy minimised by α-expansion graph cuts.

    E(l) = Σ_p U[l_p, p] + Σ_(p,q) w_pq · [l_p ≠ l_q]

Label 0 is the background, labels 1..K the tracks. With two labels one expansion is an
exact min cut; with more, α-expansion reaches a local minimum within a factor 2 of the
global one (Boykov, Veksler and Zabih 2001) in which no pixel is claimed by two tracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import maxflow
import numpy as np

from tofcut._types import F64, I64
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.multicut_kernels import cheapest_where, expansion_terms, moving_graph, settled


@dataclass(frozen=True, eq=False)
class PottsProblem:
    """Unary costs (labels × nodes) and undirected edges (i, j, weight) between nodes."""

    unary: F64
    i: I64
    j: I64
    w: F64

    def __post_init__(self) -> None:
        if self.unary.ndim != 2 or self.unary.shape[0] < 1:
            raise SegmentError("unary must be (labels, nodes)")
        if not (self.i.shape == self.j.shape == self.w.shape):
            raise SegmentError("edge arrays i, j, w must have the same shape")
        if self.w.size and float(self.w.min()) < 0:
            raise SegmentError("Potts weights must be non-negative")

    @property
    def labels(self) -> int:
        return int(self.unary.shape[0])

    @property
    def nodes(self) -> int:
        return int(self.unary.shape[1])

    def energy(self, labels: I64) -> float:
        """E(labels)."""
        data = float(self.unary[labels, np.arange(self.nodes)].sum())
        return data + float(self.w[labels[self.i] != labels[self.j]].sum())


def _expand(problem: PottsProblem, labels: I64, alpha: int, core: _Core) -> I64:
    """The best α-expansion move from `labels`: each node keeps its label or takes α; only
    the nodes of `core` may move."""
    source, sink, i, j, pair = expansion_terms(
        problem.unary, labels, alpha, core.i, core.j, core.w, core.local, core.nodes
    )
    if source.size == 0:
        return labels.copy()
    g = maxflow.Graph[float](source.size, i.size)
    nodes = g.add_nodes(source.size)
    # a node in the sink segment (segment 1) takes α and pays its source capacity
    g.add_grid_tedges(nodes, source, sink)
    if pair.size:
        g.add_edges(nodes[i], nodes[j], pair, np.zeros_like(pair))
    g.maxflow()
    take_alpha = g.get_grid_segments(nodes).astype(bool)
    out = labels.copy()
    out[core.nodes[take_alpha]] = alpha
    return out


@dataclass(frozen=True, eq=False)
class _Core:
    """The nodes an expansion may move, their number in its graph (`local`, −1 for the
    others) and the edges that reach them, in order."""

    nodes: I64
    local: I64
    i: I64
    j: I64
    w: F64

    @classmethod
    def of(cls, problem: PottsProblem, start: I64 | None) -> _Core:
        """From each node's cheapest label, a node settled on it (`multicut_kernels.settled`) never
        moves, and the graph of every move is the smaller for leaving it out; from a given
        `start`, every node may move."""
        move = ~settled(problem.unary, problem.i, problem.j, problem.w)
        if start is not None:
            move[:] = True
        return cls(*moving_graph(move, problem.i, problem.j, problem.w))


def solve_binary(problem: PottsProblem) -> I64:
    """The exact minimum of a two-label problem: one min cut."""
    if problem.labels != 2:
        raise SegmentError(f"solve_binary takes two labels, got {problem.labels}")
    core = _Core.of(problem, None)
    # one move from all background: what is settled is on its label from the start
    start = cheapest_where(problem.unary, core.local < 0)
    return _expand(problem, start, 1, core)


def solve_potts(problem: PottsProblem, start: I64 | None = None, max_sweeps: int = 4) -> I64:
    """Labels of a (local) minimum of the Potts energy by α-expansion, from `start` (default:
    each node's cheapest label). Exact when there are two labels."""
    labels = np.argmin(problem.unary, axis=0).astype(np.int64) if start is None else start.copy()
    if problem.nodes == 0:
        return labels
    core = _Core.of(problem, start)
    best = problem.energy(labels)
    for _ in range(max_sweeps):
        improved = False
        for alpha in range(problem.labels):
            moved = _expand(problem, labels, alpha, core)
            if np.array_equal(moved, labels):
                continue  # the same labels: the same energy, no better
            e = problem.energy(moved)
            if e < best - 1e-9 * max(1.0, abs(best)):
                labels, best, improved = moved, e, True
        if not improved:
            break
    return labels
