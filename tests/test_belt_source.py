"""Where a run's belt comes from: the precedence of map, metadata and found belts, their
disagreements, bad metadata, and the belt reaching the tracker and the rejects alike, at the
start and mid-run, through the command line."""

from __future__ import annotations

import argparse
import json
import math
import struct
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tofcut.driver.belt import BeltGeometry, BeltReading, KnownBelt
from tofcut.driver.conveyor.reject_rule import RejectRule
from tofcut.driver.conveyor.rejects import RejectScheduler
from tofcut.sim.catalog import open_scene
from tofcut.tools.cli import main
from tofcut.tools.commands import tracking
from tofcut.tools.pipeline.belt_source import (
    BeltCandidate,
    BeltResolution,
    disagreement,
    resolve_belt,
    resolve_run_belt,
)
from tofcut.tools.pipeline.conveyor_line import add_conveyor_options, open_conveyor
from tofcut.tools.pipeline.run_belt import RunBelt
from tofcut.tracker.tracker import Tracker

SCENE_BELT = open_scene("conveyor").belt
"""The conveyor scene's belt (camera coordinates), with its speed, 0.25 m/s."""


def moved(
    belt: KnownBelt,
    source: str,
    *,
    turn_deg: float = 0.0,
    lift_m: float = 0.0,
    speed: float | None = None,
) -> KnownBelt:
    """The belt turned about its normal and lifted along it, from another source."""
    g = belt.geometry
    side = np.cross(g.normal, g.direction)
    a = math.radians(turn_deg)
    direction = math.cos(a) * g.direction + math.sin(a) * side
    geometry = BeltGeometry(g.point + lift_m * g.normal, direction, g.normal, g.width_m)
    return KnownBelt(geometry, speed, source)


def write_map(path: Path, belt: KnownBelt, extra: str = "") -> Path:
    g = belt.geometry

    def vec(v: np.ndarray) -> str:
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"

    path.write_text(
        f"[belt]\ndirection = {vec(g.direction)}\nnormal = {vec(g.normal)}\n"
        f"point = {vec(g.point)}\nwidth_m = {g.width_m!r}\n{extra}"
    )
    return path


def rewrite_metadata(path: Path, change) -> None:
    """Change a capture's metadata in place (`change(meta)` edits the dict)."""
    data = path.read_bytes()
    (n,) = struct.unpack("<I", data[8:12])
    meta = json.loads(data[12 : 12 + n])
    change(meta)
    text = json.dumps(meta).encode()  # NaN and Infinity as Python's json writes them
    path.write_bytes(data[:8] + struct.pack("<I", len(text)) + text + data[12 + n :])


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """A short capture of the emulated conveyor, with the scene's belt in its metadata."""
    path = tmp_path_factory.mktemp("cap") / "run.tofcap"
    assert main(["record", "emulator:conveyor", "-o", str(path), "--frames", "8", "--fast"]) == 0
    return path


@pytest.fixture
def bare(capture, tmp_path) -> Path:
    """The same capture with no belt in its metadata."""
    path = tmp_path / "bare.tofcap"
    path.write_bytes(capture.read_bytes())
    rewrite_metadata(path, lambda m: (m.pop("belt"), m.pop("belt_source")))
    return path


@pytest.fixture
def spy(monkeypatch):
    """The tracker `tofcut track` makes, recording its belt and prior at every frame."""
    seen: list[tuple[int, BeltGeometry | None, object]] = []

    class SpyTracker(Tracker):
        def update(self, frame, prior=None):
            seen.append((frame.sequence, self.belt, prior))
            return super().update(frame, prior)

    monkeypatch.setattr(tracking, "Tracker", SpyTracker)
    return seen


def same_geometry(a: BeltGeometry, b: BeltGeometry) -> bool:
    return all(
        np.allclose(getattr(a, k), getattr(b, k), atol=1e-12)
        for k in ("point", "direction", "normal", "origin")
    )


# --- the precedence -------------------------------------------------------------------------


def test_what_the_user_gave_wins_and_the_speed_comes_from_the_next_source():
    map_belt = moved(SCENE_BELT, "map", lift_m=0.01)  # within the tolerance: no warning
    scene = SCENE_BELT
    found = moved(SCENE_BELT, "found", speed=0.3)
    r = resolve_belt([BeltCandidate(found), BeltCandidate(scene, "conveyor"), None,
                      BeltCandidate(map_belt, "line.toml")])  # fmt: skip
    assert r.belt.source == "map"
    assert r.belt.geometry is map_belt.geometry
    assert r.belt.speed_mps == 0.25  # the map has none: the scene's, the next with one
    assert r.speed_from == "scene"
    assert r.warnings == ()
    assert r.describe() == (
        "belt: from the map (line.toml); speed 0.250 m/s (from the scene's metadata)"
    )
    given = KnownBelt(map_belt.geometry, 0.2, "given")
    r = resolve_belt([BeltCandidate(map_belt), BeltCandidate(given)])
    assert (r.belt.source, r.belt.speed_mps, r.speed_from) == ("given", 0.2, None)
    assert resolve_belt([BeltCandidate(scene, "conveyor")]).describe() == (
        "belt: from the scene's metadata (conveyor); speed 0.250 m/s"
    )


def test_a_found_belt_is_used_only_where_nothing_was_given():
    found = moved(SCENE_BELT, "found", speed=0.3)
    r = resolve_belt([None, BeltCandidate(found)])
    assert r.belt is found
    assert r.describe().startswith("belt: found during the run")
    r = resolve_belt([BeltCandidate(found), BeltCandidate(SCENE_BELT)])
    assert r.belt is SCENE_BELT
    assert r.warnings == ("the scene's belt and the found belt disagree (speeds 0.250 and "
                          "0.300 m/s); using the scene's belt",)  # fmt: skip
    assert resolve_belt([None, None]).belt is None
    assert resolve_belt([]).describe() == "belt: none given"


def test_sources_that_disagree_are_one_warning_line_each():
    map_belt = moved(SCENE_BELT, "map", turn_deg=10.0, lift_m=0.05)
    r = resolve_belt([BeltCandidate(SCENE_BELT, "conveyor"), BeltCandidate(map_belt, "m.toml")])
    assert r.belt.geometry is map_belt.geometry
    (warning,) = r.warnings
    assert warning == (
        "the map's belt and the scene's belt disagree (directions 10.0° apart, planes 5.0 cm "
        "apart); using the map's belt"
    )
    assert r.belt.speed_mps is None  # the scene's belt runs another way: its speed is not taken
    # within a few degrees and centimetres they are the same belt
    near = moved(SCENE_BELT, "map", turn_deg=2.0, lift_m=0.02)
    assert disagreement(near, SCENE_BELT) is None
    assert disagreement(moved(SCENE_BELT, "map", turn_deg=180.0), SCENE_BELT) == (
        "directions 180.0° apart"
    )


# --- through the command line ---------------------------------------------------------------


def test_the_maps_belt_reaches_the_tracker_when_the_capture_has_none(bare, tmp_path, spy, capsys):
    line_map = write_map(tmp_path / "line.toml", SCENE_BELT)
    argv = ["track", str(bare), "--frames", "4", "--save", str(tmp_path / "r.rrd")]
    assert main(argv) == 0
    # with nothing given, the belt is found from the frames: its plane from the first frame
    out = capsys.readouterr().out
    true = SCENE_BELT.geometry
    for _, belt, _ in spy:
        assert np.degrees(np.arccos(min(1.0, float(belt.normal @ true.normal)))) < 1.0
        assert abs(float(true.height(belt.origin))) < 0.01
    assert "belt: found during the run (from frame 0" in out
    assert "found belt: plane" in out
    spy.clear()
    assert main([*argv, "--conveyor-map", str(line_map)]) == 0
    out = capsys.readouterr().out
    assert len(spy) == 4
    for _, belt, prior in spy:
        assert same_geometry(belt, SCENE_BELT.geometry)
        assert prior is None  # a map gives no speed, and there is no encoder
    assert f"belt: from the map ({line_map}); no velocity prior (no speed known)\n" in out


def test_the_map_wins_over_the_capture_and_a_disagreement_is_one_warning(
    capture, tmp_path, spy, capsys
):
    save = ["--frames", "2", "--save", str(tmp_path / "r.rrd")]
    same = write_map(tmp_path / "same.toml", moved(SCENE_BELT, "map", lift_m=0.01))
    assert main(["track", str(capture), "--conveyor-map", str(same), *save]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err
    assert (
        f"belt: from the map ({same}); speed 0.250 m/s (from the capture's metadata); "
        "velocity prior from its speed\n"
    ) in captured.out
    for _, belt, prior in spy:
        assert not same_geometry(belt, SCENE_BELT.geometry)  # the map's, lifted 1 cm
        assert float(SCENE_BELT.geometry.height(belt.origin)) == pytest.approx(0.01)
        np.testing.assert_allclose(prior.mean, [0.25, 0.0, 0.0], atol=1e-12)
    spy.clear()
    tilted = write_map(tmp_path / "tilted.toml", moved(SCENE_BELT, "map", turn_deg=8.0))
    assert main(["track", str(capture), "--conveyor-map", str(tilted), *save]) == 0
    captured = capsys.readouterr()
    warnings = [x for x in captured.err.splitlines() if "warning" in x]
    assert warnings == [
        "tofcut: warning: the map's belt and the capture's belt disagree (directions 8.0° "
        "apart); using the map's belt"
    ]
    assert f"belt: from the map ({tilted}); no velocity prior" in captured.out
    for _, belt, _ in spy:
        assert float(belt.direction @ SCENE_BELT.geometry.direction) == pytest.approx(
            math.cos(math.radians(8.0))
        )


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda b: b.update(speed_mps=float("nan")), "speed must be a number within ±10.0 m/s"),
        (lambda b: b.update(speed_mps=float("inf")), "speed must be a number within ±10.0 m/s"),
        (lambda b: b.update(speed_mps="0.25"), "speed_mps must be a number"),
        (lambda b: b.update(direction=[0.0, 0.0, 0.0]), "direction must not be zero"),
        (lambda b: b.update(normal=[0, 0, 0]), "normal must not be zero"),
        (lambda b: b.update(direction=[1, 0, "0"]), "direction must be a list of three numbers"),
        (lambda b: b.update(point=[0, float("nan"), 1]), "point must be three finite numbers"),
        (lambda b: b.update(point=[0, 0, 1e300]), "point is more than 100 m away"),
        (lambda b: b.update(width_m=-1.0), "width must be a positive number"),
        (lambda b: b.update(normal=[True, 0, 1]), "normal must be a list of three numbers"),
        (lambda b: b.pop("normal"), "the belt has no normal"),
    ],
)  # fmt: skip
def test_bad_belt_metadata_is_a_one_line_error(capture, tmp_path, capsys, change, message):
    path = tmp_path / "bad.tofcap"
    path.write_bytes(capture.read_bytes())
    rewrite_metadata(path, lambda m: change(m["belt"]))
    assert main(["track", str(path), "--save", str(tmp_path / "r.rrd")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("tofcut: error: the belt in the capture's metadata is unusable: ")
    assert message in err


def test_a_belt_source_that_is_not_a_source_is_a_one_line_error(capture, tmp_path, capsys):
    path = tmp_path / "bad.tofcap"
    path.write_bytes(capture.read_bytes())
    rewrite_metadata(path, lambda m: m.update(belt_source={"x": 1}))
    assert main(["track", str(path), "--save", str(tmp_path / "r.rrd")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "metadata says its belt came from" in err


@pytest.mark.parametrize("link", ["emulator", "port"])
def test_live_rejects_start_without_a_map_when_the_scene_knows_the_belt(
    tmp_path, capsys, monkeypatch, link, tofcut_conveyor_factory
):
    lines = []

    def keep(*a, **k):
        line = open_conveyor(*a, **k)
        lines.append(line)
        return line

    monkeypatch.setattr(tracking, "open_conveyor", keep)
    argv = ["live", "emulator:conveyor", "--fast", "--frames", "6", "--reject", "height > 0.5",
            "--diverter-distance", "1.0", "--save", str(tmp_path / "r.rrd")]  # fmt: skip
    if link == "emulator":
        assert main([*argv, "--conveyor-emulator"]) == 0
    else:  # a controller of our own on a pty: the scene's belt still comes from the scene
        port = tofcut_conveyor_factory(0.25).port
        assert main([*argv, "--conveyor", port, "--parity", "N"]) == 0
    out = capsys.readouterr().out
    assert (
        "belt: from the scene's metadata (conveyor); speed 0.250 m/s; "
        "velocity prior from the conveyor link's encoder\n"
    ) in out
    assert "rejects: 0 fired" in out
    (line,) = lines
    assert same_geometry(line.rejects.belt, SCENE_BELT.geometry)


def test_the_maps_belt_reaches_the_rejects_too(tmp_path, capsys, monkeypatch, spy):
    lines = []

    def keep(*a, **k):
        lines.append(open_conveyor(*a, **k))
        return lines[-1]

    monkeypatch.setattr(tracking, "open_conveyor", keep)
    line_map = write_map(tmp_path / "line.toml", moved(SCENE_BELT, "map", lift_m=0.02),
                         "diverter_m = 1.2\n")  # fmt: skip
    argv = ["live", "emulator:conveyor", "--fast", "--frames", "4", "--conveyor-emulator",
            "--reject", "height > 0.5", "--conveyor-map", str(line_map),
            "--save", str(tmp_path / "r.rrd")]  # fmt: skip
    assert main(argv) == 0
    (line,) = lines
    assert line.rejects.diverter_m == 1.2
    for _, belt, _ in spy:
        assert belt is line.rejects.belt  # one geometry, the map's, for both
    assert float(SCENE_BELT.geometry.height(line.rejects.belt.origin)) == pytest.approx(0.02)
    assert f"belt: from the map ({line_map}); speed 0.250 m/s" in capsys.readouterr().out


def test_rejects_with_no_belt_from_anywhere_exit_2_in_one_line(tmp_path, capsys):
    argv = ["live", "emulator:test-pattern", "--fast", "--frames", "3", "--conveyor-emulator",
            "--reject", "height > 0.1", "--diverter-distance", "1",
            "--save", str(tmp_path / "r.rrd")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("tofcut: error: --reject needs the belt's geometry")
    assert not (tmp_path / "r.rrd").exists()  # said before anything was opened


# --- a belt that becomes known mid-run ------------------------------------------------------


def frame(sequence: int, host_ns: int) -> SimpleNamespace:
    return SimpleNamespace(sequence=sequence, host_time_ns=host_ns)


class FakeLink:
    """A conveyor line as RunBelt sees it: a belt at 0.25 m/s, frames placed at arrival."""

    def __init__(self, rejects: RejectScheduler) -> None:
        self.rejects = rejects
        self.direction = None

    def frame_time_ns(self, f) -> int:
        return f.host_time_ns

    def reading_at(self, time_ns: int) -> BeltReading:
        return BeltReading(time_ns, 0, 0.25 * time_ns * 1e-9, 0.25, True, False)


def test_a_belt_found_mid_run_reaches_the_tracker_and_the_rejects_at_the_next_frame():
    rejects = RejectScheduler(RejectRule.parse("height > 0.1"), None, 1.0,
                              lambda t: None, lambda e: None)  # fmt: skip
    tracker = SimpleNamespace(belt=None)
    said: list[str] = []
    run_belt = RunBelt(BeltResolution(None), tracker, line=FakeLink(rejects), say=said.append)
    assert run_belt.at_frame(frame(1, 10**9)) is None  # no belt: no direction, no prior
    found = moved(SCENE_BELT, "found")
    offered = []
    t = threading.Thread(target=lambda: offered.append(run_belt.offer(found)))
    t.start()
    t.join()
    assert offered == [True]
    assert tracker.belt is None  # not in the middle of a frame: at the next one
    prior = run_belt.at_frame(frame(2, 2 * 10**9))
    assert tracker.belt is found.geometry is rejects.belt
    np.testing.assert_allclose(prior.mean, 0.25 * found.geometry.direction)
    assert prior.informed
    assert rejects.stats.belt_changes == 1
    better = moved(SCENE_BELT, "found", lift_m=0.001)
    assert run_belt.offer(better)
    run_belt.at_frame(frame(3, 3 * 10**9))
    assert tracker.belt is better.geometry is rejects.belt
    assert run_belt.describe() == (
        "belt: found during the run (from frame 2, refined 1 times); "
        "velocity prior from the conveyor link's encoder"
    )
    assert said == []


def test_a_found_belt_never_overrides_a_given_one_and_a_disagreement_is_said_once():
    said: list[str] = []
    tracker = SimpleNamespace(belt=SCENE_BELT.geometry)
    run_belt = RunBelt(resolve_belt([BeltCandidate(SCENE_BELT, "conveyor")]), tracker,
                       say=said.append)  # fmt: skip
    off = moved(SCENE_BELT, "found", lift_m=0.1)
    assert not run_belt.offer(off)
    assert not run_belt.offer(off)
    assert not run_belt.offer(moved(SCENE_BELT, "found"))  # agrees: nothing to say
    run_belt.at_frame(frame(1, 10**9))
    assert tracker.belt is SCENE_BELT.geometry
    assert said == [
        "the scene's belt and the found belt disagree (planes 10.0 cm apart); "
        "using the scene's belt"
    ]


def test_the_pipeline_takes_a_belt_found_mid_run_without_restarting(
    bare, tmp_path, spy, capsys, monkeypatch
):
    """A finder that finds the belt at the fourth frame: the same tracker has it from then."""
    found = moved(SCENE_BELT, "found", speed=0.25)

    class WithFinder(RunBelt):
        def find(self, finder):
            self.finder = lambda f: found if f.sequence >= 3 else None

    monkeypatch.setattr(tracking, "RunBelt", WithFinder)
    assert main(["track", str(bare), "--frames", "6", "--save", str(tmp_path / "r.rrd")]) == 0
    assert [belt is None for _, belt, _ in spy] == [True, True, True, False, False, False]
    trackers_belts = [belt for _, belt, _ in spy[3:]]
    assert all(same_geometry(b, SCENE_BELT.geometry) for b in trackers_belts)
    assert [prior is None for _, _, prior in spy] == [True, True, True, False, False, False]
    out = capsys.readouterr().out
    assert "belt: found during the run (from frame 3, refined 2 times); speed 0.250 m/s" in out


@pytest.mark.parametrize("seed", [[999, 5], [3, -1], [True, 4], [1.5, 2], "12,3"])
def test_a_target_pixel_off_the_image_is_a_one_line_error(capture, tmp_path, capsys, seed):
    path = tmp_path / "bad.tofcap"
    path.write_bytes(capture.read_bytes())
    rewrite_metadata(path, lambda m: m.update(target_pixel=seed))
    assert main(["track", str(path), "--scene-target", "--save", str(tmp_path / "r.rrd")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "target_pixel is not a pixel of the image" in err


def test_a_belt_given_through_the_python_api_reaches_the_rejects_and_the_prior(tofcut_camera):
    """The API's own source wins over the scene's: `resolve_run_belt(..., given=...)`."""
    parser = argparse.ArgumentParser()
    add_conveyor_options(parser)
    args = parser.parse_args(["--conveyor-emulator", "--reject", "height > 0.1",
                              "--diverter-distance", "1.0"])  # fmt: skip
    given = moved(SCENE_BELT, "given", turn_deg=1.0, speed=0.25)
    opened = tofcut_camera.opened  # the emulated conveyor, fast (the plugin's fixture)
    resolution = resolve_run_belt(args, opened, given=given)
    assert resolution.belt is given
    assert resolution.warnings == ()  # within a few degrees of the scene's
    with open_conveyor(args, opened, resolution=resolution) as line:
        assert line.rejects.belt is given.geometry
        tracker = SimpleNamespace(belt=given.geometry)
        run_belt = RunBelt(resolution, tracker, line=line)
        reading = line.client.wait_for(lambda r: True, 5.0)
        now = SimpleNamespace(sequence=0, host_time_ns=reading.time_ns)
        line.exposures = SimpleNamespace(host_time_ns=lambda f: f.host_time_ns)
        prior = run_belt.at_frame(now)
        np.testing.assert_allclose(prior.mean, 0.25 * given.geometry.direction, atol=1e-12)
        assert run_belt.describe().startswith("belt: given through the Python API")
