"""Several targets in one frame with disjoint masks: `segment_many(frame, targets, params)`.

    from tofcut.tracker.paper.segment_many import segment_many
    many = segment_many(frame, [Target(point=a), Target(point=b)], energy=Energy.RANGE_DATA)
    many.labels  # (H, W): 0 background, k + 1 where targets[k] won the pixel

Each target is one more label of a Potts energy minimised by α-expansion
(`tofcut.tracker.multicut`, the tracker's joint cut):

- data-term energies: label k + 1 costs target k's own eq. (5)/(6) target cost (its µt, its
  µd or image centre), the background eq. (5)'s background cost, with µb taken from the
  pixels far from every target; the Potts weights are those of `segment`;
- §4.2 energies: every target label costs 1/n a pixel, and a target's seed pays 1 under any
  label but its own; the edges are eq. (7) or (8).

With one target this is exactly `segment`'s energy and its minimum; with more, α-expansion
gives a local minimum within a factor 2 of the global one, in which no pixel has two targets.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from tofcut._types import F64, I64, B
from tofcut.driver.frames import Frame
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.multicut import PottsProblem, solve_potts
from tofcut.tracker.neighbours import OFFSETS, pair_slices
from tofcut.tracker.paper import energy as en
from tofcut.tracker.paper.segment import (
    Energy,
    Model,
    SegmentParams,
    Target,
    build_problem,
    estimate_model,
)


@dataclass(frozen=True, eq=False)
class ManySegmentation:
    """The labels found for several targets, their energy, and how long it took."""

    labels: I64
    """(H, W): 0 background, k + 1 on targets[k]."""
    energy: float
    """The Potts energy of `labels`."""
    seconds: float
    kind: Energy
    models: tuple[Model, ...]
    """Each target's estimated model (µb is the shared one)."""

    def mask(self, k: int) -> B:
        """(H, W) mask of targets[k]."""
        mask: B = self.labels == k + 1
        return mask


def segment_many(
    frame: Frame,
    targets: Sequence[Target],
    params: SegmentParams | None = None,
    *,
    energy: Energy = Energy.RANGE_DATA,
) -> ManySegmentation:
    """Segment every target at once, each pixel going to at most one (module docstring)."""
    start = time.perf_counter()
    params = params or SegmentParams()
    if not isinstance(energy, Energy):
        raise SegmentError(f"energy must be an Energy, not {energy!r}")
    if not targets:
        raise SegmentError("segment_many needs at least one target")
    intensity, xyz, valid = frame.intensity, frame.xyz, frame.valid
    if not valid.any():
        raise SegmentError("the frame has no valid pixel")
    models = [estimate_model(intensity, xyz, valid, t, energy, params) for t in targets]
    if not energy.seeded and params.mu_background is None:
        grey = en.grey_levels(intensity, valid, models[0].intensity_ref)
        points = np.array([m.mu_d for m in models])
        mu_b = en.background_intensity(grey, valid, xyz, points, params.background_margin_m)
        models = [replace(m, mu_background=mu_b) for m in models]
    problems = [build_problem(intensity, xyz, valid, energy, params, m) for m in models]
    n = valid.size
    unary = np.empty((len(targets) + 1, n))
    if energy.seeded:
        seeds = [m.pixel[1] * valid.shape[1] + m.pixel[0] for m in models]
        if len(set(seeds)) < len(seeds):
            raise SegmentError("two targets share a seed pixel")
        unary[0] = 0.0
        unary[0, seeds] = 1.0
        unary[1:] = 1.0 / n
        for k, seed in enumerate(seeds):
            unary[1:, seed] = 1.0
            unary[k + 1, seed] = 1.0 / n
    else:
        unary[0] = problems[0].cost0.reshape(-1)
        for k, problem in enumerate(problems):
            unary[k + 1] = problem.cost1.reshape(-1)
    i, j, w = _edges(problems[0].weights)
    potts = PottsProblem(unary, i, j, w)
    labels = solve_potts(potts)
    return ManySegmentation(
        labels.reshape(valid.shape),
        potts.energy(labels),
        time.perf_counter() - start,
        energy,
        tuple(models),
    )


def _edges(weights: F64) -> tuple[I64, I64, F64]:
    """The (4, H, W) weights as flat edge lists (i, j, weight), zero-weight edges left out."""
    _, h, w = weights.shape
    index = np.arange(h * w).reshape(h, w)
    heads, tails, caps = [], [], []
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices((h, w), k)
        keep = weights[k][sp] > 0
        heads.append(index[sp][keep])
        tails.append(index[sq][keep])
        caps.append(weights[k][sp][keep])
    return np.concatenate(heads), np.concatenate(tails), np.concatenate(caps)
