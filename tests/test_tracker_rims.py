"""An object's outline given back to its mask: mixed pixels, read between the object and the
scenery, go to the nearer, and notches to the track around them."""

from __future__ import annotations

import numpy as np

from tofcut.tracker.rims import add_rims
from tofcut.tracker.tracks import Track


def _track(tid: int, labels: np.ndarray) -> Track:
    rows, cols = np.nonzero(labels == tid)
    return Track(
        tid, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3),
        (int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1),
        int(rows.size), np.zeros((rows.size, 3), np.float32),
    )  # fmt: skip


def test_a_pixel_past_the_midpoint_toward_a_track_is_its_rim():
    # scenery 2.0 m; a box top at 1.8 m holds columns 2-3 of one row; beside it, pixels
    # read 1.85 (past the midpoint 1.9: mostly box), 1.95 (mostly scenery), and one 1.85
    # that is invalid
    scenery = np.full((1, 8), 2.0)
    seen = np.array([[1.95, 1.85, 1.8, 1.8, 1.85, 1.85, 2.0, 2.0]])
    valid = np.array([[True, True, True, True, False, True, True, True]])
    labels = np.array([[0, 0, 1, 1, 0, 0, 0, 0]], np.uint16)
    out = add_rims(labels, (_track(1, labels),), seen, valid, scenery, np.ones((1, 8), bool))
    np.testing.assert_array_equal(out.labels, [[0, 1, 1, 1, 0, 0, 0, 0]])
    # only the rim of the track's mask: pixel 5 touches no track pixel
    (track,) = out.tracks
    assert (track.pixels, track.bbox) == (3, (1, 0, 4, 1))
    assert track.points.shape == (2, 3)  # the rim's points are not the object's surface


def test_a_pixel_between_two_tracks_goes_to_the_one_whose_range_it_is_nearer():
    scenery = np.full((1, 3), 2.0)
    seen = np.array([[1.5, 1.7, 1.8]])
    labels = np.array([[1, 0, 2]], np.uint16)
    tracks = (_track(1, labels), _track(2, labels))
    ones = np.ones((1, 3), bool)
    out = add_rims(labels, tracks, seen, ones, scenery, ones)
    np.testing.assert_array_equal(out.labels, [[1, 2, 2]])
    assert [t.pixels for t in out.tracks] == [1, 2]
    # where the scenery is not known, nothing is given
    out = add_rims(labels, tracks, seen, ones, np.full((1, 3), np.nan), np.zeros((1, 3), bool))
    np.testing.assert_array_equal(out.labels, labels)
    assert out.tracks == tracks


def test_a_pixel_most_of_whose_neighbours_one_track_holds_is_a_notch_in_its_outline():
    # a 4x4 box's mask with a hole (an invalid pixel) and a notch in its side (a pixel read
    # on the scenery); the pixel beside its corner has only three of its neighbours in it
    labels = np.zeros((6, 6), np.uint16)
    labels[1:5, 1:5] = 1
    labels[2, 2] = 0  # hole: all eight neighbours are the track's
    labels[3, 4] = 0  # notch: five of eight
    valid = np.ones((6, 6), bool)
    valid[2, 2] = False
    scenery = np.full((6, 6), 2.0)
    seen = np.where(labels > 0, 1.8, 2.0)
    out = add_rims(labels, (_track(1, labels),), seen, valid, scenery, np.ones((6, 6), bool))
    want = labels.copy()
    want[2, 2] = want[3, 4] = 1
    np.testing.assert_array_equal(out.labels, want)
    assert out.tracks[0].pixels == 16
