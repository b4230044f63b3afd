"""The compiled tracker (the `tofcut.tracker.*_kernels` modules) against its numpy reference:
the same labels and tracks, frame by frame, on emulated scenes."""

from __future__ import annotations

import importlib
import pkgutil
from types import SimpleNamespace

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tofcut.sim import open_scene
from tofcut.sim.crowd import crowd_source
from tofcut.sim.preview import decode, decoded_frames, scene_exposure
from tofcut.tracker import (
    compiled,
    components_kernels,
    cut_kernels,
    distance_kernels,
    measure_kernels,
    multicut,
    multicut_kernels,
    pieces_kernels,
    reference,
    stats,
    stats_kernels,
)
from tofcut.tracker.background import MEDIAN_SHARES
from tofcut.tracker.belt_prior import VelocityPrior
from tofcut.tracker.motion import ConstantVelocity, MotionParams
from tofcut.tracker.multicut import PottsProblem, solve_binary, solve_potts
from tofcut.tracker.pieces import STEP_APART
from tofcut.tracker.reference import ReferenceTracker
from tofcut.tracker.tracker import Tracker


def _kernels():
    every = {name: f for name, (f, _) in compiled.KERNELS.items()} | compiled.HELPERS
    return {name: f for name, f in every.items() if f.signatures}


def _same_run(source, frames):
    belt = source.belt.geometry
    prior = VelocityPrior(belt.direction * source.belt.speed_mps, np.eye(3) * 0.02**2, True)
    fast, reference = Tracker(belt=belt), ReferenceTracker(belt=belt)
    # the tracker warms its kernels up: a live run must not stall on loading one for new
    # argument types mid-stream
    warm = {name: list(f.signatures) for name, f in _kernels().items()}
    assert len(warm) >= 12
    tracked = 0
    for i, (frame, _) in enumerate(decoded_frames(source, frames)):
        got, want = fast.update(frame, prior), reference.update(frame, prior)
        np.testing.assert_array_equal(got.labels, want.labels, err_msg=f"frame {i}")
        assert [t.id for t in got.tracks] == [t.id for t in want.tracks], i
        for g, w in zip(got.tracks, want.tracks, strict=True):
            np.testing.assert_array_equal(g.centroid, w.centroid)
            assert (g.bbox, g.pixels, g.hidden_frames) == (w.bbox, w.pixels, w.hidden_frames)
        tracked += sum(t.visible for t in got.tracks)
    assert {name: list(f.signatures) for name, f in _kernels().items()} == warm
    for name in ("range", "sigma", "known", "_farther", "_farther_min", "_unknown_seen"):
        np.testing.assert_array_equal(
            getattr(fast.background, name), getattr(reference.background, name), err_msg=name
        )
    return tracked


@pytest.mark.parametrize(
    ("source", "frames", "least"),
    [(lambda: crowd_source(10), 30, 100), (lambda: open_scene("conveyor", 0), 60, 60)],
    ids=["crowd-10", "conveyor"],
)
def test_the_compiled_tracker_gives_the_reference_labels_and_tracks(source, frames, least):
    # `least`: enough visible tracks that the cut, not just the empty scene, was compared
    assert _same_run(source(), frames) >= least


def test_surface_distances_are_the_brute_force_minimum():
    rng = np.random.default_rng(3)
    cloud = rng.normal(size=(300, 3)) * 0.05
    points = rng.normal(size=(500, 3)) * 0.08
    points[0] = np.nan
    clouds, axes = distance_kernels.sort_surfaces(cloud, np.array([0, len(cloud)]))
    inverse = np.linalg.inv(np.cov(cloud.T))
    spread = 0.015 + 0.02 * rng.random(len(points))  # each point's own (its range noise)
    distance, rough = distance_kernels.track_distances(
        points, np.full(len(points), np.inf), np.zeros((1, 3)), inverse[None],
        clouds, np.array([0, len(cloud)]), axes, 8.0, 2.5, 0.2, spread, 0.1,
    )  # fmt: skip
    near = np.sqrt(((points[:, None, :] - cloud[None]) ** 2).sum(axis=-1).min(axis=1))
    near[near >= 0.1] = np.inf
    shape = np.einsum("ni,ij,nj->n", points, inverse, points)
    want = np.where(np.isnan(shape), np.inf, shape + 0.2 * (near / spread) ** 2)
    np.testing.assert_array_equal(distance[0], want)
    assert np.isnan(rough).all()
    # with a ceiling, points the shape alone prices out are not measured: their cost from
    # the shape alone comes back instead
    ceiling = np.full(len(points), 8.0 + 2.5 * np.nanmedian(shape))
    capped, rough = distance_kernels.track_distances(
        points, ceiling, np.zeros((1, 3)), inverse[None],
        clouds, np.array([0, len(cloud)]), axes, 8.0, 2.5, 0.2, spread, 0.1,
    )  # fmt: skip
    out = 8.0 + 2.5 * shape > ceiling
    assert out.sum() > 100
    np.testing.assert_array_equal(rough[0][out], (8.0 + 2.5 * shape)[out])
    assert np.isnan(rough[0][~out]).all()
    assert np.isinf(capped[0][out]).all()
    np.testing.assert_array_equal(
        capped[0][~out & np.isfinite(shape)], want[~out & np.isfinite(shape)]
    )


def test_expansion_terms_are_the_numpy_ones():
    rng = np.random.default_rng(4)
    unary = rng.random((3, 40)) * 5
    unary[1, :5] = np.inf  # a label a node cannot take
    i, j = np.triu_indices(40, 1)
    keep = rng.random(i.size) < 0.1
    i, j = i[keep].astype(np.int64), j[keep].astype(np.int64)
    w = rng.random(i.size)
    labels = rng.choice([0, 2], 40).astype(np.int64)
    for alpha in range(3):
        every = np.arange(40)
        source, sink, si, sj, pair = multicut_kernels.expansion_terms(
            unary, labels, alpha, i, j, w, every, every
        )
        np.testing.assert_array_equal(si, i)
        np.testing.assert_array_equal(sj, j)
        idx = np.arange(40)
        li, lj = labels[i], labels[j]
        a, b, c = w * (li != lj), w * (li != alpha), w * (alpha != lj)
        unary1 = unary[alpha, idx] - unary[labels, idx]
        np.add.at(unary1, i, c - a)
        np.add.at(unary1, j, -c)
        np.testing.assert_array_equal(source, np.maximum(unary1, 0.0))
        np.testing.assert_array_equal(sink, np.maximum(-unary1, 0.0))
        np.testing.assert_array_equal(pair, b + c - a)


def test_settled_nodes_left_out_of_the_moves_change_no_cut():
    rng = np.random.default_rng(5)
    for labels in (2, 3, 4):
        for _ in range(20):
            nodes = 60
            i, j = np.triu_indices(nodes, 1)
            keep = rng.random(i.size) < 0.05
            i, j = i[keep].astype(np.int64), j[keep].astype(np.int64)
            unary = rng.random((labels, nodes)) * rng.choice([0.5, 20.0], (labels, nodes))
            problem = PottsProblem(unary, i, j, rng.random(i.size))
            core = multicut._Core.of(problem, None)
            assert 0 < core.nodes.size < nodes  # some settled, some not
            # the same moves from the same start, with every node in the graph
            cheapest = np.argmin(unary, axis=0)
            assert (solve_potts(problem) == solve_potts(problem, start=cheapest)).all()
            if labels == 2:
                every = multicut._Core.of(problem, np.zeros(nodes, np.int64))
                whole = multicut._expand(problem, np.zeros(nodes, np.int64), 1, every)
                assert (solve_binary(problem) == whole).all()


def test_the_filter_update_takes_exactly_what_the_matrix_form_multiplies_out():
    rng = np.random.default_rng(6)
    see = {"position": np.eye(6)[:3], "velocity": np.eye(6)[3:]}
    for _ in range(200):
        fast = ConstantVelocity(rng.normal(size=3), MotionParams(), rng.normal(size=3))
        x, p = fast.x.copy(), fast.P.copy()
        for _ in range(3):
            z, belt = rng.normal(size=3), rng.normal(size=3)
            fast.predict(0.02)
            fast.correct(z)
            fast.follow_belt(VelocityPrior(belt, np.eye(3) * 4e-4, True))
            f = np.eye(6)
            f[:3, 3:] = np.eye(3) * 0.02
            q = np.kron(
                np.array([[0.02**4 / 4, 0.02**3 / 2], [0.02**3 / 2, 0.02**2]]) * 0.25, np.eye(3)
            )
            x, p = f @ x, f @ p @ f.T + q
            for h, value, r in (
                (see["position"], z, np.eye(3) * 0.01**2),
                (see["velocity"], belt, np.eye(3) * 4e-4),
            ):
                k = p @ h.T @ np.linalg.inv(h @ p @ h.T + r)
                x, p = x + k @ (value - h @ x), (np.eye(6) - k @ h) @ p
        np.testing.assert_array_equal(fast.x, x)
        np.testing.assert_array_equal(fast.P, p)


def test_the_compiled_range_noise_is_the_numpy_one():
    import dataclasses

    from tofcut.tracker import noise, reference

    for name in ("conveyor", "person"):
        src = open_scene(name, 0)
        frame, _ = decode(src, scene_exposure(src, 0.0, 0))
        # and where the taps say nothing: a negative intensity, a zero amplitude, nan
        intensity, amplitude = frame.intensity.copy(), frame.amplitude.copy()
        intensity[3, :40], amplitude[5, 10:30], intensity[9, 50] = -1.0, 0.0, np.nan
        odd = dataclasses.replace(frame, intensity=intensity, amplitude=amplitude)
        blind = dataclasses.replace(frame, valid=np.zeros_like(frame.valid))
        for f in (frame, odd, blind):
            np.testing.assert_array_equal(
                noise.range_noise(f, 0.004), reference.range_noise(f, 0.004)
            )


def test_pieces_are_numbered_as_scipy_labels_them():
    from scipy import ndimage

    rng = np.random.default_rng(7)
    for _ in range(300):
        h, w = rng.integers(1, 40, 2)
        body = rng.random((h, w)) < rng.random()
        want, _ = ndimage.label(body)
        np.testing.assert_array_equal(components_kernels.label_pieces(body), want)
    checkerboard = np.indices((9, 11)).sum(axis=0) % 2 == 0  # the most pieces a frame holds
    np.testing.assert_array_equal(
        components_kernels.label_pieces(checkerboard), ndimage.label(checkerboard)[0]
    )


def _images(dtype: type, most: int) -> st.SearchStrategy[np.ndarray]:
    """Small 2D images of `dtype` holding the numbers 0 to `most`: labels, or pieces."""
    shapes = hnp.array_shapes(min_dims=2, max_dims=2, max_side=30)
    return hnp.arrays(dtype, shapes, elements=st.integers(0, most))


@settings(max_examples=200, deadline=None)
@given(_images(np.uint16, 3))
def test_each_labels_regions_are_scipys_8_connected_pieces_with_their_sizes(labels):
    from scipy import ndimage

    regions = components_kernels.label_regions(labels)
    firsts = np.unique(regions.ravel(), return_index=True)[1][1:]  # each region's first pixel
    np.testing.assert_array_equal(firsts, np.sort(firsts))  # numbered in that order
    assert (regions > 0).sum() == (labels > 0).sum()
    for k in np.unique(labels[labels > 0]).tolist():
        want, n = ndimage.label(labels == k, np.ones((3, 3), bool))
        got = regions[labels == k]
        # the same partition: one region for each of scipy's pieces, and the other way
        pairs = np.unique(np.stack([want[labels == k], got]), axis=1)
        assert pairs.shape[1] == n == np.unique(got).size
    again, owner, sizes = components_kernels.region_sizes(labels)
    np.testing.assert_array_equal(again, regions)
    np.testing.assert_array_equal(sizes, np.bincount(regions.ravel()) * (np.arange(sizes.size) > 0))
    np.testing.assert_array_equal(owner[regions[labels > 0]], labels[labels > 0])


def test_point_stats_are_numpys_mean_min_and_max():
    rng = np.random.default_rng(8)
    xyz = rng.normal(size=(144, 176, 3)) * [1e-3, 1.0, 1e3] + 2.0
    for n in (1, 2, 7, 9, 130, 400, 20000):
        mask = np.zeros(144 * 176, bool)
        mask[rng.choice(mask.size, n, replace=False)] = True
        points = xyz[mask.reshape(144, 176)]  # as the tracker takes a mask's points
        mean, lo, hi = measure_kernels.point_stats(points)
        np.testing.assert_array_equal(mean, points.mean(axis=0))
        np.testing.assert_array_equal(lo, points.min(axis=0))
        np.testing.assert_array_equal(hi, points.max(axis=0))
    points[3, 1] = np.nan
    _, lo, hi = measure_kernels.point_stats(points)
    np.testing.assert_array_equal(lo, points.min(axis=0))
    np.testing.assert_array_equal(hi, points.max(axis=0))


@settings(max_examples=200, deadline=None)
@given(_images(np.int32, 9))
def test_piece_boxes_sizes_and_holdings_are_scipys_and_numpys(pieces):
    from scipy import ndimage

    boxes = measure_kernels.piece_boxes(pieces)
    want = ndimage.find_objects(pieces)
    assert len(boxes) == len(want)
    for got, box in zip(boxes.tolist(), want, strict=True):
        rows, cols = box or (slice(0, 0), slice(0, 0))
        assert got == [rows.start, rows.stop, cols.start, cols.stop]
    np.testing.assert_array_equal(measure_kernels.piece_sizes(pieces), np.bincount(pieces.ravel()))
    # and by label's row (rows 1.. hold labels 1..; label 4, row 0, is none of them)
    labels = (pieces[::-1] % 5).astype(np.uint16)
    row = np.array([0, 1, 2, 3, 0], np.int64)
    n = int(pieces.max()) + 1
    want = np.bincount((row[labels] * n + pieces).ravel(), minlength=4 * n).reshape(4, n)
    want[0], want[:, 0] = 0, 0
    np.testing.assert_array_equal(measure_kernels.held_pieces(labels, pieces, row, 4, n), want)


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.bool_, hnp.array_shapes(min_dims=2, max_dims=2, max_side=12)), st.data())
def test_a_masks_points_are_numpys_boolean_index(mask, data):
    from tofcut.tracker import frame_kernels

    h, w = mask.shape
    top, left = data.draw(st.integers(0, 5)), data.draw(st.integers(0, 5))
    xyz = np.arange((h + top + 3) * (w + left + 2) * 3, dtype=float).reshape(h + top + 3, -1, 3)
    np.testing.assert_array_equal(
        frame_kernels.points_in(xyz, mask, top, left), xyz[top : top + h, left : left + w][mask]
    )


def test_rims_and_notches_are_given_as_the_numpy_form_gives_them():
    from tofcut.tracker import rims_kernels

    rng = np.random.default_rng(11)
    for _ in range(200):
        h, w = rng.integers(1, 20, 2)
        # sparse, or dense enough for notches (five of eight neighbours held by one track)
        tracks, held = (4, 0.4) if rng.random() < 0.5 else (2, 0.85)
        labels = (rng.integers(1, tracks, (h, w)) * (rng.random((h, w)) < held)).astype(np.uint16)
        scenery = rng.uniform(1.8, 2.2, (h, w))
        known = rng.random((h, w)) < 0.9
        scenery[~known] = np.nan
        # ranges on a coarse grid, so that ties between neighbours happen
        seen = np.round(rng.uniform(1.5, 2.3, (h, w)), 1)
        valid = rng.random((h, w)) < 0.9
        ids = np.arange(1, tracks, dtype=np.int64)
        boxes = np.zeros((ids.size, 4), np.int64)
        pixels = np.zeros(ids.size, np.int64)
        for k, i in enumerate(ids):
            rows, cols = np.nonzero(labels == i)
            if rows.size:
                boxes[k] = cols.min(), rows.min(), cols.max() + 1, rows.max() + 1
                pixels[k] = rows.size
        got, grown, counts = rims_kernels.rims(
            labels, seen, valid, scenery, known, ids, boxes, pixels
        )
        np.testing.assert_array_equal(got, reference.rims(labels, seen, valid, scenery, known))
        for k, i in enumerate(ids):  # each track's box and pixels, as its mask now has them
            rows, cols = np.nonzero(got == i)
            assert counts[k] == rows.size
            if rows.size:
                box = [cols.min(), rows.min(), cols.max() + 1, rows.max() + 1]
                np.testing.assert_array_equal(grown[k], box)


@settings(max_examples=200, deadline=None)
@given(
    hnp.arrays(
        np.uint16, hnp.array_shapes(min_dims=2, max_dims=2, max_side=20), elements=st.integers(0, 6)
    )
)
def test_where_labels_meet_is_where_the_numpy_slices_find_them(labels):
    from tofcut.tracker import tops_kernels
    from tofcut.tracker.neighbours import OFFSETS, pair_slices

    rows, cols, ks, keys = tops_kernels.meetings(labels, 7)
    want = []
    for k in (0, 1):
        first, second = pair_slices(labels.shape, k)
        a, b = labels[first].astype(np.int64), labels[second].astype(np.int64)
        v, u = np.nonzero((a != b) & (a > 0) & (b > 0))
        x, y = labels[v, u].astype(np.int64), labels[v + OFFSETS[k][0], u + OFFSETS[k][1]]
        key = np.minimum(x, y) * 7 + np.maximum(x, y)
        want.append(np.stack([v, u, np.full(v.size, k), key], axis=1))
    np.testing.assert_array_equal(np.stack([rows, cols, ks, keys], axis=1), np.concatenate(want))


def test_the_unmeasured_costs_needed_are_those_the_numpy_form_finds():
    rng = np.random.default_rng(11)
    for _ in range(200):
        k, n = rng.integers(1, 5), rng.integers(1, 30)
        pairs = rng.permutation(k * n)[: rng.integers(1, k * n + 1)]
        labels, cells = pairs // n + 1, pairs % n
        unary = rng.choice(
            [0.0, 0.5, 1.0, 2.0, np.inf, np.nan], (k + 1, n), p=[0.2] * 4 + [0.1] * 2
        )
        least = np.where(rng.random((k, n)) < 0.5, np.nan, rng.choice([0.5, 1.0, 2.5, 3.0], (k, n)))
        ties = rng.choice([0.0, 0.5, 1.0], n)
        unmeasured = ~np.isnan(least[labels - 1, cells])
        held = ~unmeasured & np.isfinite(unary[labels, cells])
        top = unary[0].copy()
        with np.errstate(invalid="ignore"):  # a nan in the background's costs stays
            np.maximum.at(top, cells[held], unary[labels[held], cells[held]])
        want = unmeasured.copy()
        at = cells[unmeasured]
        want[unmeasured] = least[labels[unmeasured] - 1, at] <= top[at] + ties[at] + 1e-6
        got = cut_kernels.unmeasured_needed(labels, cells, unary, least, ties, 1e-6)
        np.testing.assert_array_equal(got, want)


def test_touching_pieces_are_the_pieces_under_each_dilated_mask():
    from scipy import ndimage

    rng = np.random.default_rng(10)
    for _ in range(100):
        h, w = rng.integers(1, 30, 2)
        labels = (rng.integers(0, 4, (h, w)) * (rng.random((h, w)) < 0.3)).astype(np.uint16)
        pieces = (rng.integers(0, 6, (h, w)) * (rng.random((h, w)) < 0.3)).astype(np.int32)
        reach = int(rng.integers(1, 3))
        ids, starts, near = measure_kernels.touching(labels, pieces, reach)
        got = {i: near[starts[k] : starts[k + 1]].tolist() for k, i in enumerate(ids.tolist())}
        want = {}
        for lab in range(1, 4):
            around = ndimage.binary_dilation(labels == lab, np.ones((3, 3), bool), reach)
            found = [int(r) for r in np.unique(pieces[around]) if r > 0]
            if found:
                want[lab] = found
        assert got == want


def test_3x3_medians_are_scipys_and_a_nan_is_placed_as_an_insertion_sort_places_it():
    from scipy import ndimage

    def inserted(values):  # the insertion sort median3_at falls back on where a nan is
        window = []
        for x in values:
            k = len(window)
            window.append(x)
            while k > 0 and window[k - 1] > x:
                window[k] = window[k - 1]
                k -= 1
            window[k] = x
        return window[4]

    rng = np.random.default_rng(11)
    for i in range(200):
        h, w = rng.integers(1, 20, 2)
        values = rng.integers(0, 4, (h, w)).astype(float) if i % 2 else rng.normal(size=(h, w))
        where = rng.random((h, w)) < 0.7
        want = np.where(where, ndimage.median_filter(values, 3, mode="nearest"), values)
        np.testing.assert_array_equal(stats_kernels.median3_at(values, where), want)
        values[rng.random((h, w)) < 0.1] = np.nan
        padded = np.pad(values, 1, mode="edge")
        want = values.copy()
        for v, u in zip(*np.nonzero(where), strict=True):
            want[v, u] = inserted(padded[v : v + 3, u : u + 3].ravel().tolist())
        np.testing.assert_array_equal(stats_kernels.median3_at(values, where), want)


@settings(max_examples=100, deadline=None)
@given(
    hnp.arrays(
        np.float64,
        hnp.array_shapes(min_dims=2, max_dims=2, max_side=8),
        elements=st.sampled_from([0.0, -0.0, 1.0, 2.0, -3.5]) | st.floats(-10, 10),
    )
)
def test_a_3x3_median_by_sorted_columns_is_the_median_of_the_nine(values):
    # ties drawn often; edges repeated, as the background's cost takes its medians
    h, w = values.shape
    window, column = np.empty(9), np.empty((w, 3))
    for v in range(h):
        for u in range(w):
            assert stats_kernels.sorted_column(values, v, u, column[u])
        for u in range(w):
            left, right = max(u - 1, 0), min(u + 1, w - 1)
            got = stats_kernels.median3_from_columns(column[left], column[u], column[right])
            rows = [max(v - 1, 0), v, min(v + 1, h - 1)]
            want = np.median(values[np.ix_(rows, [left, u, right])])
            assert got == want == stats_kernels.median3(values, v, u, window)
    values[0, 0] = np.nan
    assert not stats_kernels.sorted_column(values, 0, 0, column[0])


def test_seams_are_counted_as_the_numpy_form_counts_them():
    from tofcut.tracker.neighbours import pair_slices

    rng = np.random.default_rng(12)
    for _ in range(100):
        h, w = rng.integers(2, 25, 2)
        xyz = rng.normal(size=(h, w, 3)) * 0.01
        pieces = rng.integers(0, 3, (h, w)).astype(np.int32)
        top, left = int(rng.integers(0, h)), int(rng.integers(0, w))
        mask = rng.random((int(rng.integers(1, h - top + 1)), int(rng.integers(1, w - left + 1))))
        mask = mask < 0.5
        whole = np.zeros((h, w), bool)
        whole[top : top + mask.shape[0], left : left + mask.shape[1]] = mask
        near = np.array([1, 2], np.int64)
        corners = np.zeros((2, 4), np.int64)
        want = []
        for k, r in enumerate(near):
            r0, c0 = int(rng.integers(0, h)), int(rng.integers(0, w))
            r1, c1 = int(rng.integers(r0 + 1, h + 1)), int(rng.integers(c0 + 1, w + 1))
            corners[k] = r0, r1, c0, c1
            rows = slice(max(r0 - 1, 0), min(r1 + 1, h))
            cols = slice(max(c0 - 1, 0), min(c1 + 1, w))
            a, b, pts = whole[rows, cols], pieces[rows, cols] == r, xyz[rows, cols]
            meet = joined = 0
            for d in (0, 1):  # as `Roster._continuing` counted them in numpy
                one, other = pair_slices(a.shape, d)
                pairs = (a[one] & b[other]) | (b[one] & a[other])
                gap = np.linalg.norm(pts[one][pairs] - pts[other][pairs], axis=-1)
                meet += gap.size
                joined += int(np.count_nonzero(gap <= 0.01))
            want.append((np.count_nonzero(pieces[r0:r1, c0:c1] == r), meet, joined))
        sizes, meet, joined = measure_kernels.seams(
            mask, top, left, pieces, near, corners, xyz, 0.01
        )
        assert list(zip(sizes, meet, joined, strict=True)) == want


def test_cut_at_steps_leaves_out_what_the_numpy_form_does():
    rng = np.random.default_rng(9)
    for _ in range(50):
        h, w = rng.integers(2, 30, 2)
        body = rng.random((h, w)) < rng.random()
        xyz = rng.normal(size=(h, w, 3)) * 0.02
        far = rng.integers(0, 3, (h, w)).astype(float)  # ties: the upper-left pixel goes
        noise = rng.random((h, w)) * 0.02
        noise[rng.random((h, w)) < 0.05] = np.inf  # as at invalid pixels
        for step_noise in (True, False):
            spread2 = 9.0 * noise**2 if step_noise else np.zeros((h, w))
            want = body.copy()
            for dv, du in ((0, 1), (1, 0)):
                a, b = (slice(0, h - dv), slice(0, w - du)), (slice(dv, h), slice(du, w))
                jump = np.sum((xyz[a] - xyz[b]) ** 2, axis=-1) > np.maximum(
                    1e-3, spread2[a] + spread2[b]
                )
                jump &= body[a] | body[b]
                want[a] &= ~(jump & (far[a] > far[b]))
                want[b] &= ~(jump & ~(far[a] > far[b]))
            np.testing.assert_array_equal(
                pieces_kernels.cut_at_steps(body, xyz, far, 1e-3, noise, step_noise), want
            )


def test_the_background_cost_weighs_the_nearness_as_the_background_model_does():
    # reference.weighed_nearness's numpy, then the cost of the scenery seen at
    # model - nearer (as JointCut.background_cost passed it before the two were one pass)
    rng = np.random.default_rng(13)
    factor, loud_sigma, share, deadband, cap, unknown = 4.0, 0.05, 0.418, 1.0, 8.0, 3.0
    for _ in range(40):
        h, w = rng.integers(1, 25, 2)
        model = rng.random((h, w)) + 1.0
        sigma = rng.random((h, w)) * 0.025  # loud (4σ > 0.05) about half the time
        known, valid = rng.random((2, h, w)) < 0.9
        seen = model - rng.normal(size=(h, w)) * 0.05
        seen[rng.random((h, w)) < 0.05] = np.nan
        usable = valid & known
        with np.errstate(invalid="ignore"):
            nearer = np.where(usable, model - seen, 0.0)
        loud = usable & (factor * sigma > loud_sigma)
        nearer = np.where(loud, stats_kernels.median3_at(nearer, loud), nearer)
        noise = np.where(loud, sigma * share, sigma)
        with np.errstate(invalid="ignore"):
            z = np.where(usable, (model - (model - nearer)) / noise, 0.0) - deadband
        want = np.where(known, np.minimum(0.5 * np.maximum(z, 0.0) ** 2, cap), unknown)
        shares = np.array([1.0, share, 0.251, 0.179])  # none louder than a 3×3 median quietens
        got = cut_kernels.background_cost(
            model, sigma, known, seen, valid, factor, loud_sigma, shares, deadband, cap, unknown
        )
        np.testing.assert_array_equal(got, want)


def test_the_background_cost_widens_the_median_where_the_noise_is_louder():
    # 3×3 to 7×7 windows by the noise, against reference.weighed_nearness's numpy (scipy's
    # median filter for the wider windows)
    rng = np.random.default_rng(21)
    factor, loud_sigma, deadband, cap, unknown = 4.0, 0.05, 1.0, 8.0, 3.0
    for _ in range(30):
        h, w = rng.integers(1, 25, 2)
        bg = SimpleNamespace(
            range=rng.random((h, w)) + 1.0,
            sigma=rng.random((h, w)) * 0.12,  # quiet, 3×3, 5×5 and 7×7 windows
            known=rng.random((h, w)) < 0.9,
            params=SimpleNamespace(
                noise_factor=factor, min_height_sigmas=1.0, min_height_m=loud_sigma
            ),
        )
        frame = SimpleNamespace(valid=rng.random((h, w)) < 0.9)
        seen = bg.range - rng.normal(size=(h, w)) * 0.05
        nearer, noise = reference.weighed_nearness(bg, frame, seen)
        usable = frame.valid & bg.known
        z = np.where(usable, (bg.range - (bg.range - nearer)) / noise, 0.0) - deadband
        want = np.where(bg.known, np.minimum(0.5 * np.maximum(z, 0.0) ** 2, cap), unknown)
        got = cut_kernels.background_cost(
            bg.range, bg.sigma, bg.known, seen, frame.valid, factor, loud_sigma, MEDIAN_SHARES,
            deadband, cap, unknown,
        )  # fmt: skip
        np.testing.assert_array_equal(got, want)


def test_quieten_moves_the_loud_points_as_the_numpy_form_does():
    rng = np.random.default_rng(14)
    for _ in range(30):
        h, w = rng.integers(1, 25, 2)
        frame = SimpleNamespace(xyz=rng.normal(size=(h, w, 3)), range=rng.random((h, w)) + 0.5)
        frame.range[rng.random((h, w)) < 0.1] = 0.0  # not moved along its ray
        # none loud, or some (3×3), or some very loud (up to 7×7 windows)
        noise = rng.random((h, w)) * rng.choice([0.01, 0.02, 0.06])
        body = rng.random((h, w)) < 0.7
        want = reference.quietened(frame, body, noise, 0.03)
        got = pieces_kernels.quieten(
            frame.xyz, frame.range, noise, body, 0.03, MEDIAN_SHARES, STEP_APART
        )
        for g, x in zip(got, (want.xyz, want.range, want.noise), strict=True):
            np.testing.assert_array_equal(g, x)


def test_the_compiled_median_is_numpys():
    """Below and above `SAMPLED` values, with ties, sorted, heavy tails and infinities, and
    where the sample's brackets miss the middle (every SAMPLE_STEP-th value far off)."""
    rng = np.random.default_rng(10)
    for n in (1, 2, 3, 8, 9, 100, 511, 512, 513, 6263, 6264):
        missed = rng.random(n)
        missed[:: stats_kernels.SAMPLE_STEP] += 10.0
        tails = rng.standard_cauchy(n)
        tails[: n // 10] = np.inf
        tails[n // 10 : n // 5] = -np.inf
        for values in (
            rng.random(n), rng.integers(0, 4, n).astype(float), np.sort(rng.random(n)),
            missed, tails,
        ):  # fmt: skip
            assert stats_kernels.median(values) == np.median(values)
    values[1] = np.nan
    assert np.isnan(stats_kernels.median(values))


def test_whether_the_median_lies_above_a_value_is_the_compiled_medians_answer():
    rng = np.random.default_rng(11)
    near = [0.1, 0.19, 0.2, np.nextafter(0.2, 1.0), 0.21, 0.3]  # ties at and next to 0.2
    for n in (0, 1, 2, 3, 4, 9, 10, 101, 1000):
        for _ in range(30):
            values = rng.choice(near, n)
            values[: n // 2] = rng.random(n // 2) * 0.4
            for x in (0.0, 0.2, 0.25, 1.0):
                want = bool(n and stats_kernels.median(values) > x)
                assert stats_kernels.median_above(values, x) == want
    values = np.array([0.1, 0.3])  # half above 0.19 and 0.2: the two middle values' mean
    assert stats_kernels.median_above(values, 0.19)
    assert not stats_kernels.median_above(values, 0.2)
    values[1] = np.nan
    assert not stats_kernels.median_above(values, 0.0)


_POINTS = hnp.arrays(
    np.float64,
    st.tuples(st.integers(4, 3000), st.just(3)),
    elements=st.floats(-1e3, 1e3, allow_nan=False, allow_subnormal=True),
)


@settings(max_examples=300, deadline=None)
@given(_POINTS, st.integers(-3, 3))
def test_a_clouds_covariance_is_numpys(points, scale):
    # centred point by point in order, as numpy sums an F-ordered points.T
    points = points * 10.0**scale
    np.testing.assert_array_equal(stats.covariance(points), np.cov(points.T))


@settings(max_examples=300, deadline=None)
@given(
    hnp.arrays(
        np.float64,
        st.integers(1, 2000),
        elements=st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.0, 1.0]),
    ),
    st.floats(0.0, 100.0),
)
def test_a_percentile_is_numpys(values, q):
    # ties (0 and 1 drawn often), and numpy's own rules for an inf or a nan
    with np.errstate(invalid="ignore"):
        got, want = stats.percentile(values, q), np.percentile(values, q)
    assert got == want or (np.isnan(got) and np.isnan(want))


def test_sorted_surfaces_hold_the_same_points_in_slabs_in_order_along_their_axis():
    rng = np.random.default_rng(12)
    clouds = [rng.normal(size=(n, 3)) * [0.05, 0.1, 0.02] for n in (1, 7, 300, 401)]
    clouds.append(np.repeat(rng.normal(size=(3, 3)), 40, axis=0))  # many ties
    starts = np.cumsum([0] + [len(c) for c in clouds])
    out, axes = distance_kernels.sort_surfaces(np.concatenate(clouds), starts)
    for k, cloud in enumerate(clouds):
        got = out[starts[k] : starts[k + 1]]
        along = got[:, axes[k]]
        for s in range(distance_kernels.SLAB, len(got), distance_kernels.SLAB):
            assert along[s - distance_kernels.SLAB : s].max() <= along[s:].min()
        np.testing.assert_array_equal(np.unique(got, axis=0), np.unique(cloud, axis=0))
        assert len(got) == len(cloud)


def test_grouping_is_a_stable_argsort():
    rng = np.random.default_rng(13)
    for n in (0, 1, 2, 3, 10, 101, 1000):
        for count in (1, 3, 40):
            keys = rng.integers(0, count, n).astype(np.int64)
            order, bounds = cut_kernels._grouped(keys, count)
            want = np.argsort(keys, kind="stable")
            np.testing.assert_array_equal(order, want)
            np.testing.assert_array_equal(bounds, np.searchsorted(keys[want], np.arange(count + 1)))


def test_every_step_the_reference_replaces_is_still_a_step_of_the_tracker():
    # the reference's parts override the tracker's steps by name: a step renamed or removed
    # in the tracker would leave the reference's version unused, and the equivalence tests
    # above would compare the compiled path with itself
    from tofcut.tracker.background import BackgroundModel
    from tofcut.tracker.cut import JointCut
    from tofcut.tracker.pieces import Pieces
    from tofcut.tracker.reference import ReferenceBackground, ReferenceCut, ReferencePieces

    parts = {"background_model": BackgroundModel, "cut_model": JointCut, "pieces_model": Pieces}
    for name, base in parts.items():
        assert getattr(Tracker, name) is base
        assert issubclass(getattr(ReferenceTracker, name), base)
    for ref, base in (
        (ReferenceCut, JointCut), (ReferencePieces, Pieces), (ReferenceBackground, BackgroundModel)
    ):  # fmt: skip
        replaced = {
            name for name, value in vars(ref).items()
            if callable(value) and not name.startswith("__")
        }  # fmt: skip
        assert replaced, ref
        missing = [name for name in replaced if not callable(getattr(base, name, None))]
        assert not missing, f"{ref.__name__} replaces {missing}, which {base.__name__} lacks"


def _compiled_in(module_name):
    """The numba functions a module defines (not those it imports), by module and name."""
    module = importlib.import_module(module_name)
    return {
        f"{module_name}.{name}": f
        for name, f in vars(module).items()
        if isinstance(f, numba.core.dispatcher.Dispatcher) and f.py_func.__module__ == module_name
    }


def test_every_compiled_kernel_is_registered_for_the_warm_up():
    import tofcut.tracker

    # every compiled function of the multi-object tracker (the paper's segmentation, in its
    # own package, is not the tracker's) lives in a kernel module...
    modules = [f"tofcut.tracker.{m.name}" for m in pkgutil.iter_modules(tofcut.tracker.__path__)]
    assert set(compiled.kernel_modules()) < set(modules)
    stray = [
        name for module in modules if module not in compiled.kernel_modules()
        for name in _compiled_in(module)
    ]  # fmt: skip
    assert not stray, f"compiled outside a *_kernels module: {stray}"
    found = {}
    for module in compiled.kernel_modules():
        found |= _compiled_in(module)
    assert len(found) >= 40
    # ...registered as a kernel, with the argument types it is called with, or as a helper
    registered = {name: f for name, (f, _) in compiled.KERNELS.items()} | compiled.HELPERS
    unregistered = sorted(name for name, f in found.items() if registered.get(name) is not f)
    assert not unregistered, f"compiled, but registered for the warm-up neither way: {unregistered}"
    # a helper is warmed up inside the kernels that call it: some kernel reaches it
    helpers = {id(f): f for f in compiled.HELPERS.values()}
    reached, todo = set(), [f for f, _ in compiled.KERNELS.values()]
    while todo:
        f = todo.pop()
        for name in f.py_func.__code__.co_names:
            callee = id(f.py_func.__globals__.get(name))
            if callee in helpers and callee not in reached:
                reached.add(callee)
                todo.append(helpers[callee])
    idle = sorted(name for name, f in compiled.HELPERS.items() if id(f) not in reached)
    assert not idle, f"helpers no kernel calls, so never warmed up: {idle}"
    # and the warm-up loads each kernel for each of its examples
    compiled.warm_up()
    for name, (f, examples) in compiled.KERNELS.items():
        assert len(f.signatures) >= len(examples), name
