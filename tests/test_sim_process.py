"""The emulated camera in a process of its own (`EmulatorProcess`), behind the same pyusb
backend: the driver reads the same bytes and meets the same faults as from the camera in
its own process; the child ends when it is closed, when its parent dies, and says in one
line why it could not start."""

from __future__ import annotations

import functools
import hashlib
import os
import select
import signal
import subprocess
import sys
import textwrap
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from tofcut.driver import Camera, CameraConfig, Disconnected, ReconnectPolicy
from tofcut.driver.errors import TofcutError
from tofcut.sim import EmulatedBackend, EmulatedCamera, TestPattern, open_scene
from tofcut.sim.device import EmulatedDevice
from tofcut.sim.process import EmulatorProcess, EmulatorProcessError
from tofcut.sim.source import Exposure
from tofcut.tools.pipeline.sources import SourceSpec, open_source

SERIAL = 0x4000002F
WAIT_S = 60.0
"""The longest a test waits for a process to start or end (it is awaited, not slept)."""


@pytest.fixture
def children():
    """Emulator processes made by a test, closed after it whatever happened."""
    made: list[EmulatorProcess] = []
    yield made
    for child in made:
        child.close()


def in_process(**kwargs) -> EmulatedCamera:
    return EmulatedCamera(TestPattern(32, 24, seed=1), serial=SERIAL, realtime=False, **kwargs)


def in_child(children: list[EmulatorProcess], **kwargs) -> EmulatorProcess:
    recipe = functools.partial(TestPattern, 32, 24, seed=1)
    child = EmulatorProcess(recipe, serial=SERIAL, realtime=False, **kwargs)
    children.append(child)
    return child


def read(cam: Camera, n: int, *, at: int, then: Callable[[], object]) -> None:
    """Read `n` frames, and after the one numbered `at` (from 0) do `then`."""
    for i, _ in enumerate(cam.raw_frames(count=n)):
        if i == at:
            then()


def wait_for_exit(pid: int) -> None:
    """Until process `pid` has ended (a pidfd: it need not be our child)."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return
    try:
        ready, _, _ = select.select([fd], [], [], WAIT_S)
        assert ready, f"process {pid} still runs after {WAIT_S} s"
    finally:
        os.close(fd)


# --- the same bytes -------------------------------------------------------------------------


def test_frames_through_the_process_are_the_in_process_frames_bit_for_bit(children):
    """Fast (virtual clock): the same scene and seed give the same wire bytes and truth."""
    recipe = functools.partial(open_scene, "conveyor", 3)
    child = EmulatorProcess(recipe, realtime=False)
    children.append(child)
    here = EmulatedCamera(recipe(), realtime=False)
    runs = []
    for emu in (here, child):
        with Camera.open(backend=EmulatedBackend([emu])) as cam:
            frames = list(cam.raw_frames(count=12))
        runs.append(frames)
    assert [f.wire for f in runs[0]] == [f.wire for f in runs[1]]
    assert child.frames_sent == here.frames_sent == 12
    last = runs[0][-1].sequence
    ours, theirs = here.truth(last), child.truth(last)
    assert ours is not None
    assert theirs is not None
    np.testing.assert_array_equal(ours.labels, theirs.labels)
    np.testing.assert_array_equal(ours.range, theirs.range)


def test_real_time_frames_are_rendered_ahead_as_the_scene_renders_them(children):
    """In real time the child renders each frame as its exposure ends; each is the scene's
    own rendering of that frame's sequence number and start time."""
    child = EmulatorProcess(functools.partial(TestPattern, 32, 24, seed=5), realtime=True)
    children.append(child)
    scene = TestPattern(32, 24, seed=5)
    with Camera.open(backend=EmulatedBackend([child])) as cam:
        frames = list(cam.raw_frames(count=8))
    for raw in frames:
        h = raw.header
        exposure = Exposure(
            sequence=h.sequence,
            t0_s=h.device_time_us / 1e6,
            tap_interval_s=h.tap_interval_us / 1e6,
            integration_s=(h.tap_interval_us - 200) / 1e6,
            mod_code=h.mod_code,
        )
        np.testing.assert_array_equal(raw.taps, scene.render(exposure).taps)


# --- the same faults ------------------------------------------------------------------------


class FakeClock:
    """The driver's host clock (the emulator runs on its virtual one): moves on command."""

    def __init__(self) -> None:
        self.t = 1000.0

    def ns(self) -> int:
        return round(self.t * 1e9)


Fault = Callable[[EmulatedBackend, EmulatedDevice], None]


def _unplug(power_loss: bool, back_at_look: int) -> Fault:
    def fault(bus: EmulatedBackend, emu: EmulatedDevice) -> None:
        bus.unplug(emu, power_loss=power_loss)

    fault.back_at_look = back_at_look  # type: ignore[attr-defined]
    return fault


FAULTS: dict[str, Fault] = {
    "unplugged (power lost)": _unplug(True, 3),
    "unplugged (power kept)": _unplug(False, 2),
    "held by another program on return": _unplug(True, 1),
    "stalled endpoint, mid-frame": lambda bus, emu: emu.stall_endpoint(after_packets=3),
    "endpoint stalling until a reset": lambda bus, emu: emu.stall_endpoint(count=10),
    "reads timed out": lambda bus, emu: emu.time_out_next(3),
    "hung firmware": lambda bus, emu: emu.hang(),
    "FIFO overflow": lambda bus, emu: emu.overflow_fifo(10),
    **{
        f"damaged frame ({kind})": functools.partial(
            lambda kind, bus, emu: emu.damage_next(kind), kind
        )
        for kind in EmulatedCamera.DAMAGE_KINDS
    },
}


def run_fault(emu: EmulatedDevice, name: str) -> tuple[object, ...]:
    """Read 14 frames with `name` injected after the 5th; everything the run shows."""
    fault = FAULTS[name]
    bus = EmulatedBackend([emu])
    clock = FakeClock()
    looks: list[float] = []
    back_at = getattr(fault, "back_at_look", None)

    def wait(seconds: float, cancel: threading.Event) -> None:
        looks.append(seconds)
        clock.t += seconds
        if len(looks) == back_at:
            bus.replug(emu)
            if name.startswith("held"):
                bus.hold(emu)
        if len(looks) == 3 and name.startswith("held"):
            bus.release(emu)

    policy = ReconnectPolicy(wait=wait)
    seqs, wires = [], []
    with Camera.open(backend=bus, reconnect=policy, clock_ns=clock.ns) as cam:
        cam.configure(CameraConfig.make(frame_rate=25))
        for i, raw in enumerate(cam.raw_frames(count=14)):
            seqs.append(raw.sequence)
            wires.append(hashlib.sha256(raw.wire).hexdigest())
            if i == 4:
                fault(bus, emu)
        s = cam.stats
        counts = (
            s.frames, s.lost, s.lost_estimated, s.damaged, s.read_timeouts, s.stalls_cleared,
            s.reconnects, s.sequence_restarts, s.device_dropped_flags, list(s.gaps),
        )  # fmt: skip
        events = [(e.kind, e.errno) for e in s.events]
    return seqs, wires, counts, events, looks, emu.boots, emu.frames_sent, emu.frames_dropped


@pytest.mark.parametrize("name", list(FAULTS))
def test_a_fault_injected_through_the_process_is_the_fault_in_process(children, name):
    here = run_fault(in_process(), name)
    there = run_fault(in_child(children), name)
    assert there == here
    kinds = {kind for kind, _ in here[3]}
    if name != "FIFO overflow" and not name.startswith(("damaged", "reads")):
        assert kinds, "the fault did something the driver noticed"


def test_without_reconnect_an_unplug_through_the_process_is_disconnected(children):
    emu = in_child(children)
    bus = EmulatedBackend([emu])
    with Camera.open(backend=bus) as cam, pytest.raises(Disconnected):
        read(cam, 5, at=1, then=lambda: bus.unplug(emu))


# --- lifetime -------------------------------------------------------------------------------


def test_closing_ends_the_child_at_once_even_with_a_read_waiting_in_it(children):
    child = EmulatorProcess(functools.partial(TestPattern, 32, 24), realtime=True)
    children.append(child)
    outcome: list[BaseException] = []
    with Camera.open(backend=EmulatedBackend([child])) as cam:
        cam.configure(CameraConfig.make(trigger_mode=1))  # software trigger: no frame comes
        cam.start()

        def read() -> None:
            try:
                cam.read_raw(timeout_ms=60_000)
            except BaseException as exc:
                outcome.append(exc)

        reader = threading.Thread(target=read)
        reader.start()
        child.close()
        reader.join(WAIT_S)
        assert not reader.is_alive()
    assert child.exit_status == 0
    assert isinstance(outcome[0], Disconnected)  # the camera is gone, as when unplugged


def test_the_child_dies_with_its_parent(tmp_path):
    """The parent killed (SIGKILL: nothing of it runs), with a forked process still
    holding its sockets; and the parent ending without closing."""
    script = textwrap.dedent(
        """
        import functools, os, signal, sys
        from tofcut.sim import TestPattern
        from tofcut.sim.process import EmulatorProcess
        child = EmulatorProcess(functools.partial(TestPattern, 8, 6), realtime=True)
        if sys.argv[1] == "killed":
            holder = os.fork()
            if holder == 0:  # holds the parent's sockets, not the test's pipes
                null = os.open(os.devnull, os.O_RDWR)
                for fd in (0, 1, 2):
                    os.dup2(null, fd)
                signal.pause()
            print(child.pid, holder, flush=True)
            os.kill(os.getpid(), signal.SIGKILL)
        print(child.pid, 0, flush=True)
        """
    )
    for how in ("killed", "exits"):
        done = subprocess.run(
            [sys.executable, "-c", script, how], capture_output=True, text=True, timeout=WAIT_S
        )
        child_pid, holder = (int(x) for x in done.stdout.split())
        try:
            wait_for_exit(child_pid)
        finally:
            if holder:
                os.kill(holder, signal.SIGKILL)
        assert done.stderr == ""


def test_a_child_that_cannot_start_says_why_in_one_line():
    with pytest.raises(EmulatorProcessError) as info:
        EmulatorProcess(functools.partial(open_scene, "no-such-scene"))
    text = str(info.value)
    assert isinstance(info.value, TofcutError)
    assert "\n" not in text
    assert text.startswith("the emulated camera's process could not start: ")
    assert "no-such-scene" in text
    with pytest.raises(EmulatorProcessError, match=r"could not start \(exit status 3\)"):
        EmulatorProcess(functools.partial(os._exit, 3))


def test_a_child_that_dies_mid_run_is_one_error_not_an_unplug(children):
    child = EmulatorProcess(functools.partial(TestPattern, 32, 24), realtime=True)
    children.append(child)
    gone = r"ended unexpectedly \(exit status -9\)"
    with (
        Camera.open(backend=EmulatedBackend([child]), reconnect=True) as cam,
        pytest.raises(EmulatorProcessError, match=gone),
    ):
        read(cam, 50, at=2, then=lambda: os.kill(child.pid, signal.SIGKILL))


# --- chosen by how the camera runs ------------------------------------------------------------


def test_a_real_time_emulator_runs_in_its_own_process_and_a_fast_one_in_ours():
    live = open_source(SourceSpec("emulator", "test-pattern"), realtime=True)
    fast = open_source(SourceSpec("emulator", "test-pattern"), realtime=False)
    try:
        assert isinstance(live.emulator, EmulatorProcess)
        assert isinstance(fast.emulator, EmulatedCamera)
        assert live.device.info == fast.device.info
        assert isinstance(live.emulator.source, TestPattern)  # the parent's copy, for metadata
    finally:
        live.close()
        fast.close()
    assert live.emulator.exit_status == 0


def test_the_scene_names_the_child_builds_are_the_parents(tmp_path, monkeypatch):
    """A scene file is read by the child in the parent's working directory."""
    scene = Path(__file__).resolve().parent.parent / "sim" / "scenes" / "conveyor.toml"
    (tmp_path / "mine.toml").write_text(scene.read_text())
    monkeypatch.chdir(tmp_path)
    opened = open_source(SourceSpec("emulator", "mine.toml"), realtime=True)
    try:
        assert isinstance(opened.emulator, EmulatorProcess)
        (frame,) = opened.device.frames(count=1)
        assert frame.valid.any()
    finally:
        opened.close()
