"""The tracker's per-pixel loops are compiled with numba (one thread), each in a module beside
the code it serves (`cut_kernels` beside the cut, `background_kernels` beside the background
model, ...); this module warms them all up.

Each kernel does the same floating-point operations in the same order as the numpy
expressions it replaces (`tofcut.tracker.reference` holds those), with numpy's rules for
division by zero, so the tracker's output does not change.
"""

from __future__ import annotations

import numpy as np

from tofcut.tracker.background_kernels import follow_scene, standing_out, standing_regions
from tofcut.tracker.belt_sweep_kernels import sweep_scores
from tofcut.tracker.components_kernels import label_pieces
from tofcut.tracker.cut_kernels import (
    add_fixed_ties,
    add_fixed_ties_at,
    background_cost,
    binary_parts,
    cut_nodes,
    free_edges,
    free_pixels,
    object_costs,
    split_parts,
    tie_exponents,
    tie_weights,
)
from tofcut.tracker.distance_kernels import sort_surfaces, track_distances
from tofcut.tracker.measure_kernels import held_pieces, label_points, point_stats
from tofcut.tracker.multicut_kernels import cheapest_where, expansion_terms, moving_graph, settled
from tofcut.tracker.noise_kernels import noise_fit, noise_scaled
from tofcut.tracker.pieces_kernels import cut_at_steps
from tofcut.tracker.stats_kernels import median, median3_at, median3_within
from tofcut.tracker.tops_kernels import steep_pixels, top_stats


def warm_up() -> None:
    """Load (or compile) every kernel for the argument types the tracker calls it with, so
    the first frames of a live run do not stall on it (about a second, once per process)."""
    global _warm
    if _warm:
        return
    f64, i64, yes = np.zeros((2, 2)), np.zeros((2, 2), np.int64), np.ones((2, 2), bool)
    xyz, wt = np.zeros((2, 2, 3)), np.zeros((4, 2, 2))
    one = np.zeros(1, np.int64)
    tie_weights(tie_exponents(xyz, yes, yes, 1.0), yes, yes, 1.0)
    free, rows, cols, _, _, _ = free_pixels(yes, f64, f64, xyz, f64, 0.0)  # all four free
    cost = object_costs(np.zeros((1, 4)), 1.0, 1.0, f64, f64, rows, cols, free)
    cut_nodes(free, rows, cols, f64, f64, cost, cost)
    free_edges(i64, wt, rows, cols)
    add_fixed_ties(np.zeros((2, 4)), i64, wt, rows, cols)
    add_fixed_ties_at(np.zeros(1), i64, wt, one, one)
    points, ceiling = np.zeros((1, 3)), np.zeros(1)
    starts = np.array([0, 1])
    cloud, axes = sort_surfaces(points, starts)
    track_distances(
        points, ceiling, points, np.eye(3)[None], cloud, starts, axes, 1.0, 1.0, 1.0,
        np.ones(1), 1.0,
    )  # fmt: skip
    label_pieces(cut_at_steps(yes, xyz, f64, 1.0, f64))
    point_stats(points)
    label_points(np.zeros((2, 2), np.uint16), xyz, one)
    held_pieces(np.zeros((2, 2), np.uint16), np.zeros((2, 2), np.int32), one, 1, 1)
    moving_graph(np.ones(1, bool), one, one, np.zeros(1))
    part_of, order, _, edge_order, _, _, can_win, _ = split_parts(f64, one, one, np.zeros(2))
    binary_parts(f64, one, one, np.zeros(1), part_of, order, edge_order, can_win[0], can_win)
    unary = np.zeros((2, 3))
    for layout in (unary, np.asfortranarray(unary)):  # a stack, and columns taken out of one
        settled(layout, one, one, np.zeros(1))
        cheapest_where(layout, np.ones(3, bool))
        expansion_terms(layout, np.zeros(3, np.int64), 1, one, one, np.zeros(1), one, one)
    background_cost(f64, f64, yes, f64, yes, 1.0, 1.0, 1.0)
    noise_scaled(noise_fit(f64, f64, yes, f64, 1)[0], 1.0, 1.0)
    median(np.zeros(2))
    f32 = np.zeros((2, 2), np.float32)
    sweep_scores(f32, yes, f32, f32, np.zeros(1), 2)
    standing_out(f64, f64, yes, f64, yes, np.zeros((2, 2), np.uint16), 1.0, 1.0)
    counts = np.zeros((2, 2), np.int32)
    follow_scene(
        f64, f64, yes, counts, f64, counts, np.zeros((1, 1, 1)), f64, yes, yes, yes, f64, 1.0,
        1.0, 1.0, 1, 1.0, 1.0,
    )  # fmt: skip
    median3_at(f64, yes)
    median3_within(f64, yes, yes)
    standing_regions(f64, f64, yes, f64, 1, 1.0, 1.0, 1.0)
    steep_pixels(yes, xyz, f64, np.ones(3), 1, 1.0)
    top_stats(np.ones((2, 2), np.int32), 1, np.ones((2, 2), np.int32), xyz, f64, np.zeros(3),
              np.ones(3))  # fmt: skip
    _warm = True


_warm = False
