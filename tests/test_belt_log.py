"""The conveyor log beside a capture: `tofcut record` writes what the link said, `tofcut
track` replays it into the same velocity priors the live run had; damaged lines are skipped
and counted, never trusted."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tofcut.driver.belt import BeltReading, KnownBelt
from tofcut.driver.capture import CaptureReader
from tofcut.driver.conveyor.belt_log import (
    PENDING_KEPT,
    BeltLogError,
    BeltLogReader,
    BeltLogWriter,
    LoggedBelt,
    LogHeader,
    ReplayedLink,
    belt_log_path,
    parse_line,
)
from tofcut.tools.cli import main
from tofcut.tools.commands import record, tracking
from tofcut.tools.pipeline.sources import open_source
from tofcut.tracker.tracker import Tracker

WAIT_S = 5.0
SPEEDS = {0: 0.25, 12: 0.4, 24: 0.1}
"""The emulated controller's belt speed from each frame on (the frame's index)."""
FRAMES = 36
MS = 1_000_000


def reading(t_ns: int, speed: float = 0.25, **changes) -> dict:
    doc = {"kind": "reading", "time_ns": t_ns, "count": t_ns // 400_000 % 2**32,
           "distance_m": speed * t_ns * 1e-9, "speed_mps": speed, "running": True,
           "fault": False}  # fmt: skip
    doc.update(changes)
    return doc


def header(offset: int | None = 1000) -> dict:
    return {"kind": "log", "version": 1, "port": "/dev/pts/9", "exposure_offset_ns": offset,
            "max_extrapolation_s": 0.5}  # fmt: skip


def write_lines(path, docs) -> None:
    path.write_text("".join((d if isinstance(d, str) else json.dumps(d)) + "\n" for d in docs))


@pytest.fixture
def spy(monkeypatch):
    """(sequence, prior) of every frame the tracker of `tofcut track` is given."""
    seen: list[tuple[int, object]] = []

    class SpyTracker(Tracker):
        def update(self, frame, prior=None):
            seen.append((frame.sequence, prior))
            return super().update(frame, prior)

    monkeypatch.setattr(tracking, "Tracker", SpyTracker)
    return seen


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A recording of the emulated conveyor with the emulated controller, its belt changing
    speed twice, and the velocity prior a live run would have given each frame: the link's
    own answer for the frame's exposure, asked once the link has read past it."""
    mp = pytest.MonkeyPatch()
    path = tmp_path_factory.mktemp("rec") / "run.tofcap"
    lines, live = [], {}

    def opening(spec, **kw):
        opened = open_source(spec, **kw)
        original = opened.device.raw_frames

        def raw_frames(*a, **k):
            for i, raw in enumerate(original(*a, **k)):
                (line,) = lines
                if i in SPEEDS:
                    line.emulated.set_speed(SPEEDS[i])
                t = line.frame_time_ns(raw)
                speed = SPEEDS[max(j for j in SPEEDS if j <= i)]
                assert line.client.wait_for(
                    lambda r, t=t, v=speed: r.time_ns > t and r.speed_mps == pytest.approx(v),
                    WAIT_S,
                )
                live[raw.sequence] = line.velocity_prior(raw)
                yield raw

        opened.device.raw_frames = raw_frames
        return opened

    def linking(*a, **k):
        lines.append(open_conveyor(*a, **k))
        return lines[-1]

    open_conveyor = record.open_conveyor
    mp.setattr(record, "open_source", opening)
    mp.setattr(record, "open_conveyor", linking)
    try:
        # in real time: a frame is exposed before it arrives, as from a real camera (on the
        # virtual clock of --fast, frames are stamped at the frame rate, whatever the time)
        code = main(["record", "emulator:conveyor", "-o", str(path), "--frames", str(FRAMES),
                     "--fps", "25", "--conveyor-emulator"])  # fmt: skip
    finally:
        mp.undo()
    assert code == 0
    return path, live


def test_record_logs_the_encoder_and_the_belt_beside_the_capture(recorded, capsys):
    path, _ = recorded
    log = belt_log_path(path)
    assert log.name == "run.conveyor.jsonl"
    docs = [json.loads(x) for x in log.read_text().splitlines()]
    first, readings = docs[0], docs[1:]
    assert first["kind"] == "log"
    assert first["version"] == 1
    assert first["port"].startswith("/dev/pts/")
    assert isinstance(first["exposure_offset_ns"], int)  # the emulated camera's clock: fixed
    assert first["max_extrapolation_s"] == 0.5
    assert readings
    assert {d["kind"] for d in readings} == {"reading"}
    assert set(readings[0]) == {"kind", "time_ns", "count", "distance_m", "speed_mps",
                                "running", "fault"}  # fmt: skip
    times = [d["time_ns"] for d in readings]
    assert times == sorted(times)
    assert {round(d["speed_mps"], 3) for d in readings} == {0.25, 0.4, 0.1}
    meta = CaptureReader(path).capture.metadata
    assert meta["belt_source"] == "scene"
    assert KnownBelt.from_dict(meta["belt"], "capture").speed_mps == 0.25


def test_replaying_the_capture_gives_the_tracker_the_live_runs_priors(recorded, spy, capsys):
    path, live = recorded
    assert main(["track", str(path), "--save", str(path.with_suffix(".rrd"))]) == 0
    out = capsys.readouterr().out
    assert len(spy) == FRAMES == len(live)
    speeds = set()
    for sequence, prior in spy:
        expected = live[sequence]
        assert prior.informed == expected.informed, sequence
        np.testing.assert_allclose(prior.mean, expected.mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(prior.cov, expected.cov, rtol=0, atol=1e-15)
        if prior.informed:
            speeds.add(round(float(prior.mean[0]), 6))
    assert speeds == {0.25, 0.4, 0.1}  # the encoder's, not the metadata's nominal speed
    assert (
        "belt: from the capture's metadata (recorded from the scene); speed 0.250 m/s; "
        "velocity prior from the encoder readings in the capture's conveyor log\n"
    ) in out
    used = next(x for x in out.splitlines() if x.startswith("conveyor log run.conveyor.jsonl"))
    assert "damaged" not in used


def test_without_its_log_a_capture_replays_with_the_known_speed(recorded, tmp_path, spy, capsys):
    path, _ = recorded
    alone = tmp_path / "alone.tofcap"
    alone.write_bytes(path.read_bytes())
    assert main(["track", str(alone), "--frames", "3", "--save", str(tmp_path / "r.rrd")]) == 0
    for _, prior in spy:
        np.testing.assert_allclose(prior.mean, [0.25, 0.0, 0.0], atol=1e-12)
        assert prior.cov[0, 0] == prior.cov[1, 1]  # the nominal speed's isotropic prior
    out = capsys.readouterr().out
    assert "speed 0.250 m/s; velocity prior from its speed\n" in out
    assert "conveyor log" not in out


def test_damaged_log_lines_are_skipped_and_counted(recorded, tmp_path, spy, capsys):
    path, live = recorded
    copy = tmp_path / "run.tofcap"
    copy.write_bytes(path.read_bytes())
    lines = belt_log_path(path).read_text().splitlines()
    t = json.loads(lines[5])["time_ns"]
    damage = [
        "this is not JSON",
        "[1, 2, 3]",
        '{"kind": "reading", "time_ns": 1, "count": 0, "distance_m": 0.0, "speed_mps": NaN, '
        '"running": true, "fault": false}',
        json.dumps(reading(t, speed=1e9)),
        json.dumps(reading(t, speed=float("inf")), allow_nan=True),
        json.dumps(reading(t, count=-1)),
        json.dumps(reading(t, running="yes")),
        json.dumps(reading(t, time_ns=True)),
        json.dumps(reading(t - 10**9)),  # earlier than the one before it
        json.dumps({"kind": "diverter", "time_ns": t}),
        json.dumps({"kind": "belt", "time_ns": t, "source": "found",
                    "belt": {"point": [0, 0, 1], "direction": [0, 0, 0], "normal": [0, 0, 1]}}),
    ]  # fmt: skip
    cut = lines[-1][: len(lines[-1]) // 2]  # the recorder killed mid-line
    write_lines(belt_log_path(copy), [*lines[:6], *damage, *lines[6:-1], cut])
    assert main(["track", str(copy), "--save", str(tmp_path / "r.rrd")]) == 0
    out = capsys.readouterr().out
    summary = next(x for x in out.splitlines() if x.startswith("conveyor log "))
    assert f"{len(damage) + 1} damaged lines skipped (first: line 7: not a JSON line)" in summary
    for sequence, prior in spy:  # the damage changed no prior
        assert prior.informed == live[sequence].informed
        np.testing.assert_allclose(prior.mean, live[sequence].mean, atol=1e-12)


def test_a_log_that_cannot_be_read_is_a_one_line_error(recorded, tmp_path, capsys):
    path, _ = recorded
    copy = tmp_path / "run.tofcap"
    copy.write_bytes(path.read_bytes())
    belt_log_path(copy).mkdir()
    assert main(["track", str(copy), "--save", str(tmp_path / "r.rrd")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("tofcut: error: ")
    assert "run.conveyor.jsonl: Is a directory" in err


# --- the format, line by line ---------------------------------------------------------------


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("{", "not a JSON line"),
        (b"\xff\xfe", "not a JSON line"),
        ("1" * 5000, "not a JSON line"),
        ('"reading"', "not a JSON object"),
        ('{"kind": "reading", "time_ns": NaN}', "'time_ns' is not an integer"),
        (json.dumps(reading(5, speed=11.0)), "'speed_mps' is not a finite number within ±10"),
        (json.dumps(reading(5, distance_m=1e12)), "'distance_m' is not a finite number"),
        (json.dumps(reading(5, count=2**32)), "'count' is not an integer in range"),
        (json.dumps(reading(5, fault=0)), "'fault' is not true or false"),
        (json.dumps(reading(-5)), "'time_ns' is not an integer in range"),
        (json.dumps({"kind": "belt", "time_ns": 5, "source": "elsewhere", "belt": {}}),
         "belt: 'source' is not one of"),
        (json.dumps({"kind": "belt", "time_ns": 5, "source": "found", "belt": {
            "point": [0, 0, 1], "direction": [1, 0, 0], "normal": [0, 0, 1],
            "speed_mps": 1e3}}), "belt: the belt's speed must be"),
        (json.dumps({**header(), "exposure_offset_ns": 1.5}), "'exposure_offset_ns' is not"),
        (json.dumps({**header(), "max_extrapolation_s": -1}), "'max_extrapolation_s' is negative"),
        (json.dumps({**header(), "version": 2}), "version 2 is newer"),
        (json.dumps({**header(), "port": 3}), "'port' is not a string"),
        ('{"kind": null}', "unknown kind 'None'"),
    ],
)  # fmt: skip
def test_every_value_read_back_is_checked(line, message):
    with pytest.raises(BeltLogError) as caught:
        parse_line(line)
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_good_lines_read_back_as_they_were_written(tmp_path):
    path = tmp_path / "run.conveyor.jsonl"
    found = KnownBelt.from_dict(
        {"point": [0, 0.1, 1.3], "direction": [1, 0, 0], "normal": [0, -0.4, -0.9],
         "width_m": 0.5, "speed_mps": 0.2}, "found")  # fmt: skip
    r = BeltReading(1_000 * MS, 12345, 0.1 + 0.2, -0.123456789, True, False)
    with BeltLogWriter(path) as log:
        log.reading(r)  # before the header: kept, written after it
        assert path.read_text() == ""
        log.begin(port="tcp://gw:502", exposure_offset_ns=None, max_extrapolation_s=0.5)
        log.belt(found, 1_001 * MS)
        # every line is on disk as soon as it is written: a killed recorder loses no more
        written = path.read_text().splitlines()
        assert len(written) == 3
    entries = list(BeltLogReader(path))
    assert entries[0] == LogHeader("tcp://gw:502", None, 0.5)
    assert entries[1] == r  # floats round-trip exactly
    assert isinstance(entries[2], LoggedBelt)
    assert entries[2].time_ns == 1_001 * MS
    assert entries[2].belt.to_dict() == found.to_dict()
    assert entries[2].belt.source == "found"


def test_lines_before_the_header_are_bounded_to_the_newest(tmp_path):
    """A link that polls long before the camera opens must not grow memory without end."""
    path = tmp_path / "run.conveyor.jsonl"
    n = PENDING_KEPT + 250
    with BeltLogWriter(path) as log:
        for i in range(n):
            log.reading(BeltReading(i * MS, i, i * 1e-4, 0.1, True, False))
        assert len(log._pending) == PENDING_KEPT
        assert log.pending_dropped == 250
        log.begin(port="p", exposure_offset_ns=None, max_extrapolation_s=0.5)
    entries = list(BeltLogReader(path))
    assert len(entries) == 1 + PENDING_KEPT
    assert entries[1].count == 250  # the newest were kept
    assert entries[-1].count == n - 1


def test_the_replay_answers_as_the_live_link_did(tmp_path):
    path = tmp_path / "run.conveyor.jsonl"
    docs = [header(offset=None)]
    docs += [reading(t * 20 * MS) for t in range(1, 11)]  # 20 ms apart, 20-200 ms
    docs += [reading(t * 20 * MS, speed=0.5) for t in range(60, 63)]  # after 1 s of silence
    write_lines(path, docs)
    replay = ReplayedLink(path)
    assert replay.exposures.offset_ns is None  # placed in time from the frames, as live
    assert replay.reading_at(10 * MS) is None  # before the first reading
    mid = replay.reading_at(50 * MS)
    assert mid.distance_m == pytest.approx(0.25 * 0.05)  # interpolated between readings
    assert mid.speed_mps == 0.25
    late = replay.reading_at(600 * MS)  # 400 ms after the last before the silence
    assert late.distance_m == pytest.approx(0.25 * 0.6)
    assert replay.reading_at(800 * MS) is None  # 600 ms: the live link had stopped answering
    assert replay.reading_at(1210 * MS).speed_mps == 0.5
    assert replay.reading_at(1240 * MS + 600 * MS) is None  # past the end
    replay.finish()
    assert replay.summary() == "conveyor log run.conveyor.jsonl: 13 of 13 readings used"


def test_a_log_without_its_header_still_replays_and_says_so(tmp_path):
    path = tmp_path / "run.conveyor.jsonl"
    found = {"point": [0, 0.1, 1.3], "direction": [1, 0, 0], "normal": [0, -0.4, -0.9]}
    write_lines(path, [reading(20 * MS), reading(40 * MS),
                       {"kind": "belt", "time_ns": 45 * MS, "source": "found", "belt": found},
                       reading(60 * MS)])  # fmt: skip
    replay = ReplayedLink(path)
    assert replay.header is None
    assert replay.belts_until(30 * MS) == []
    (logged,) = replay.belts_until(50 * MS)
    assert logged.belt.source == "found"
    assert math.isclose(replay.reading_at(50 * MS).distance_m, 0.25 * 0.05)
    replay.finish()
    assert "no header line" in replay.summary()
    assert "3 of 3 readings used" in replay.summary()


def test_a_missing_log_is_no_readings_and_an_unreadable_one_an_error(tmp_path):
    path = tmp_path / "nope.conveyor.jsonl"
    with pytest.raises(BeltLogError, match=r"nope\.conveyor\.jsonl: No such file"):
        ReplayedLink(path)
    empty = tmp_path / "empty.conveyor.jsonl"
    empty.write_text("")
    replay = ReplayedLink(empty)
    assert replay.reading_at(10**9) is None
