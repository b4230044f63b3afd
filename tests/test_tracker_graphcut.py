"""The graph-cut solvers: fast == full-frame reference, and PyMaxflow == an independent
max-flow (scipy) == brute force on tiny grids."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import maximum_flow

from tofcut.tracker.energy import OFFSETS, energy_of, pair_slices, seed_costs
from tofcut.tracker.graphcut import Problem, solve_cropped, solve_reduced, solve_reference


def in_frame(weights: np.ndarray) -> np.ndarray:
    """Zero the weights of edges that would leave the frame (the Problem convention)."""
    out = np.zeros_like(weights)
    for k in range(len(OFFSETS)):
        sp, _ = pair_slices(weights.shape[1:], k)
        out[k][sp] = weights[k][sp]
    return out


def random_problem(rng: np.random.Generator, h: int, w: int) -> Problem:
    """Continuous random costs and weights of a random balance (ties have probability 0)."""
    scale = rng.uniform(0.05, 3.0)
    return Problem(
        rng.random((h, w)) * rng.uniform(0.5, 2.0),
        rng.random((h, w)) * rng.uniform(0.5, 2.0),
        in_frame(rng.random((4, h, w)) * scale * (rng.random((4, h, w)) < rng.uniform(0.3, 1))),
    )


def seeded_problem(rng: np.random.Generator, h: int, w: int) -> tuple[Problem, tuple[int, int]]:
    """A §4.2-shaped problem: 1/n to the background, a seed, blobs of strong weights."""
    seed = (int(rng.integers(w)), int(rng.integers(h)))
    cost1, cost0 = seed_costs((h, w), seed)
    strong = rng.random((h, w)) < rng.uniform(0.2, 0.9)
    weights = rng.random((4, h, w)) * np.where(strong, 1.0, 1e-3)[None]
    return Problem(cost1, cost0, in_frame(weights)), seed


def value(problem: Problem, labels: np.ndarray) -> float:
    return energy_of(labels, problem.cost1, problem.cost0, problem.weights)


@pytest.mark.parametrize("seed", range(60))
def test_reduced_solver_equals_the_reference_on_random_problems(seed):
    rng = np.random.default_rng(seed)
    h, w = (int(x) for x in rng.integers(1, 40, 2))
    problem = random_problem(rng, h, w)
    ref = solve_reference(problem)
    fast = solve_reduced(problem)
    assert fast.graph_nodes <= h * w
    assert value(problem, fast.labels) == pytest.approx(value(problem, ref.labels), rel=1e-12)
    assert np.array_equal(fast.labels, ref.labels)


@pytest.mark.parametrize("seed", range(40))
def test_cropped_solver_equals_the_reference_on_random_seeded_problems(seed):
    rng = np.random.default_rng(1000 + seed)
    h, w = (int(x) for x in rng.integers(1, 50, 2))
    problem, pixel = seeded_problem(rng, h, w)
    ref = solve_reference(problem)
    fast = solve_cropped(problem, pixel, half_size=int(rng.integers(0, 6)))
    assert value(problem, fast.labels) == pytest.approx(value(problem, ref.labels), rel=1e-12)
    assert np.array_equal(fast.labels, ref.labels)


def test_ties_give_equal_energy():
    # integer costs and invalid (zero-cost) pixels make many minima; energies must agree
    rng = np.random.default_rng(5)
    for _ in range(30):
        h, w = 12, 17
        cost1 = rng.integers(0, 4, (h, w)).astype(float)
        cost0 = rng.integers(0, 4, (h, w)).astype(float)
        dead = rng.random((h, w)) < 0.3
        cost1[dead] = cost0[dead] = 0.0
        problem = Problem(cost1, cost0, in_frame(rng.integers(0, 3, (4, h, w)).astype(float)))
        assert value(problem, solve_reduced(problem).labels) == value(
            problem, solve_reference(problem).labels
        )


@settings(max_examples=60, deadline=None)
@given(
    h=st.integers(1, 9),
    w=st.integers(1, 9),
    seed=st.integers(0, 2**32 - 1),
    smooth=st.floats(0.0, 5.0),
)
def test_reduced_solver_never_loses_energy(h, w, seed, smooth):
    rng = np.random.default_rng(seed)
    problem = Problem(
        rng.normal(size=(h, w)), rng.normal(size=(h, w)), in_frame(rng.random((4, h, w)) * smooth)
    )
    fast = value(problem, solve_reduced(problem).labels)
    assert fast == pytest.approx(value(problem, solve_reference(problem).labels), abs=1e-9)


def brute_force_minimum(problem: Problem) -> float:
    h, w = problem.shape
    best = np.inf
    for bits in itertools.product((False, True), repeat=h * w):
        best = min(best, value(problem, np.array(bits).reshape(h, w)))
    return best


def scipy_max_flow(problem: Problem) -> int:
    """Max flow of the s-t network of an integer problem, by scipy (not PyMaxflow)."""
    h, w = problem.shape
    n = h * w
    s, t = n, n + 1
    rows, cols, caps = [], [], []
    idx = np.arange(n).reshape(h, w)
    for p in range(n):
        rows += [s, p]
        cols += [p, t]
        caps += [int(problem.cost1.flat[p]), int(problem.cost0.flat[p])]
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices((h, w), k)
        for a, b, c in zip(
            idx[sp].ravel(), idx[sq].ravel(), problem.weights[k][sp].ravel(), strict=True
        ):
            rows += [a, b]
            cols += [b, a]
            caps += [int(c), int(c)]
    graph = csr_matrix((np.array(caps, np.int32), (rows, cols)), shape=(n + 2, n + 2))
    return int(maximum_flow(graph, s, t).flow_value)


@pytest.mark.parametrize("seed", range(25))
def test_pymaxflow_matches_scipy_max_flow_and_brute_force(seed):
    rng = np.random.default_rng(77 + seed)
    h, w = int(rng.integers(1, 4)), int(rng.integers(1, 5))
    problem = Problem(
        rng.integers(0, 60, (h, w)).astype(float),
        rng.integers(0, 60, (h, w)).astype(float),
        in_frame(rng.integers(0, 25, (4, h, w)).astype(float)),
    )
    best = brute_force_minimum(problem)
    assert value(problem, solve_reference(problem).labels) == best
    assert value(problem, solve_reduced(problem).labels) == best
    assert scipy_max_flow(problem) == best


@pytest.mark.parametrize("seed", range(10))
def test_seeded_cut_matches_scipy_max_flow_on_small_grids(seed):
    rng = np.random.default_rng(300 + seed)
    h, w = 6, 7
    problem, pixel = seeded_problem(rng, h, w)
    scale = 1000 * h * w  # 1/n becomes 1000: integer capacities, rounding kept small
    scaled = Problem(
        np.round(problem.cost1 * scale),
        np.round(problem.cost0 * scale),
        np.round(problem.weights * scale),
    )
    flow = scipy_max_flow(scaled)
    assert value(scaled, solve_reference(scaled).labels) == flow
    assert value(scaled, solve_cropped(scaled, pixel, half_size=1).labels) == flow
