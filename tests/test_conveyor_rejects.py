"""Rejects: rules over track measures, the diverter's timing, and the whole chain over a pty
(tracks → rule → belt position by the encoder → diverter write → the emulated diverter)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tofcut.driver.belt import BeltGeometry, BeltReading
from tofcut.driver.conveyor.reject_rule import MAX_NESTING, RejectRule, hull_area, measure_track
from tofcut.driver.conveyor.rejects import CANDIDATES_KEPT, RejectScheduler
from tofcut.driver.errors import ConfigError
from tofcut.tracker.tracks import Track

WAIT_S = 5.0
# A camera looking down at the belt at a slant, the belt running slightly askew in the image.
BELT = BeltGeometry.from_plane(
    np.array([1.0, 0.05, 0.0]), np.array([0.1, -0.5, -0.85]), np.array([0.0, 0.0, 1.3])
)


def box_track(
    track_id: int,
    along: float,
    size: tuple[float, float, float],
    *,
    across: float = 0.0,
    yaw_deg: float = 0.0,
    seed: int = 0,
    n: int = 600,
    noise_m: float = 0.002,
) -> Track:
    """What a tracker would report for a box on the belt: points on its top and on the side
    facing the camera, with noise, in camera coordinates."""
    rng = np.random.default_rng(seed)
    length, width, height = size
    top = rng.uniform(-0.5, 0.5, (n, 2)) * [length, width]
    side = np.column_stack([rng.uniform(-0.5, 0.5, n // 2) * length, np.full(n // 2, -width / 2)])
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    xy = np.vstack([top, side]) @ np.array([[c, s], [-s, c]]) + [along, across]
    z = np.r_[np.full(n, height), rng.uniform(0.0, height, n // 2)]
    side_dir = np.cross(BELT.normal, BELT.direction)
    points = (
        BELT.origin + xy[:, :1] * BELT.direction + xy[:, 1:] * side_dir + z[:, None] * BELT.normal
    )
    points += rng.normal(0.0, noise_m, points.shape)
    return Track(
        id=track_id,
        centroid=points.mean(axis=0),
        velocity=np.zeros(3),
        box_min=points.min(axis=0),
        box_max=points.max(axis=0),
        bbox=(0, 0, 1, 1),
        pixels=len(points),
        points=points.astype(np.float32),
    )


# --- rules and measures -----------------------------------------------------------------


def test_measures_of_a_box_on_the_belt():
    m = measure_track(box_track(1, 0.2, (0.3, 0.2, 0.1), across=0.05, noise_m=0.0, n=4000), BELT)
    assert m.height == pytest.approx(0.1, abs=1e-6)
    # Extents leave out 2 % of the points at each end: 96 % of a uniformly seen box.
    assert m.length == pytest.approx(0.96 * 0.3, abs=0.003)
    # Across, the side's 2000 points sit at one edge; the far edge loses 120 of the top's 4000.
    assert m.width == pytest.approx(0.2 * (1 - 120 / 4000), abs=0.003)
    assert m.footprint == pytest.approx(m.length * m.width, rel=0.02)  # the box's rectangle
    assert m.volume == pytest.approx(m.footprint * 0.1)
    assert m.along == pytest.approx(0.2, abs=0.002)
    assert m.pixels == 6000
    square = measure_track(box_track(2, 0.2, (0.2, 0.2, 0.1), noise_m=0.0, n=4000), BELT)
    turned = measure_track(
        box_track(3, 0.2, (0.2, 0.2, 0.1), yaw_deg=45, noise_m=0.0, n=4000), BELT
    )
    assert turned.footprint == pytest.approx(square.footprint, rel=0.05)  # a hull, not a box
    assert turned.length > 1.2 * square.length  # corner to corner along the belt now


def test_a_hidden_track_has_no_measures():
    hidden = Track(7, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), (0, 0, 0, 0), 0,
                   np.zeros((0, 3), np.float32), hidden_frames=2)  # fmt: skip
    assert measure_track(hidden, BELT) is None


def test_hull_area():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5], [0.2, 0.9]], float)
    assert hull_area(square[:, 0], square[:, 1]) == pytest.approx(1.0)
    assert hull_area(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 2.0])) == 0.0


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("height > 0.08", True),
        ("height > 0.12", False),
        ("volume > 0.001", True),
        ("footprint >= 0.07", False),
        ("0.05 < length <= 0.31 and not (width < 0.1 or pixels < 10)", True),
        ("height < 0.05 or width > 0.15", True),
        ("not height > -1e-3", False),
    ],
)
def test_rules_over_measures(text, expected):
    m = measure_track(box_track(1, 0.0, (0.3, 0.2, 0.1), noise_m=0.0), BELT)
    assert RejectRule.parse(text)(m) is expected


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("heigth > 1", "unknown measure 'heigth'"),
        ("height >", "ends too early"),
        ("height", "needs a comparison"),
        ("(height > 1", "ends too early"),
        ("height > 1 )", "unexpected ')'"),
        ("__import__('os') > 1", "unexpected"),
        ("height > 1e999", "not a finite number"),
    ],
)
def test_bad_rules_are_refused_clearly(text, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        RejectRule.parse(text)


@pytest.mark.parametrize(
    "text",
    ["(" * 10_000 + "height > 1" + ")" * 10_000, "not " * 10_000 + "height > 1"],
    ids=["parentheses", "nots"],
)
def test_deep_nesting_is_a_one_line_error_not_a_recursion_error(text):
    with pytest.raises(ConfigError, match=f"more than {MAX_NESTING} deep") as info:
        RejectRule.parse(text)
    assert "\n" not in str(info.value)
    assert len(str(info.value)) < 200  # the rule is shortened in the message


def test_nesting_up_to_the_bound_is_fine():
    m = measure_track(box_track(1, 0.0, (0.3, 0.2, 0.1), noise_m=0.0), BELT)
    half = MAX_NESTING // 2
    text = "not " * half + "(" * half + "height > 0.08" + ")" * half
    assert RejectRule.parse(text)(m) is True  # an even number of nots


# --- the scheduler, on a belt given as a function ---------------------------------------


class Belt:
    """A belt moving at `speed` since host time 0."""

    def __init__(self, speed: float) -> None:
        self.speed = speed

    def at(self, time_ns: int) -> BeltReading:
        d = self.speed * time_ns * 1e-9
        return BeltReading(time_ns, round(d * 1e4), d, self.speed, True, False)


def run_line(scheduler, objects, belt, *, until_m, frame_ms=20, poll_ms=5, view=(-0.35, 0.35)):
    """Frames every `frame_ms` of the objects in view, belt readings every `poll_ms`."""
    fired = []
    t_ns = 0
    while belt.at(t_ns).distance_m < until_m:
        reading = belt.at(t_ns)
        fired += scheduler.on_reading(reading)
        if t_ns % (frame_ms * 10**6) == 0:
            tracks = [
                box_track(i, s0 + reading.distance_m, size, seed=t_ns + i)
                for i, (s0, size) in objects.items()
                if view[0] < s0 + reading.distance_m < view[1]
            ]
            scheduler.observe(tracks, t_ns)
        t_ns += poll_ms * 10**6
    return fired


def test_the_scheduler_fires_matching_objects_once_when_they_reach_the_diverter():
    objects = {  # id: (position along the belt at travel 0, size)
        1: (-0.10, (0.08, 0.08, 0.05)),
        2: (-0.25, (0.08, 0.08, 0.12)),
        3: (-0.40, (0.08, 0.08, 0.07)),
        4: (-0.55, (0.08, 0.08, 0.10)),
    }
    belt = Belt(0.4)
    sent = []
    rule = RejectRule.parse("height > 0.08")
    scheduler = RejectScheduler(rule, BELT, 0.6, belt.at, sent.append)
    fired = run_line(scheduler, objects, belt, until_m=1.3)
    assert [e.track_id for e in fired] == [2, 4] == [e.track_id for e in sent]
    step = belt.speed * 5e-3  # the belt's travel between readings
    for e in fired:
        s0 = objects[e.track_id][0]
        assert e.target_m == pytest.approx(0.6 - s0, abs=0.002)  # estimated from noisy points
        assert e.target_m <= e.distance_m < e.target_m + step + 1e-9
    assert scheduler.stats.fired == 2
    assert scheduler.stats.passed == 2


def test_a_long_run_keeps_the_newest_rejects_and_counts_them_all(monkeypatch):
    monkeypatch.setattr("tofcut.driver.conveyor.rejects.EVENTS_KEPT", 2)
    objects = {i: (-0.1 - 0.15 * i, (0.08, 0.08, 0.12)) for i in range(1, 5)}
    scheduler = RejectScheduler(
        RejectRule.parse("height > 0.08"), BELT, 0.6, Belt(0.4).at, lambda e: None
    )
    fired = run_line(scheduler, objects, Belt(0.4), until_m=1.5)
    assert [e.track_id for e in fired] == [1, 2, 3, 4]
    assert [e.track_id for e in scheduler.events] == [3, 4]
    assert scheduler.stats.fired == 4


def test_objects_that_never_reach_the_diverter_are_bounded_and_keep_no_point_cloud():
    """A stuck encoder: the belt never moves, so no object reaches the diverter."""
    scheduler = RejectScheduler(
        RejectRule.parse("height > 0.08"), BELT, 0.6, Belt(0.0).at, lambda e: None
    )
    n = CANDIDATES_KEPT + 300
    for i in range(1, n + 1):
        scheduler.observe([box_track(i, 0.0, (0.08, 0.08, 0.12), n=20)], i * 10**6)
        scheduler.on_reading(Belt(0.0).at(i * 10**6))
    candidates = scheduler._candidates
    assert len(candidates) == CANDIDATES_KEPT
    assert min(candidates) == n - CANDIDATES_KEPT + 1  # the newest are kept
    assert scheduler.stats.forgotten == 300
    assert all(len(c.best.track.points) == 0 for c in candidates.values())
    assert scheduler.stats.fired == 0


def test_a_python_callable_as_the_rule_and_the_majority_of_views_decides():
    belt = Belt(0.4)
    flicker = {"n": 0}

    def rule(m):  # object 1 matches in one frame out of three; object 2 in all
        flicker["n"] += 1
        return m.track_id == 2 or flicker["n"] % 3 == 0

    scheduler = RejectScheduler(RejectRule.from_callable(rule), BELT, 0.5, belt.at, lambda e: None)
    objects = {1: (-0.1, (0.1, 0.1, 0.1)), 2: (-0.3, (0.1, 0.1, 0.1))}
    fired = run_line(scheduler, objects, belt, until_m=1.0)
    assert [e.track_id for e in fired] == [2]
    assert scheduler.rule.text == "rule"


def test_frames_the_belt_cannot_place_are_counted_not_guessed():
    scheduler = RejectScheduler(
        RejectRule.parse("height > 0"), BELT, 0.5, lambda t: None, lambda e: None
    )
    scheduler.observe([box_track(1, 0.0, (0.1, 0.1, 0.1))], 123)
    assert scheduler.stats.unplaced == 1
    assert scheduler.stats.views == 0


# --- the whole chain over a pseudo-terminal ---------------------------------------------


def test_rejects_hit_exactly_the_matching_objects_at_the_right_encoder_count(
    tofcut_conveyor_factory,
):
    """Tracks of six boxes ride the emulated belt past the camera; the rule picks the tall
    ones; the project's client reads the encoder over a pty and writes the diverter; the
    emulated diverter records the encoder count each command came at.

    The belt moves in 10 mm steps (the test's clock); each command must come at the first
    step at or past the count at which the object's centre is at the diverter, give or take
    3 mm for the position estimated from noisy points: count − expected ∈ [−30, 130]."""
    step_m, speed, diverter_m = 0.01, 0.5, 0.45
    objects = {  # id: (position along the belt at travel 0, (length, width, height))
        1: (-0.1045, (0.07, 0.07, 0.05)),  # off the 10 mm grid: targets fall between steps
        2: (-0.2045, (0.08, 0.06, 0.12)),
        3: (-0.3045, (0.06, 0.08, 0.06)),
        4: (-0.4045, (0.08, 0.08, 0.10)),
        5: (-0.5045, (0.07, 0.06, 0.09)),
        6: (-0.6045, (0.06, 0.07, 0.04)),
    }
    tall = {i for i, (_, size) in objects.items() if size[2] > 0.08}
    now = [0.0]
    line = tofcut_conveyor_factory(speed, clock=lambda: now[0], start_count=1000)
    conveyor = line.controller
    with line.connect(timeout_s=0.1, poll_hz=200.0, heartbeat_s=0.0) as client:
        scheduler = RejectScheduler(
            RejectRule.parse("height > 0.08"), BELT, diverter_m, client.reading_at,
            lambda e: client.divert(e.track_id),
        )  # fmt: skip
        client.add_listener(scheduler.on_reading)
        for k in range(round((diverter_m + 0.62) / step_m)):
            now[0] = k * step_m / speed
            count = conveyor.count()
            reading = client.wait_for(lambda r, c=count: r.count == c, WAIT_S)
            assert reading is not None
            travel = reading.distance_m
            tracks = [
                box_track(i, s0 + travel, size, seed=k * 10 + i)
                for i, (s0, size) in objects.items()
                if -0.35 < s0 + travel < 0.35
            ]
            scheduler.observe(tracks, reading.time_ns)
            # Let the link send what this reading fired before the belt moves on.
            fired = scheduler.stats.fired
            client.wait_stats(lambda s, f=fired: s.diverter_writes >= f, WAIT_S)
        stats = client.stats
    assert {e.track_id for e in scheduler.events} == tall
    assert scheduler.stats.passed == len(objects) - len(tall)
    commands = conveyor.diverter_commands
    assert len(commands) == len(tall) == stats.diverter_writes
    expected = sorted(conveyor.count_at_distance(diverter_m - objects[i][0]) for i in tall)
    counts = sorted(c.count for c in commands)
    errors = [c - e for c, e in zip(counts, expected, strict=True)]
    print("diverter count − expected count:", errors)
    assert all(-30 <= err <= 130 for err in errors), errors
    assert all(c.value == 1 for c in commands)
