"""The roster's rules on synthetic masks and clouds: when a track holds two objects
(`tofcut.tracker.roster._two_objects`), lies beside the belt or flat on it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tofcut.driver.belt import BeltGeometry
from tofcut.driver.frames import Frame
from tofcut.driver.intrinsics import Intrinsics
from tofcut.tracker.background import BackgroundModel
from tofcut.tracker.live_track import LiveTrack
from tofcut.tracker.params import TrackerParams
from tofcut.tracker.roster import Roster, _beside, _two_objects, still_time
from tofcut.tracker.tracker import Tracker

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


# --- what lies beside the belt, and what lies flat on it ------------------------------------

BELT_RANGE_M = 2.0


def _belt(width_m: float | None) -> BeltGeometry:
    """A belt 2 m in front of the camera, facing it, running along x; across it is -y."""
    return BeltGeometry(
        np.array([0.0, 0.0, BELT_RANGE_M]), np.array([1.0, 0.0, 0.0]),
        np.array([0.0, 0.0, -1.0]), width_m,
    )  # fmt: skip


def _block(y0: float, y1: float, height_m: float, n: int = 400) -> np.ndarray:
    """Points of a block's top and sides: x in [-0.1, 0.1], y in [y0, y1], from the belt up
    to `height_m` (a flat patch of belt when 0)."""
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-0.1, 0.1, n), rng.uniform(y0, y1, n)
    h = np.where(np.arange(n) % 2 == 0, height_m, rng.uniform(0.0, height_m, n))
    return np.column_stack([x, y, BELT_RANGE_M - h])


def _roster_with(*clouds: np.ndarray) -> tuple[Roster, np.ndarray]:
    """A roster holding one track per cloud (ids 1, 2, ...), each seen this frame at its
    cloud's points and on a row of the labels."""
    roster = Tracker(TrackerParams()).roster
    labels = np.zeros((len(clouds), 4), np.uint16)
    for k, cloud in enumerate(clouds):
        tid = roster._start(cloud, np.eye(3) * 0.01)
        track = roster.tracks[-1]
        track.last = track.report(cloud, (slice(k, k + 1), slice(0, 4)))
        labels[k] = tid
    return roster, labels


def test_a_track_beside_a_belt_of_known_width_is_ended_and_those_on_it_kept():
    over = _block(-0.1, 0.1, 0.1)
    edge = _block(0.15, 0.35, 0.1)  # half of it over the belt's edge at 0.25
    beside = _block(0.4, 0.6, 0.1)  # past the edge: a guide, the floor, a far wall
    roster, labels = _roster_with(over, edge, beside)
    assert roster.off_belt(labels, _belt(None)) == []  # no width: nothing is beside it
    assert roster.off_belt(labels, _belt(0.5)) == [3]
    assert [t.id for t in roster.tracks] == [1, 2]
    assert not labels[2].any()
    assert labels[:2].all()
    assert _beside(beside, _belt(0.5))
    assert not _beside(edge, _belt(0.5))


def test_tracks_flat_on_the_belt_are_ended_and_low_objects_kept():
    belt = _belt(0.5)
    flat = _block(-0.2, 0.2, 0.0) + np.random.default_rng(4).normal(0.0, 0.005, (400, 3))
    low = _block(-0.1, 0.1, 0.04)  # the lowest box the family draws
    roster, labels = _roster_with(flat, low)
    assert roster.flat_on(labels, belt, min_height_m=0.02) == [1]
    assert [t.id for t in roster.tracks] == [2]
    assert not labels[0].any()
    assert labels[1].all()


@pytest.mark.parametrize("unseen", ["never reported", "coasting"])
def test_a_track_not_seen_this_frame_is_left_to_coast(unseen):
    roster, labels = _roster_with(_block(0.4, 0.6, 0.0))  # beside the belt, and flat
    track = roster.tracks[0]
    # coasting: what `LiveTrack.coast` reports, its predicted place and no points
    track.last = (
        None
        if unseen == "never reported"
        else dataclasses.replace(track.last, pixels=0, points=np.zeros((0, 3), np.float32))
    )
    assert roster.off_belt(labels, _belt(0.5)) == []
    assert roster.flat_on(labels, _belt(0.5), min_height_m=0.02) == []


@pytest.mark.parametrize("entering", [True, False])
def test_a_track_coming_into_view_is_not_seen_carried_by_its_growing_view(entering):
    # an object coming into view at the image's border: its centroid moves 0.3 m/s as more of
    # it shows, then it stands whole in view. Only where it was first seen whole counts (a
    # crawling belt is not seen to run by the views of a box coming into view)
    p = TrackerParams()
    dt, home = 0.02, np.array([0.0, 0.0, 1.0])
    box = (slice(0, 10), slice(0, 10))
    square = np.stack(np.meshgrid(np.linspace(0, 0.1, 10), np.linspace(0, 0.1, 10)), -1)
    view = np.concatenate([square.reshape(-1, 2), np.zeros((100, 1))], axis=1)
    track = LiveTrack(1, home[None, :] + view, np.eye(3), p)
    for k in range(1, 61):
        track.predict(dt, None)
        track.see(home + view + [0.3 * dt * min(k, 50), 0.0, 0.0], box, entering and k <= 50, None)
    assert (track.pace(p.still_s, p.gate_m) > 0) == (not entering)


def _seen_at(track, point, measured: bool = True) -> None:
    """The track measured (or not) at `point` this frame."""
    track.filter.x[:3] = point
    track.measured = measured


def test_what_stays_put_is_judged_on_the_frames_it_is_seen_and_forgives_a_moment_away():
    p = TrackerParams()
    dt, home = 0.02, np.array([0.2, 0.2, 1.0])
    steps = round(p.still_s / dt) + 2
    # a rail's ghost: seen in place, one frame in four not measured (its view changed size),
    # and for 0.2 s dragged aside by a box passing beside it: still part of the machine
    rail = LiveTrack(1, home[None, :], np.eye(3), p)
    verdicts = []
    for k in range(round(steps * 1.5)):
        away = 40 <= k < 50
        _seen_at(rail, home + (0.3 if away else 0.0), measured=k % 4 != 3)
        verdicts.append(rail.stays_put(dt, p.still_s))
    assert any(verdicts)
    # and nothing stays put while the belt stands
    still = LiveTrack(3, home[None, :], np.eye(3), p)
    for _ in range(steps * 2):
        _seen_at(still, home)
        assert not still.stays_put(dt, None)


@pytest.mark.parametrize("speed", [0.05, 0.1, 0.3])
def test_what_the_belt_carries_never_stays_put_and_what_stands_does_at_any_pace(speed):
    # staying put is judged over as long as the belt takes to carry a box 2 gate_m: a box
    # carried past at the belt's pace never stays put, a rail's ghost does, on a belt at
    # 0.05 m/s (3.2 s) as at 0.3 m/s (still_s)
    p = TrackerParams()
    dt, home = 0.02, np.array([0.2, 0.2, 1.0])
    hold_s = still_time(speed, p.still_s, p.gate_m)
    assert hold_s == pytest.approx(max(p.still_s, 2 * p.gate_m / speed))
    box = LiveTrack(1, home[None, :], np.eye(3), p)
    rail = LiveTrack(2, home[None, :], np.eye(3), p)
    stayed = []
    for k in range(round(3 * hold_s / dt)):
        _seen_at(box, home + np.array([speed * dt * k, 0.0, 0.0]))
        assert not box.stays_put(dt, hold_s), k
        _seen_at(rail, home)
        stayed.append(rail.stays_put(dt, hold_s))
    assert stayed.index(True) == pytest.approx(hold_s / dt, abs=2)


def test_a_belt_too_slow_or_standing_is_not_judged_on():
    p = TrackerParams()
    assert still_time(0.0, p.still_s, p.gate_m) is None
    assert still_time(0.03, p.still_s, p.gate_m) is None  # 0.12 m in 2 still_s < 2 gate_m
    assert still_time(0.05, p.still_s, p.gate_m) == pytest.approx(3.2)


@pytest.mark.parametrize(
    ("speed", "seconds", "carried"),
    [(0.3, 1.2, True), (0.06, 6.0, True), (0.3, 0.6, False), (0.0, 6.0, False)],
)
def test_a_track_is_seen_carried_at_its_pace(speed, seconds, carried):
    # the belt is seen to run, before its speed is known, by a track carried 2 gate_m,
    # followed for still_s / 2 at least, at the pace it was carried: not by one only just
    # seen, nor one standing
    p = TrackerParams()
    dt, home = 0.02, np.array([0.0, 0.0, 1.0])
    track = LiveTrack(1, home[None, :], np.eye(3), p)
    for k in range(1, round(seconds / dt) + 1):
        track.predict(dt, None)
        _seen_at(track, home + np.array([speed * dt * k, 0.0, 0.0]))
    pace = track.pace(p.still_s, p.gate_m)
    assert (pace > 0) == carried
    if carried:
        assert pace == pytest.approx(speed, rel=0.05)


@pytest.mark.parametrize("growing", [True, False])
def test_a_view_growing_at_the_border_of_a_slow_belt_does_not_stay_put(growing):
    # a box coming into view at the image's border on a belt at 0.06 m/s: its view grows,
    # and its centroid (what shows of it) creeps at a third of the belt's pace, within gate_m
    # of one place for longer than staying put is judged over; it is coming into view, not
    # part of the machine. A rail's ghost at the border, its view steady, stays put.
    p = TrackerParams()
    dt, home, speed = 0.02, np.array([0.0, 0.0, 1.0]), 0.06
    hold_s = still_time(speed, p.still_s, p.gate_m)
    assert hold_s is not None
    track = LiveTrack(1, home[None, :], np.eye(3), p)
    stayed = []
    for k in range(round(2 * hold_s / dt)):
        shown = 0.05 + (speed * dt * k if growing else 0.0)  # metres of it in view
        xs = np.linspace(0.0, shown, max(2, round(shown * 200)))
        points = np.stack([xs, np.zeros_like(xs), np.ones_like(xs)], axis=1)
        points[:, 0] += home[0] - xs.mean() + speed / 3 * dt * k * growing
        track.predict(dt, None)
        track.see(points, (slice(0, 5), slice(0, len(xs))), True, None)
        stayed.append(track.stays_put(dt, hold_s))
    assert any(stayed) == (not growing)


# --- a track that holds two objects apart ----------------------------------------------------


def _view(tops: list[tuple[int, float]], between_m: float = BELT_RANGE_M) -> Frame:
    """A 20×40 view of the belt straight below (2 cm a pixel), with 10×10 tops standing up
    from it (first column, height), and the range `between_m` over columns 15–17."""
    depth = np.full((20, 40), BELT_RANGE_M)
    depth[:, 15:18] = between_m
    for col, height in tops:
        depth[5:15, col : col + 10] = BELT_RANGE_M - height
    return Frame.from_arrays(time_s=0.0, depth_m=depth, intrinsics=_LENS)


_LENS = Intrinsics(width=40, height=20, fx=100.0, fy=100.0, cx=19.5, cy=9.5)


def _scenery(between_m: float = BELT_RANGE_M) -> BackgroundModel:
    """The empty view of `_view`, learned."""
    model = BackgroundModel((20, 40))
    empty, noise = _view([], between_m), np.full((20, 40), 0.005)
    while not model.learn(empty, noise, np.zeros((0, 3)), 0.15):
        pass
    return model


def _one_track_on(frame: Frame, mask: np.ndarray) -> tuple[Roster, np.ndarray]:
    """A roster whose one track (id 1) holds `mask`, and the labels."""
    roster = Tracker(TrackerParams()).roster
    roster._start(frame.xyz[mask], np.eye(3) * 0.01)
    return roster, mask.astype(np.uint16)


@pytest.mark.parametrize(
    ("between_m", "scenery_m", "parted"),
    [
        (BELT_RANGE_M, BELT_RANGE_M, True),  # the belt seen between them: two objects apart
        (1.5, BELT_RANGE_M, False),  # something in front: an occluder
        (1.5, 1.5, False),  # a gantry: scenery, but in front
        (BELT_RANGE_M - 0.2, BELT_RANGE_M, False),  # the first top goes on: the cut missed it
    ],
)
def test_a_track_holding_two_objects_with_the_belt_between_is_parted(between_m, scenery_m, parted):
    # two boxes 6 cm apart, both in one track's mask (the cut gave it the second as it came
    # into view); the range `between_m` read between them, where the scenery is `scenery_m`
    frame = _view([(5, 0.2), (18, 0.1)], between_m)
    left, right = np.zeros((20, 40), bool), np.zeros((20, 40), bool)
    left[5:15, 5:15], right[5:15, 18:28] = True, True
    roster, labels = _one_track_on(frame, left | right)
    split_frames = roster.params.split_frames
    bg = _scenery(scenery_m)
    seen, noise = bg.seen_range(frame), np.full((20, 40), 0.005)
    born = [roster._part(frame, labels, noise, _belt(None), bg, seen) for _ in range(split_frames)]
    assert born[:-1] == [[]] * (split_frames - 1)  # not before it held both that long
    if parted:
        assert born[-1] == [2]
        assert (labels[left] == 1).all()
        assert (labels[right] == 2).all()
        new = roster.tracks[1]
        assert np.allclose(new.filter.position, frame.xyz[right].mean(axis=0))
        assert np.allclose(roster.tracks[0].filter.position, frame.xyz[left].mean(axis=0))
    else:
        assert born[-1] == []
        assert len(roster.tracks) == 1
        assert (labels[left | right] == 1).all()


def test_a_small_part_of_a_mask_is_not_an_object_of_its_own():
    frame = _view([(5, 0.2), (18, 0.1)])
    mask = np.zeros((20, 40), bool)
    mask[5:15, 5:15] = True
    mask[8:12, 18:22] = True  # 16 pixels: fewer than `min_pixels`
    roster, labels = _one_track_on(frame, mask)
    bg = _scenery()
    seen, noise = bg.seen_range(frame), np.full((20, 40), 0.005)
    assert not any(roster._part(frame, labels, noise, _belt(None), bg, seen) for _ in range(5))


def test_a_part_another_track_follows_goes_to_that_track():
    # the cut gave the second box to the first box's track, though a track follows it
    frame = _view([(5, 0.2), (18, 0.1)])
    left, right = np.zeros((20, 40), bool), np.zeros((20, 40), bool)
    left[5:15, 5:15], right[5:15, 18:28] = True, True
    roster, labels = _one_track_on(frame, left | right)
    roster._start(frame.xyz[right], np.eye(3) * 0.01)  # track 2, left nothing this frame
    bg = _scenery()
    seen, noise = bg.seen_range(frame), np.full((20, 40), 0.005)
    for _ in range(roster.params.split_frames):
        born = roster._part(frame, labels, noise, _belt(None), bg, seen)
    assert born == []
    assert [t.id for t in roster.tracks] == [1, 2]
    assert (labels[left] == 1).all()
    assert (labels[right] == 2).all()


# --- a small object's top in a big track's mask ----------------------------------------------


def _pressed(low: np.ndarray) -> tuple[Frame, np.ndarray, np.ndarray]:
    """A 20×40 view of a 20×22-pixel box 20 cm tall, pressed against a 10×10-pixel surface
    whose height `low` gives column by column: the box's mask and the surface's."""
    depth = np.full((20, 40), BELT_RANGE_M)
    box, other = np.zeros((20, 40), bool), np.zeros((20, 40), bool)
    box[:, 2:24], other[5:15, 24:34] = True, True
    depth[box] = BELT_RANGE_M - 0.2
    depth[5:15, 24:34] = BELT_RANGE_M - low
    return Frame.from_arrays(time_s=0.0, depth_m=depth, intrinsics=_LENS), box, other


@pytest.mark.parametrize(
    ("low", "dealt"),
    [
        (np.full(10, 0.08), True),  # a low box's top: it faces up, at its own height
        (np.linspace(0.17, 0.03, 10), False),  # a face falling away: it does not face up
        (np.r_[0.1, np.full(9, 0.2)], False),  # the box's own top beyond a rim: one height
    ],
)
def test_a_small_top_pressed_against_a_big_box_in_its_track_is_dealt_out(low, dealt):
    # 100 pixels of 540 (90 once a step's seam is cut): under `split_share` and `split_pixels`
    frame, box, other = _pressed(low)
    roster, labels = _one_track_on(frame, box | other)
    noise = np.full((20, 40), 0.005)
    born = [roster._reconcile(frame, labels, noise, _belt(None)) for _ in range(3)]
    assert born[:2] == [[], []]  # not before it held both `split_frames` frames
    if dealt:
        assert born[2] == [2]
        assert (labels[box] == 1).all()
        # all of the low top but the seam its step leaves, which stays where the cut put it
        assert (labels[5:15, 25:34] == 2).all()
    else:
        assert born[2] == []
        assert (labels[box | other] == 1).all()


def test_a_small_top_two_tracks_share_goes_whole_to_the_one_holding_most():
    frame, box, other = _pressed(np.full(10, 0.08))
    roster, labels = _one_track_on(frame, box | other)
    roster._start(frame.xyz[other], np.eye(3) * 0.01)
    labels[5:15, 29:34] = 2  # track 2 holds most of the low top, track 1 the rest
    noise = np.full((20, 40), 0.005)
    assert all(roster._reconcile(frame, labels, noise, _belt(None)) == [] for _ in range(3))
    assert (labels[box] == 1).all()
    assert (labels[5:15, 25:34] == 2).all()
