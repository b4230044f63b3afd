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

from tofcut.tracker.neighbours import OFFSETS, pair_slices
from tofcut.tracker.paper.contraction import cut_lower_bounds, merged_nodes, solve_merged
from tofcut.tracker.paper.energy import energy_of, potts_bound, potts_weights, seed_costs
from tofcut.tracker.paper.graphcut import Problem, solve_cropped, solve_reduced, solve_reference


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
    assert_same_minimum(problem, fast.labels, ref.labels)


def total_weights(weights: np.ndarray) -> np.ndarray:
    """W_p: the sum of the weights of each pixel's in-frame edges."""
    total = np.zeros(weights.shape[1:])
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(weights.shape[1:], k)
        total[sp] += weights[k][sp]
        total[sq] += weights[k][sp]
    return total


@pytest.mark.parametrize("seed", range(30))
def test_a_weight_bound_changes_nothing_but_what_is_read(seed):
    rng = np.random.default_rng(7000 + seed)
    h, w = (int(x) for x in rng.integers(1, 40, 2))
    problem = random_problem(rng, h, w)
    bound = float(total_weights(problem.weights).max()) * rng.choice([1.0, 1.5, 10.0])
    bounded = Problem(problem.cost1, problem.cost0, problem.weights, bound)
    fast, exact = solve_reduced(bounded), solve_reduced(problem)
    assert np.array_equal(fast.labels, exact.labels)
    # the same fixed point, unless a loose bound left so many pixels free at first that the
    # full grid was cut instead
    assert fast.graph_nodes in (exact.graph_nodes, h * w)
    assert np.array_equal(fast.labels, solve_reference(problem).labels)


def test_the_potts_bound_bounds_every_pixels_weight_and_bad_bounds_are_refused():
    for smoothness in (0.0, 1.0, 200.0, 1e-7, 3e5):
        weights = potts_weights((7, 9), smoothness)
        assert total_weights(weights).max() <= potts_bound(smoothness)
    with pytest.raises(ValueError, match="weight_bound"):
        Problem(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((4, 2, 2)), -1.0)


@pytest.mark.parametrize("seed", range(10))
def test_fast_solvers_take_windows_of_larger_arrays(seed):
    # strided views (as `solve_cropped` and callers cutting a region pass them), with the
    # weights of the edges leaving the window left in: both solvers must ignore those
    rng = np.random.default_rng(6000 + seed)
    big = random_problem(rng, 30, 40)
    window = (slice(3, 27, 2), slice(5, 36))
    problem = Problem(big.cost1[window], big.cost0[window], big.weights[(slice(None), *window)])
    ref = solve_reference(problem)
    assert np.array_equal(solve_reduced(problem).labels, ref.labels)
    seeded, pixel = seeded_problem(rng, 30, 40)
    cut = Problem(seeded.cost1[:, 5:], seeded.cost0[:, 5:], seeded.weights[:, :, 5:])
    centre = (max(pixel[0] - 5, 0), pixel[1])
    cut = Problem(*seed_costs(cut.shape, centre), cut.weights)
    assert_same_minimum(cut, solve_cropped(cut, centre, 2).labels, solve_reference(cut).labels)


def assert_same_minimum(problem: Problem, fast: np.ndarray, ref: np.ndarray) -> None:
    """Equal labels, except in §4.2's one exact tie: when no region beats 1, all-background
    and all-target both cost exactly 1 (Σ 1/n), and rounding picks one."""
    if not np.array_equal(fast, ref):
        assert value(problem, ref) == pytest.approx(1.0, rel=1e-12)
        assert {bool(fast.all()), bool(ref.all())} == {True, False}
        assert not fast.any() or not ref.any()


@pytest.mark.parametrize("seed", range(40))
def test_merged_cut_equals_the_reference_on_random_problems(seed):
    # general energies too: negative costs, seeded and data-term shapes
    rng = np.random.default_rng(2000 + seed)
    h, w = (int(x) for x in rng.integers(1, 30, 2))
    if seed % 2:
        problem, _ = seeded_problem(rng, h, w)
    else:
        problem = random_problem(rng, h, w)
        problem = Problem(problem.cost1 - 0.5, problem.cost0, problem.weights)
    ref = solve_reference(problem)
    labels, _ = solve_merged(problem.cost1, problem.cost0, problem.weights)
    assert value(problem, labels) == pytest.approx(value(problem, ref.labels), rel=1e-12)
    assert_same_minimum(problem, labels, ref.labels)


@pytest.mark.parametrize("seed", range(10))
def test_merged_cut_ignores_weights_of_edges_that_leave_the_grid(seed):
    # a window cut out of a frame keeps the weights of its edges to the rest of the frame
    rng = np.random.default_rng(4000 + seed)
    h, w = (int(x) for x in rng.integers(2, 12, 2))
    problem, _ = seeded_problem(rng, h, w)
    leaking = problem.weights + (in_frame(np.ones((4, h, w))) == 0) * rng.random((4, h, w))
    labels, _ = solve_merged(problem.cost1, problem.cost0, leaking)
    assert_same_minimum(problem, labels, solve_reference(problem).labels)


def test_paths_through_pixels_outside_the_grid_do_not_merge():
    # 1×2, no edge between the two: only the weights stored for edges leaving the grid
    # (south of the seed, south-west of its neighbour) would join them, through (1, 0)
    cost1, cost0 = seed_costs((1, 2), (0, 0))
    weights = np.zeros((4, 1, 2))
    weights[1, 0, 0] = weights[3, 0, 1] = 5.0
    labels, _ = solve_merged(cost1, cost0, weights)
    assert labels.tolist() == [[True, False]]


def test_a_smooth_surface_merges_into_one_node_and_a_step_keeps_it_apart():
    h, w = 20, 30
    cost1, cost0 = seed_costs((h, w), (5, 5))
    weights = in_frame(np.full((4, h, w), 0.6))
    weights[(0, 2), :, 14] = 0.0  # no edge from column 14 east or south-east
    weights[3, :, 15] = 0.0  # nor from column 15 south-west
    count, node = merged_nodes(cost1, cost0, weights)
    assert count == 2
    assert len(set(node[:, :15].ravel())) == 1
    assert len(set(node[:, 15:].ravel())) == 1
    labels, _ = solve_merged(cost1, cost0, weights)
    assert labels[:, :15].all()
    assert not labels[:, 15:].any()
    assert np.array_equal(labels, solve_reference(Problem(cost1, cost0, weights)).labels)


@pytest.mark.parametrize("seed", range(8))
def test_cut_lower_bounds_never_exceed_the_pairs_max_flow(seed):
    # the bound against scipy's max-flow between the two pixels of every axial pair
    rng = np.random.default_rng(500 + seed)
    h, w = 4, 5
    weights = in_frame(rng.integers(0, 9, (4, h, w)).astype(float))
    bounds = cut_lower_bounds(weights)
    n = h * w
    idx = np.arange(n).reshape(h, w)
    rows, cols, caps = [], [], []
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices((h, w), k)
        a, b, c = idx[sp].ravel(), idx[sq].ravel(), weights[k][sp].ravel().astype(np.int32)
        rows += [*a, *b]
        cols += [*b, *a]
        caps += [*c, *c]
    graph = csr_matrix((np.array(caps, np.int32), (rows, cols)), shape=(n, n))
    for slot, k in enumerate((0, 1)):
        sp, sq = pair_slices((h, w), k)
        for p, q, bound in zip(
            idx[sp].ravel(), idx[sq].ravel(), bounds[slot][sp].ravel(), strict=True
        ):
            assert bound <= maximum_flow(graph, int(p), int(q)).flow_value


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
