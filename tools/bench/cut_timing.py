"""How much faster the exact fast cut is than the full-frame reference, on the same energy.

The cut is timed from the built energy (unary costs and weights) to the labels, the part
the two solvers do differently: both get the same `Problem`, and the fast one's time
includes all its own work on it (the full-frame pass that fixes pixels by their unary
cost, the window and its contraction); nothing is computed for it in advance but what the
energy states in closed form (the Potts energies' bound of a pixel's total weight,
4λ + 4λ/√2, which spares that pass reading the weights). `segment` end
to end (estimation and building the energy included, which both paths share) is timed too.
Two ways, the same for both solvers, all in one process. Times are CPU time of this
process (`time.process_time`, every thread counted), the fastest of the repeats: on a
shared machine wall time counts whatever else runs, and it slows the long reference calls
more often than the short fast ones.

- steady: each solver called back to back (after one warm-up call), as `timeit` does;
- cold: a 32 MiB buffer is read before every call, so each starts with its inputs out of
  the CPU caches, as after other work in a pipeline. (Alternating the two solvers instead
  would give the fast one the caches the reference just emptied, and the reference those
  the fast one barely touched: unfair to the fast one.)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tofcut._types import F64
from tofcut.driver.frames import Frame
from tofcut.tracker.paper.graphcut import Solution, solve_cropped, solve_reduced, solve_reference
from tofcut.tracker.paper.segment import (
    Energy,
    SegmentParams,
    Target,
    build_problem,
    estimate_model,
    segment,
)


@dataclass(frozen=True)
class CutTiming:
    """Times (fastest of the repeats) of one energy on one frame, reference against fast."""

    energy: Energy
    reference_s: float
    """Steady: the reference cut called back to back."""
    fast_s: float
    """Steady: the fast cut called back to back."""
    segment_reference_s: float
    segment_fast_s: float
    identical: bool
    """The two labellings are equal pixel for pixel."""
    graph_nodes: int
    """Nodes of the fast cut's graph(s) (the reference has H·W)."""
    pixels: int
    reference_cold_s: float = math.nan
    """Cold: the reference cut with the caches emptied before each call."""
    fast_cold_s: float = math.nan
    """Cold: the fast cut with the caches emptied before each call."""

    @property
    def ratio(self) -> float:
        """Reference time over fast time for the cut, steady."""
        return self.reference_s / self.fast_s

    @property
    def cold_ratio(self) -> float:
        """Reference time over fast time for the cut, cold."""
        return self.reference_cold_s / self.fast_cold_s

    @property
    def segment_ratio(self) -> float:
        return self.segment_reference_s / self.segment_fast_s


FLUSH_BYTES = 32 << 20
"""What the cold timings read before each call: well over any L2/L3 cache of this machine."""


def _best_time(call: Callable[[], object], repeats: int, flush: F64 | None = None) -> float:
    """Fastest CPU time of `call` over `repeats` calls after one warm-up call; with `flush`,
    that buffer is read before each call (not timed)."""
    call()
    times = []
    for _ in range(repeats):
        if flush is not None:
            flush.sum()
        t = time.process_time()
        call()
        times.append(time.process_time() - t)
    return min(times)


def time_cut(
    frame: Frame,
    target: Target,
    energy: Energy,
    params: SegmentParams | None = None,
    repeats: int = 21,
) -> CutTiming:
    """Time the reference and the fast cut of one energy on one frame, steady and cold."""
    params = params or SegmentParams()
    model = estimate_model(frame.intensity, frame.xyz, frame.valid, target, energy, params)
    problem = build_problem(frame.intensity, frame.xyz, frame.valid, energy, params, model)

    def fast() -> Solution:
        if energy.seeded:
            return solve_cropped(problem, model.pixel)
        return solve_reduced(problem)

    def reference() -> Solution:
        return solve_reference(problem)

    flush = np.ones(FLUSH_BYTES // 8)
    ref_s = _best_time(reference, repeats)
    fast_s = _best_time(fast, repeats)
    ref_cold_s = _best_time(reference, repeats, flush)
    fast_cold_s = _best_time(fast, repeats, flush)
    seg_ref_s = _best_time(lambda: segment(frame, target, energy, params, reference=True), repeats)
    seg_fast_s = _best_time(lambda: segment(frame, target, energy, params), repeats)
    quick = fast()
    return CutTiming(
        energy,
        ref_s,
        fast_s,
        seg_ref_s,
        seg_fast_s,
        bool(np.array_equal(reference().labels, quick.labels)),
        quick.graph_nodes,
        problem.shape[0] * problem.shape[1],
        ref_cold_s,
        fast_cold_s,
    )
