"""How much faster the exact fast cut is than the full-frame reference, on the same energy.

The cut is timed from the built energy (unary costs and weights) to the labels, the part
the two solvers do differently; `segment` end to end (estimation and building the energy
included, which both paths share) is timed too. Warm-up, then the two alternate, and the
medians are compared, all in one process.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tofcut.driver.frames import Frame
from tofcut.tracker.graphcut import Solution, solve_cropped, solve_reduced, solve_reference
from tofcut.tracker.segment import (
    Energy,
    SegmentParams,
    Target,
    build_problem,
    estimate_model,
    segment,
)


@dataclass(frozen=True)
class CutTiming:
    """Median times of one energy on one frame, reference against fast."""

    energy: Energy
    reference_s: float
    fast_s: float
    segment_reference_s: float
    segment_fast_s: float
    identical: bool
    """The two labellings are equal pixel for pixel."""
    graph_nodes: int
    """Nodes of the fast cut's graph (the reference has H·W)."""
    pixels: int

    @property
    def ratio(self) -> float:
        """Reference time over fast time for the cut."""
        return self.reference_s / self.fast_s

    @property
    def segment_ratio(self) -> float:
        return self.segment_reference_s / self.segment_fast_s


def _median_pair(
    first: Callable[[], object], second: Callable[[], object], repeats: int
) -> tuple[float, float]:
    first()
    second()
    a, b = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        first()
        a.append(time.perf_counter() - t)
        t = time.perf_counter()
        second()
        b.append(time.perf_counter() - t)
    return float(np.median(a)), float(np.median(b))


def time_cut(
    frame: Frame,
    target: Target,
    energy: Energy,
    params: SegmentParams | None = None,
    repeats: int = 21,
) -> CutTiming:
    """Time the reference and the fast cut of one energy on one frame."""
    params = params or SegmentParams()
    model = estimate_model(frame.intensity, frame.xyz, frame.valid, target, energy, params)
    problem = build_problem(frame.intensity, frame.xyz, frame.valid, energy, params, model)

    def fast() -> Solution:
        if energy.seeded:
            return solve_cropped(problem, model.pixel)
        return solve_reduced(problem)

    ref_s, fast_s = _median_pair(lambda: solve_reference(problem), fast, repeats)
    seg_ref_s, seg_fast_s = _median_pair(
        lambda: segment(frame, target, energy, params, reference=True),
        lambda: segment(frame, target, energy, params),
        repeats,
    )
    reference = solve_reference(problem)
    quick = fast()
    return CutTiming(
        energy,
        ref_s,
        fast_s,
        seg_ref_s,
        seg_fast_s,
        bool(np.array_equal(reference.labels, quick.labels)),
        quick.graph_nodes,
        problem.shape[0] * problem.shape[1],
    )
