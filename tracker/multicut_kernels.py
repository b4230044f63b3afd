"""The α-expansion moves' graphs, compiled (see `tofcut.tracker.compiled`): the nodes
settled on their cheapest label, the nodes that may move and their edges, and each move's
capacities (`tofcut.tracker.multicut`).
"""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, I64, B
from tofcut.tracker.compiled import B_1D, F64_1D, F64_2D, F64_2D_F, I64_1D, kernel


@kernel((F64_2D, I64_1D, I64_1D, F64_1D), (F64_2D_F, I64_1D, I64_1D, F64_1D))
def settled(unary: F64, i: I64, j: I64, w: F64) -> B:
    """Nodes whose cheapest label is cheaper than any other by more than all their edges
    weigh: from there no labelling of their neighbours makes another label pay, so no
    expansion move ever takes them off it."""
    n = unary.shape[1]
    weigh = np.zeros(n)
    for e in range(i.size):
        weigh[i[e]] += w[e]
        weigh[j[e]] += w[e]
    out = np.zeros(n, np.bool_)
    for p in range(n):
        best, second = np.inf, np.inf
        for label in range(unary.shape[0]):
            u = unary[label, p]
            if u < best:
                best, second = u, best
            elif u < second:
                second = u
        if np.isfinite(best):
            out[p] = second > best + weigh[p] + 1e-9 * (1.0 + abs(best) + weigh[p])
    return out


@kernel((B_1D, I64_1D, I64_1D, F64_1D))
def moving_graph(move: B, i: I64, j: I64, w: F64) -> tuple[I64, I64, I64, I64, F64]:
    """The nodes that `move` (in order), each node's number among them (−1 for the others)
    and the edges (i, j, w) with an end among them, in order."""
    local = np.full(move.size, -1, np.int64)
    m = 0
    for p in range(move.size):
        if move[p]:
            local[p] = m
            m += 1
    nodes = np.empty(m, np.int64)
    for p in range(move.size):
        if move[p]:
            nodes[local[p]] = p
    ri = np.empty(i.size, np.int64)
    rj = np.empty(i.size, np.int64)
    rw = np.empty(i.size)
    k = 0
    for e in range(i.size):
        if move[i[e]] or move[j[e]]:
            ri[k], rj[k], rw[k] = i[e], j[e], w[e]
            k += 1
    return nodes, local, ri[:k], rj[:k], rw[:k]


@kernel((F64_2D, B_1D), (F64_2D_F, B_1D))
def cheapest_where(unary: F64, where: B) -> I64:
    """`np.argmin(unary[:, where], axis=0)` (the first nan, if any) at the nodes `where`,
    0 elsewhere."""
    out = np.zeros(unary.shape[1], np.int64)
    for p in range(unary.shape[1]):
        if not where[p]:
            continue
        best, at = unary[0, p], 0
        if not np.isnan(best):
            for label in range(1, unary.shape[0]):
                x = unary[label, p]
                if np.isnan(x):
                    at = label
                    break
                if x < best:
                    best, at = x, label
        out[p] = at
    return out


@kernel(
    (F64_2D, I64_1D, 1, I64_1D, I64_1D, F64_1D, I64_1D, I64_1D),
    (F64_2D_F, I64_1D, 1, I64_1D, I64_1D, F64_1D, I64_1D, I64_1D),
)
def expansion_terms(
    unary: F64, labels: I64, alpha: int, i: I64, j: I64, w: F64, local: I64, nodes: I64
) -> tuple[F64, F64, I64, I64, F64]:
    """The α-expansion move's graph from `labels` (see `multicut._expand`) over the nodes
    that may move (`nodes`; `local` ≥ 0: their number in the graph; the others keep their
    label): each one's capacity from the source and to the sink, and the edges between
    them (i, j, capacity from i to j). An edge to a node that keeps its label is a unary
    term; edges between two such nodes may be left out of i, j, w.

    With x_p = 1 for "take α", an edge's E(x_p, x_q) has A = E00, B = E01, C = E10 and
    D = E11 = 0, so E = A + (C−A)·x_p + (D−C)·x_q + (B+C−A−D)·(1−x_p)·x_q."""
    n = nodes.size
    unary1 = np.empty(n)
    for p in nodes:
        unary1[local[p]] = unary[alpha, p] - unary[labels[p], p]
    ri = np.empty(i.size, np.int64)
    rj = np.empty(i.size, np.int64)
    pair = np.empty(i.size)
    m = 0
    for e in range(i.size):
        li, lj = labels[i[e]], labels[j[e]]
        a = w[e] * (1.0 if li != lj else 0.0)
        b = w[e] * (1.0 if li != alpha else 0.0)
        c = w[e] * (1.0 if alpha != lj else 0.0)
        p, q = local[i[e]], local[j[e]]
        if p >= 0 and q >= 0:
            unary1[p] += c - a
            ri[m], rj[m] = p, q
            pair[m] = b + c - a
            m += 1
        elif p >= 0:
            unary1[p] += c - a  # x_q = 0
        elif q >= 0:
            unary1[q] += b - a  # x_p = 0
    for e in range(i.size):
        p, q = local[i[e]], local[j[e]]
        if p >= 0 and q >= 0:
            c = w[e] * (1.0 if alpha != labels[j[e]] else 0.0)
            unary1[q] += -c
    source = np.empty(n)
    sink = np.empty(n)
    for p in range(n):
        x = unary1[p]
        source[p] = x if (x >= 0.0 or x != x) else 0.0
        y = -x
        sink[p] = y if (y >= 0.0 or y != y) else 0.0
    return source, sink, ri[:m], rj[:m], pair[:m]
