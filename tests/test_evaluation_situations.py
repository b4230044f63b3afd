"""The two situations the tracker's bars name, scored from masks: objects in view from the
first frame, and touching pairs of different heights (`tofcut.tools.evaluation.situations`)."""

from __future__ import annotations

import numpy as np

from tofcut.sim.family import draw_line
from tofcut.sim.truth import FrameTruth, ObjectTruth
from tofcut.tools.evaluation.family import Plan, touching_pairs
from tofcut.tools.evaluation.situations import situations

A = np.s_[2:12, 2:12]  # object 1: 100 pixels
B = np.s_[2:12, 12:22]  # object 2 beside it: 100 pixels


def _truths(frames: int, shown: dict[int, object]) -> list[FrameTruth]:
    """`frames` frames of a 16×24 image in which each object id shows where `shown` says."""
    out = []
    for k in range(frames):
        labels = np.zeros((16, 24), np.int32)
        objects = []
        for oid, where in shown.items():
            labels[where] = oid
            z = np.zeros(3)
            objects.append(ObjectTruth(oid, f"box-{oid}", np.eye(4), z, z, z, z,
                                       int(np.count_nonzero(labels == oid))))  # fmt: skip
        out.append(FrameTruth(k, k / 50, (0.0, 0.0, 0.0, 0.0), labels,
                              np.ones((16, 24), np.float32), tuple(objects)))  # fmt: skip
    return out


def _masks(frames: int, held: dict[int, tuple[object, int]]) -> list[np.ndarray]:
    """Label images: from frame `start` on, `where` holds track `track` (held[track])."""
    out = []
    for k in range(frames):
        m = np.zeros((16, 24), np.uint16)
        for track, (where, start) in held.items():
            if k >= start:
                m[where] = track
        out.append(m)
    return out


def test_an_object_in_view_from_the_start_is_held_by_frame_ten_and_kept():
    truths = _truths(30, {1: A})
    assert situations(truths, _masks(30, {7: (A, 4)})).from_start_held == 1
    late = situations(truths, _masks(30, {7: (A, 11)}))
    assert (late.from_start, late.from_start_held) == (1, 0)
    switched = _masks(30, {7: (A, 4)})
    for m in switched[20:]:
        m[A] = 8
    assert situations(truths, switched).from_start_held == 0
    lost = _masks(30, {7: (A, 4)})
    lost[15][A] = 0
    assert situations(truths, lost).from_start_held == 0
    half = _masks(30, {7: (np.s_[2:12, 2:6], 4)})  # 40% of it: not held
    assert situations(truths, half).from_start_held == 0


def test_touching_objects_count_apart_only_when_two_tracks_hold_them():
    truths = _truths(20, {1: A, 2: B})
    pair = [("box-1", "box-2")]
    apart = situations(truths, _masks(20, {3: (A, 2), 4: (B, 2)}), pair)
    assert (apart.touching, apart.touching_apart) == (1, 1)
    both = np.s_[2:12, 2:22]
    one = situations(truths, _masks(20, {3: (both, 2)}), pair)
    assert (one.touching, one.touching_apart) == (1, 0)
    assert situations(truths, _masks(20, {3: (A, 2), 4: (B, 2)})).touching == 0  # no pairs


def test_a_family_lines_touching_pairs_are_its_contacts_of_different_heights():
    plan = Plan("family:conveyor:{seed}", (7,), ("tofcut",), work=None)  # type: ignore[arg-type]
    line = draw_line("conveyor", 7)
    height = {o.name: o.height_m for o in line.objects}
    pairs = touching_pairs(plan, 7)
    assert pairs
    for a, b in pairs:
        assert abs(height[a] - height[b]) >= 0.04
    kinds = {frozenset((c.a, c.b)): c.kind for c in line.contacts()}
    assert all(kinds[frozenset(p)] in ("side", "nose") for p in pairs)
    touching = [c for c in line.contacts() if c.kind != "near"]
    assert len(pairs) == sum(abs(height[c.a] - height[c.b]) >= 0.04 for c in touching)
    assert touching_pairs(Plan("conveyor", (7,), ("tofcut",), work=None), 7) == ()  # type: ignore[arg-type]


def test_a_pair_that_flickers_in_and_out_of_view_passes_once():
    # one of the two partly hidden, showing about MIN_PIXELS: each break of a frame or two
    # is not a new passage (one line counted one pass 37 times)
    truths = _truths(40, {1: A, 2: B})
    for k in range(3, 40, 4):
        truths[k].labels[truths[k].labels == 2] = 0
    masks = _masks(40, {3: (A, 2), 4: (B, 2)})
    seen = situations(truths, masks, [("box-1", "box-2")])
    assert (seen.touching, seen.touching_apart) == (1, 1)
    apart = [_truths(10, {1: A, 2: B}), _truths(15, {1: A}), _truths(10, {1: A, 2: B})]
    again = situations([t for part in apart for t in part], _masks(35, {}), [("box-1", "box-2")])
    assert again.touching == 2  # out of view for 15 frames: it came round again
