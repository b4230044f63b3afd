"""The pytest plugin tofcut ships (`tofcut.testing`): its fixtures, its faults and what each
cost, and docs/testing.md's example run as a user runs it (pytest in a project of its own)."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tofcut.driver import Camera, TofcutError
from tofcut.driver.capture import CaptureReader
from tofcut.testing import CameraRig, ConveyorRig, RigError, emulated_camera, emulated_conveyor
from tofcut.tools.cli import main

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 5.0
"""Upper bound of every wait; each returns as soon as its condition holds."""


def example_tests() -> tuple[str, str]:
    """The example tests docs/testing.md tells a user to copy: the first python block, and
    the one on a recording of the line (which runs with the first block's imports)."""
    text = (ROOT / "docs" / "testing.md").read_text()
    (block, recorded, *_) = re.findall(r"```python\n(.*?)```", text, re.S)
    return block, recorded


# --- the plugin as a user meets it ----------------------------------------------------------


def test_the_documented_examples_pass_in_a_project_of_their_own(pytester, capture):
    """pytest finds the plugin by its entry point, in a fresh process, as in a user's
    project; the examples in docs/testing.md pass there as they are written (the recorded
    line is the test pattern's capture)."""
    block, recorded = example_tests()
    (pytester.path / "tests" / "data").mkdir(parents=True)
    (pytester.path / "tests" / "data" / "line.tofcap").write_bytes(capture.read_bytes())
    pytester.makepyfile(test_line=block + "\n\n" + recorded)
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=len(re.findall(r"^def test_", block + recorded, re.M)))


def test_a_project_that_does_not_use_it_imports_nothing_of_tofcut(pytester):
    """Loaded in every pytest run where tofcut is installed, the plugin imports only itself
    (and the package it sits in) until a test asks for one of its fixtures."""
    pytester.makepyfile(
        test_other="""
        import sys

        def test_nothing_of_tofcut_is_loaded(request):
            assert request.config.pluginmanager.has_plugin("tofcut")
            loaded = sorted(m for m in sys.modules if m.split(".")[0] == "tofcut")
            assert loaded == ["tofcut", "tofcut.testing", "tofcut.testing.plugin"]
        """
    )
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)


def test_importing_the_plugin_imports_nothing_else():
    code = (
        "import sys, tofcut.testing.plugin; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'tofcut'))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['tofcut', 'tofcut.testing', 'tofcut.testing.plugin']"


# --- the camera fixture ---------------------------------------------------------------------


def test_the_camera_fixture_is_the_emulated_conveyor_fast_and_seeded(tofcut_camera):
    assert isinstance(tofcut_camera, CameraRig)
    assert isinstance(tofcut_camera.camera, Camera)
    assert (tofcut_camera.scene, tofcut_camera.seed, tofcut_camera.realtime) == (
        "conveyor", 0, False,
    )  # fmt: skip
    frames = list(tofcut_camera.frames(count=3))
    assert [f.sequence for f in frames] == [0, 1, 2]
    assert [f.device_time_us for f in frames] == [0, 20_000, 40_000]  # the virtual clock
    assert tofcut_camera.belt is not None
    assert tofcut_camera.truth(frames[-1].sequence).sequence == 2
    with emulated_camera(seed=0) as again:  # the same frames for the same seed
        (first,) = again.frames(count=1)
    assert (first.range == frames[0].range).all()


@pytest.mark.tofcut_camera("test-pattern", seed=4)
def test_a_marker_says_which_scene(tofcut_camera):
    assert (tofcut_camera.scene, tofcut_camera.seed) == ("test-pattern", 4)
    assert tofcut_camera.scene_model is None
    assert tofcut_camera.belt is None
    assert next(tofcut_camera.frames(count=1)).shape == (144, 176)


@pytest.mark.parametrize("tofcut_camera", ["tools", {"scene": "test-pattern", "seed": 2}],
                         indirect=True)  # fmt: skip
def test_indirect_parametrization_says_which_scene(tofcut_camera):
    assert tofcut_camera.scene in ("tools", "test-pattern")
    assert next(tofcut_camera.frames(count=1)).valid.any()


def test_a_scene_that_does_not_exist_is_one_line(tofcut_camera_factory):
    with pytest.raises(TofcutError, match="no-such-scene") as info:
        tofcut_camera_factory("no-such-scene")
    assert "\n" not in str(info.value)


# --- camera faults: each counted as the driver counts it ------------------------------------


def test_unplugged_for_a_while_reboots_and_the_outage_is_estimated(tofcut_camera):
    list(tofcut_camera.frames(count=5))
    with tofcut_camera.unplugged(seconds=0.2) as fault:
        seqs = [f.sequence for f in tofcut_camera.frames(count=5)]
    assert seqs == [0, 1, 2, 3, 4]  # it lost power: its numbers start again
    assert fault.reconnects == 1
    assert fault.lost == fault.lost_estimated > 0
    assert fault.event_kinds == ["disconnected", "reconnected", "resumed"]
    assert tofcut_camera.stats.reconnects == 1  # and nothing more after the block


def test_unplugged_for_the_block_and_held_by_another_program_on_return(tofcut_camera):
    with tofcut_camera.unplugged() as away:
        pass  # nothing read: the camera is back at the block's end
    assert away.events == ()
    with tofcut_camera.unplugged(seconds=0.05, held_for=0.2) as fault:
        assert len(list(tofcut_camera.frames(count=3))) == 3
    kinds = fault.event_kinds
    assert kinds[0] == "disconnected"
    assert kinds.index("device-busy") < kinds.index("reconnected")
    assert fault.reconnects == 1


FAULT_COSTS = [
    ("stalled", {}, {"stalls_cleared": 1, "lost": 0}),
    ("stalled", {"after_packets": 3}, {"stalls_cleared": 1, "lost": 1}),
    ("timing_out", {"reads": 2}, {"read_timeouts": 2, "lost": 0}),
    ("damaged", {"kind": "truncate"}, {"damaged": 1, "lost": 1}),
    ("damaged", {"kind": "drop-packet", "frames": 2}, {"damaged": 2, "lost": 2}),
    ("fifo_overflow", {"frames": 10}, {"lost": 10, "fifo_overflows": 1}),
    ("hung", {}, {"reconnects": 1}),
]


@pytest.mark.parametrize(("fault", "args", "counts"), FAULT_COSTS)
def test_each_fault_costs_what_the_drill_says(tofcut_camera, fault, args, counts):
    list(tofcut_camera.frames(count=2))
    with getattr(tofcut_camera, fault)(**args) as window:
        assert len(list(tofcut_camera.frames(count=4))) == 4
    assert {name: getattr(window, name) for name in counts} == counts
    assert window.frames == 4


# --- a capture, replayed by the camera fixture ----------------------------------------------


CAPTURED = 40


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """40 frames of the test pattern, recorded fast."""
    path = tmp_path_factory.mktemp("plugin") / "pattern.tofcap"
    argv = ["record", "emulator:test-pattern", "--fast", "--frames", str(CAPTURED)]
    assert main([*argv, "-o", str(path)]) == 0
    return path


@pytest.mark.parametrize(("fault", "args", "counts"), FAULT_COSTS)
def test_a_replayed_capture_costs_what_a_scene_does(tofcut_camera_factory, capture, fault,
                                                    args, counts):  # fmt: skip
    camera = tofcut_camera_factory(capture)
    recorded = [raw.header.payload_crc for raw in CaptureReader(capture).raw_frames()]
    got = [raw.header.payload_crc for raw in camera.raw_frames(count=2)]
    with getattr(camera, fault)(**args) as window:
        got += [raw.header.payload_crc for raw in camera.raw_frames(count=4)]
    assert {name: getattr(window, name) for name in counts} == counts
    assert window.frames == 4
    index = [recorded.index(crc) for crc in got]
    assert index == sorted(index)  # the recorded frames, in order, less what the fault cost
    if fault != "hung":  # (a hung camera's silence is time: its frames pass unseen)
        assert index[-1] + 1 == len(got) + window.lost


def test_a_replay_ends_with_its_capture_or_loops(tofcut_camera_factory, capture):
    once = tofcut_camera_factory(capture)
    assert once.replay is not None
    assert once.scene == str(capture)
    assert len(list(once.frames(count=3))) == 3
    with once.unplugged(seconds=0.1) as fault:
        frames = list(once.frames())  # to the capture's end, through the outage
    assert fault.reconnects == 1
    assert len(frames) == CAPTURED - 3  # on the virtual clock an outage takes no time
    looped = tofcut_camera_factory(capture, loop=True)
    assert len(list(looped.frames(count=2 * CAPTURED))) == 2 * CAPTURED


def test_faults_refuse_what_they_cannot_do_in_one_line(tofcut_camera):
    for call, match in [
        (lambda: tofcut_camera.damaged("melted"), "kind must be one of payload"),
        (lambda: tofcut_camera.unplugged(seconds=-1), "seconds must be in 0..3600"),
        (lambda: tofcut_camera.unplugged(held_for=0.5), "held_for .* needs seconds"),
    ]:
        with pytest.raises(RigError, match=match) as info, call():
            pass
        assert "\n" not in str(info.value)


@pytest.mark.tofcut_camera(realtime=True)
def test_in_real_time_an_unplug_costs_frames_at_the_cameras_rate(tofcut_camera):
    list(tofcut_camera.frames(count=3))
    with tofcut_camera.unplugged(seconds=0.3) as fault:
        list(tofcut_camera.frames(count=3))
    # away 0.3 s at 50 fps, plus the driver's backoff: at least 15 frames
    assert fault.lost_estimated >= 15
    assert fault.reconnects == 1


# --- the conveyor fixture -------------------------------------------------------------------


def test_the_conveyor_fixture_answers_modbus_on_a_pty(tofcut_conveyor):
    assert isinstance(tofcut_conveyor, ConveyorRig)
    assert Path(tofcut_conveyor.port).exists()
    client = tofcut_conveyor.connect(poll_hz=200.0, heartbeat_s=0.0)
    reading = client.wait_for(lambda r: True, WAIT_S)
    assert reading.speed_mps == pytest.approx(0.25)
    tofcut_conveyor.controller.set_speed(0.4)
    assert client.wait_for(lambda r: r.speed_mps == pytest.approx(0.4), WAIT_S) is not None


@pytest.mark.tofcut_conveyor(speed_mps=0.1, start_count=7)
def test_a_marker_sets_the_conveyor(tofcut_conveyor):
    assert tofcut_conveyor.controller.count() >= 7
    client = tofcut_conveyor.connect(poll_hz=200.0, heartbeat_s=0.0)
    assert client.wait_for(lambda r: True, WAIT_S).speed_mps == pytest.approx(0.1)


def test_with_the_camera_the_conveyor_runs_its_belt_on_the_cameras_clock(
    tofcut_camera, tofcut_conveyor
):
    """As `--conveyor-emulator` does: the encoder counts the travel the camera sees."""
    list(tofcut_camera.frames(count=25))  # the virtual clock: 0.48 s of device time
    assert tofcut_conveyor.controller.distance_m() == pytest.approx(
        0.25 * tofcut_camera.now_us() * 1e-6
    )


def test_conveyor_faults_are_survived_by_tofcuts_own_client(tofcut_conveyor):
    client = tofcut_conveyor.connect(poll_hz=200.0, heartbeat_s=0.0, timeout_s=0.05)
    assert client.wait_for(lambda r: True, WAIT_S) is not None
    with tofcut_conveyor.silent():
        assert client.wait_stats(lambda s: s.timeouts >= 2, WAIT_S).timeouts >= 2
    with tofcut_conveyor.spoiled("crc", 2):
        assert client.wait_stats(lambda s: s.bad_frames >= 2, WAIT_S).bad_frames >= 2
    assert tofcut_conveyor.server.pending_faults() == 0
    with tofcut_conveyor.unplugged(seconds=0.1):
        assert client.wait_stats(lambda s: s.disconnects >= 1, WAIT_S).disconnects == 1
    assert client.wait_stats(lambda s: s.reopens >= 1, WAIT_S).reopens == 1
    assert client.wait_stats(lambda s: s.link_up, WAIT_S).link_up


def test_a_conveyor_cannot_follow_a_scene_without_a_belt():
    with emulated_camera("test-pattern") as camera, pytest.raises(RigError, match="no belt"):
        emulated_conveyor(camera=camera)
    with emulated_camera() as camera, pytest.raises(RigError, match="takes its speed"):
        emulated_conveyor(0.3, camera=camera)


def test_a_spoiled_block_leaves_nothing_pending():
    with emulated_conveyor() as conveyor:
        with conveyor.spoiled("lost", 5):
            assert conveyor.server.pending_faults() == 5
        assert conveyor.server.pending_faults() == 0
        with pytest.raises(RigError, match="kind must be one of garbage"), conveyor.spoiled("x"):
            pass


def test_the_factories_close_what_they_opened(pytester):
    """Each rig a factory made is closed after its test, the test's result either way."""
    pytester.makepyfile(
        test_closed=textwrap.dedent(
            """
            RIGS = []

            def test_opens(tofcut_camera_factory, tofcut_conveyor_factory):
                RIGS.append(tofcut_camera_factory("test-pattern"))
                RIGS.append(tofcut_conveyor_factory())
                raise AssertionError("fails")

            def test_they_were_closed():
                camera, conveyor = RIGS
                assert camera._closed and conveyor._closed
            """
        )
    )
    result = pytester.runpytest("-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, failed=1)
