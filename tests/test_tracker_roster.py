"""When a track holds two objects (`tofcut.tracker.roster._two_objects`): synthetic masks."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.tracker.roster import _two_objects

STEP_M = 0.03


def _scene(gap_range_m: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two 10×10 surfaces at 1.5 m held by one track: side by side when `gap_range_m` is
    None, else three columns apart with that range seen between them."""
    pieces = np.zeros((20, 40), np.int32)
    rng = np.full((20, 40), 2.0)
    pieces[5:15, 5:15] = 1
    right = 15 if gap_range_m is None else 18
    pieces[5:15, right : right + 10] = 2
    rng[pieces > 0] = 1.5
    if gap_range_m is not None:
        rng[5:15, 15:18] = gap_range_m
    return pieces, pieces > 0, rng


def test_two_surfaces_side_by_side_in_one_mask_are_two_objects():
    pieces, mask, rng = _scene(None)
    assert _two_objects(pieces, np.array([1, 2]), mask, rng, STEP_M)


def test_a_surface_mostly_held_by_another_track_still_counts_where_this_one_holds_it():
    # the largest surface lies mostly outside this track's mask (another track has it)
    pieces, mask, rng = _scene(None)
    pieces[5:15, 25:39] = 2  # surface 2 runs on to the right, beyond this track
    mask[:, 22:] = False
    assert _two_objects(pieces, np.array([1, 2]), mask, rng, STEP_M)


@pytest.mark.parametrize(
    ("gap_range_m", "two"),
    [
        (2.0, True),  # the belt seen between them: two objects apart
        (1.2, False),  # something in front: one object seen either side of an occluder
        (1.5, False),  # the object's own surface, missed: one object
        (np.nan, False),  # nothing read between them: no guess
    ],
)
def test_parts_of_a_mask_are_two_objects_only_with_the_scenery_seen_between(gap_range_m, two):
    pieces, mask, rng = _scene(gap_range_m)
    assert _two_objects(pieces, np.array([1, 2]), mask, rng, STEP_M) is two
