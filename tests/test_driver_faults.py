"""Faults injected through the emulated camera: what the driver recovers and what it counts.

Time is a fake clock shared by the emulator (device time) and the driver (host time), and
the driver's wait for a vanished camera is a scripted function, so nothing here sleeps:
each test says how long an outage lasts and checks what it cost, to the frame.
"""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from tofcut.driver import (
    Camera,
    CameraConfig,
    CaptureReader,
    DeviceBusy,
    DeviceTimeout,
    Disconnected,
    EventKind,
    ProtocolError,
    ReconnectPolicy,
    Register,
    RequestRejected,
)
from tofcut.driver.protocol import STATUS_FIFO_OVERFLOW
from tofcut.sim import EmulatedBackend, EmulatedCamera, TestPattern
from tofcut.sim.drill import FAULTS, drill, table

SERIAL = 0x4000002F
PERIOD_S = 0.02  # the reset FRAME_PERIOD: 50 fps


class FakeClock:
    """Monotonic seconds for the emulator, epoch nanoseconds for the driver; moves on command."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t

    def ns(self) -> int:
        return round(self.t * 1e9)


class ScriptedWait:
    """The driver's wait between looks for its camera: the clock moves by the delay asked
    for, and the test's actions for that look run; nothing sleeps."""

    def __init__(self, clock: FakeClock, actions: dict[int, Callable[[], None]]) -> None:
        self.clock = clock
        self.actions = actions
        self.delays: list[float] = []

    def __call__(self, seconds: float, cancel: threading.Event) -> None:
        self.delays.append(seconds)
        self.clock.t += seconds
        self.actions.get(len(self.delays), lambda: None)()


def emulated(clock: FakeClock, *, serial: int = SERIAL, size=(32, 24)) -> EmulatedCamera:
    return EmulatedCamera(
        TestPattern(*size, seed=serial), serial=serial, realtime=False, monotonic=clock
    )


def open_camera(backend, clock, wait=None, **kwargs) -> Camera:
    policy = ReconnectPolicy(wait=wait) if wait is not None else kwargs.pop("reconnect", False)
    return Camera.open(
        f"{SERIAL:08X}", backend=backend, reconnect=policy, clock_ns=clock.ns, **kwargs
    )


def kinds(cam: Camera) -> list[EventKind]:
    return [e.kind for e in cam.stats.events]


def read(cam: Camera, n: int, *, during: Callable[[int], None] = lambda i: None) -> list[int]:
    """Sequence numbers of the next n frames; `during(i)` runs after the i-th."""
    seqs = []
    for i, raw in enumerate(cam.raw_frames(count=n)):
        seqs.append(raw.sequence)
        during(i)
    return seqs


# --- unplug and replug --------------------------------------------------------------------


def test_an_unplugged_camera_is_found_again_and_the_run_goes_on():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    # Back at the third look, 12 ms after that look's wait: 50 + 100 + 200 + 12 ms = 0.362 s.
    wait = ScriptedWait(
        clock, {3: lambda: (setattr(clock, "t", clock.t + 0.012), backend.replug(emu))}
    )
    seen = []
    cam = open_camera(backend, clock, wait, on_event=seen.append)
    wanted = CameraConfig.make(mod_freq_mhz=15, integration_ms=2.0, frame_rate=50)
    cam.configure(wanted)
    old_address = backend.enumerate_devices()[0].address

    seqs = read(cam, 20, during=lambda i: i == 9 and backend.unplug(emu))

    # The camera lost power: it rebooted, so its numbers start again at 0.
    assert seqs == list(range(10)) + list(range(10))
    assert emu.boots == 2
    assert backend.enumerate_devices()[0].address != old_address
    # Its registers were back at reset values; the driver put its configuration back.
    assert cam.config == wanted
    # Frames the camera would have taken in 0.362 s at 50 fps: those due at 20, 40, ...,
    # 340 ms after the last one came; the one due at 360 ms is the first after the outage.
    stats = cam.stats
    assert (stats.frames, stats.lost, stats.lost_estimated, stats.damaged) == (20, 17, 17, 0)
    assert list(stats.gaps) == list(stats.estimated_gaps) == [(10, 26)]
    assert stats.sequence_offset == 27  # run sequence of the camera's new frame 0
    assert (stats.reconnects, stats.sequence_restarts) == (1, 1)
    assert wait.delays == [0.05, 0.1, 0.2]
    assert kinds(cam) == [EventKind.DISCONNECTED, EventKind.RECONNECTED, EventKind.RESUMED]
    assert stats.events[0].errno == errno.ENODEV
    assert stats.events[1].host_time_ns - stats.events[0].host_time_ns == round(0.362e9)
    assert "17 estimated" in stats.events[2].detail
    assert seen == list(stats.events)
    cam.close()


def test_a_camera_that_kept_power_goes_on_counting_and_the_outage_is_estimated():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    back = ScriptedWait(
        clock, {2: lambda: (setattr(clock, "t", clock.t + 0.01), backend.replug(emu))}
    )
    with open_camera(backend, clock, back) as cam:
        seqs = read(cam, 12, during=lambda i: i == 5 and backend.unplug(emu, power_loss=False))
    assert seqs == list(range(12))  # the camera took no frames while the host was away
    assert emu.boots == 1
    # 0.05 + 0.1 + 0.01 s away at 50 fps: frames due at 20..140 ms were never taken (7),
    # and none of them had a number.
    assert (cam.stats.lost, cam.stats.lost_estimated) == (7, 7)
    assert list(cam.stats.gaps) == [(6, 12)]
    assert cam.stats.sequence_restarts == 0
    assert cam.stats.sequence_offset == 7


def test_it_comes_back_at_another_address_and_no_other_camera_is_taken_for_it():
    clock = FakeClock()
    emu = emulated(clock)
    stranger = emulated(clock, serial=0x11111111)
    backend = EmulatedBackend([emu])

    def plug_stranger_first() -> None:
        backend.plug(stranger)  # another camera appears first, at the next free address
        backend.replug(emu, address=9)

    wait = ScriptedWait(clock, {2: plug_stranger_first})
    with open_camera(backend, clock, wait) as cam:
        seqs = read(cam, 5, during=lambda i: i == 1 and backend.unplug(emu))
    assert seqs == [0, 1, 0, 1, 2]
    assert "address 9" in cam.stats.events[1].detail
    assert stranger.frames_sent == 0
    assert emu.frames_sent == 5


def test_a_camera_that_comes_back_as_another_device_is_refused():
    clock = FakeClock()
    emu = emulated(clock)
    impostor = emulated(clock, size=(48, 36))  # the same serial number, another sensor
    backend = EmulatedBackend([emu])
    wait = ScriptedWait(clock, {1: lambda: backend.plug(impostor)})
    with open_camera(backend, clock, wait) as cam:
        with pytest.raises(ProtocolError, match="came back as another device"):
            read(cam, 5, during=lambda i: i == 1 and backend.unplug(emu))
        assert cam.stats.frames == 2


def test_without_reconnect_an_unplug_is_reported_as_disconnected():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock) as cam, pytest.raises(Disconnected) as info:
        read(cam, 5, during=lambda i: i == 1 and backend.unplug(emu))
    assert info.value.errno == errno.ENODEV


def test_giving_up_after_the_policy_limit():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    wait = ScriptedWait(clock, {})
    policy = ReconnectPolicy(give_up_after_s=1.0, max_delay_s=0.4, wait=wait)
    cam = Camera.open(backend=backend, reconnect=policy, clock_ns=clock.ns)
    with cam, pytest.raises(Disconnected, match="did not come back within 1 s"):
        read(cam, 5, during=lambda i: i == 0 and backend.unplug(emu))
    assert wait.delays == [0.05, 0.1, 0.2, 0.4]  # 0.75 s; the next 0.4 s would pass 1 s
    assert kinds(cam)[-1] is EventKind.GAVE_UP


# --- a second program ---------------------------------------------------------------------


def test_a_camera_held_by_another_program_is_busy_until_released():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    backend.hold(emu)
    with pytest.raises(DeviceBusy, match="another program") as info:
        open_camera(backend, clock)
    assert info.value.errno == errno.EBUSY
    backend.release(emu)
    with open_camera(backend, clock) as cam:
        assert read(cam, 2) == [0, 1]


def test_a_camera_grabbed_by_another_program_during_an_outage_is_waited_for():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])

    def back_but_taken() -> None:
        backend.replug(emu)
        backend.hold(emu)

    def released() -> None:
        clock.t += 0.01
        backend.release(emu)

    wait = ScriptedWait(clock, {1: back_but_taken, 4: released})
    with open_camera(backend, clock, wait) as cam:
        seqs = read(cam, 6, during=lambda i: i == 2 and backend.unplug(emu))
    assert seqs == [0, 1, 2, 0, 1, 2]
    assert kinds(cam) == [
        EventKind.DISCONNECTED,
        EventKind.DEVICE_BUSY,  # said once, not at every look
        EventKind.RECONNECTED,
        EventKind.RESUMED,
    ]
    assert cam.stats.events[1].errno == errno.EBUSY
    # away 0.05 + 0.1 + 0.2 + 0.4 + 0.01 = 0.76 s: 37 frames due in between, estimated
    assert (cam.stats.lost, cam.stats.lost_estimated) == (37, 37)


# --- stalls -------------------------------------------------------------------------------


@pytest.mark.parametrize("reconnect", [False, True])
def test_a_stalled_endpoint_is_cleared_and_nothing_is_lost(reconnect):
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock, reconnect=reconnect) as cam:
        seqs = read(cam, 6, during=lambda i: i == 2 and emu.stall_endpoint())
    assert seqs == list(range(6))
    assert (cam.stats.stalls_cleared, cam.stats.lost, cam.stats.reconnects) == (1, 0, 0)
    assert kinds(cam) == [EventKind.STALL_CLEARED]
    assert cam.stats.events[0].errno == errno.EPIPE


def test_a_stall_in_mid_frame_costs_that_frame():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock, read_size=512) as cam:
        seqs = read(cam, 6, during=lambda i: i == 2 and emu.stall_endpoint(after_packets=3))
    assert seqs == [0, 1, 2, 4, 5, 6]
    assert (cam.stats.stalls_cleared, cam.stats.lost, cam.stats.damaged) == (1, 1, 0)
    assert list(cam.stats.gaps) == [(3, 3)]
    assert cam.stats.bytes_skipped == 3 * 512


def test_an_endpoint_that_keeps_stalling_gets_the_camera_reset():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock, ScriptedWait(clock, {})) as cam:
        cam.configure(CameraConfig.make(frame_rate=25))
        seqs = read(cam, 6, during=lambda i: i == 2 and emu.stall_endpoint(count=10))
        assert cam.read_register(Register.FRAME_PERIOD) == 400  # restored after the reboot
    assert seqs == [0, 1, 2, 0, 1, 2]  # the reset rebooted the firmware
    assert emu.boots == 2
    assert cam.stats.stalls_cleared == 3  # ReconnectPolicy.stalls_before_reset
    assert kinds(cam) == [EventKind.STALL_CLEARED] * 3 + [
        EventKind.DISCONNECTED,
        EventKind.RESET,
        EventKind.RECONNECTED,
        EventKind.RESUMED,
    ]
    assert cam.stats.reconnects == 1
    assert cam.stats.lost == 0  # no host time passed on the fake clock


def test_without_reconnect_a_stall_that_persists_is_raised():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock) as cam, pytest.raises(RequestRejected) as info:
        read(cam, 6, during=lambda i: i == 2 and emu.stall_endpoint(count=2))
    assert info.value.errno == errno.EPIPE
    assert cam.stats.stalls_cleared == 1


# --- timeouts and hangs -------------------------------------------------------------------


@pytest.mark.parametrize("reconnect", [False, True])
def test_reads_that_time_out_now_and_then_cost_nothing(reconnect):
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock, reconnect=reconnect) as cam:
        seqs = read(cam, 6, during=lambda i: i == 2 and emu.time_out_next(3))
    assert seqs == list(range(6))
    assert (cam.stats.read_timeouts, cam.stats.lost, cam.stats.reconnects) == (3, 0, 0)


def test_a_hung_camera_is_reset_and_reopened():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])

    def hang_for_2_5_s(i: int) -> None:
        if i == 9:
            emu.hang()
            clock.t += 2.5  # what the silence takes on a real clock, 2 s of it before the reset

    with open_camera(backend, clock, ScriptedWait(clock, {})) as cam:
        seqs = read(cam, 15, during=hang_for_2_5_s)
    assert seqs == list(range(10)) + list(range(5))
    assert emu.boots == 2
    # 2 s of silence (ReconnectPolicy.silence_s) in 200 ms reads
    assert cam.stats.read_timeouts == 10
    assert kinds(cam) == [
        EventKind.DISCONNECTED,
        EventKind.RESET,
        EventKind.RECONNECTED,
        EventKind.RESUMED,
    ]
    assert cam.stats.events[0].errno == errno.ETIMEDOUT
    # 2.5 s at 50 fps: 124 frames between the last before and the first after
    assert (cam.stats.lost, cam.stats.lost_estimated) == (124, 124)


def test_without_reconnect_a_hung_camera_times_out():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock) as cam, pytest.raises(DeviceTimeout) as info:
        read(cam, 5, during=lambda i: i == 1 and emu.hang())
    assert info.value.errno == errno.ETIMEDOUT
    assert cam.stats.read_timeouts == 5  # one second in 200 ms reads


def test_a_triggered_camera_may_wait_for_its_trigger_without_being_reset():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock, ScriptedWait(clock, {})) as cam:
        cam.configure(CameraConfig.make(trigger_mode="software"))
        frames = cam.raw_frames()
        cam.start()
        for _ in range(30):  # 30 × 200 ms of silence: a free-running camera would be reset
            emu.time_out_next(1)
        cam.trigger()
        assert next(frames).sequence == 0
    assert cam.stats.read_timeouts == 30
    assert cam.stats.reconnects == 0


# --- damage on the wire -------------------------------------------------------------------


@pytest.mark.parametrize("read_size", [None, 512])
@pytest.mark.parametrize("kind", ["drop-packet", "corrupt-packet", "truncate", "payload", "header"])
def test_a_damaged_transfer_costs_only_its_own_frame(kind, read_size):
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock, read_size=read_size) as cam:
        seqs = read(cam, 8, during=lambda i: i == 2 and emu.damage_next(kind, count=2))
    assert seqs == [0, 1, 2, 5, 6, 7, 8, 9]
    assert (cam.stats.damaged, cam.stats.lost, cam.stats.lost_estimated) == (2, 2, 0)
    assert list(cam.stats.gaps) == [(3, 4)]
    assert cam.stats.bytes_skipped > 0


def test_a_frame_cut_short_is_dropped_when_its_transfer_ends_not_held_for_the_next():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock) as cam:
        cam.configure(CameraConfig.make(trigger_mode="software"))
        cam.start()
        cam.trigger()
        assert cam.read_raw().sequence == 0
        emu.damage_next("truncate")
        cam.trigger()
        with pytest.raises(DeviceTimeout):
            cam.read_raw(timeout_ms=50)
        assert cam.stats.damaged == 1  # known at once, from the short transfer
        assert cam.stats.bytes_skipped == cam.info.frame_size // 2
        cam.trigger()
        assert cam.read_raw().sequence == 2
    assert list(cam.stats.gaps) == [(1, 1)]


def test_fifo_overflow_on_command_is_counted_exactly():
    clock = FakeClock()
    emu = emulated(clock)
    backend = EmulatedBackend([emu])
    with open_camera(backend, clock) as cam:
        seqs = read(cam, 8, during=lambda i: i == 4 and emu.overflow_fifo(7))
        assert cam.read_register(Register.STATUS) & STATUS_FIFO_OVERFLOW
    assert seqs == [0, 1, 2, 3, 4, 12, 13, 14]
    assert (cam.stats.lost, cam.stats.lost_estimated, cam.stats.device_dropped_flags) == (7, 0, 1)
    assert list(cam.stats.gaps) == [(5, 11)]
    assert emu.frames_dropped == 7


# --- threads: how the live pipeline uses the camera ----------------------------------------


def test_stop_from_another_thread_ends_a_wait_for_the_camera():
    emu = EmulatedCamera(TestPattern(seed=1), realtime=False)
    backend = EmulatedBackend([emu])
    waiting = threading.Event()

    def wait_a_long_time(seconds: float, cancel: threading.Event) -> None:
        waiting.set()
        cancel.wait(3600.0)  # only a stop can end this in time

    cam = Camera.open(backend=backend, reconnect=ReconnectPolicy(wait=wait_a_long_time))
    got: list[int] = []
    errors: list[BaseException] = []

    def reader() -> None:
        try:
            for raw in cam.raw_frames():
                got.append(raw.sequence)
                if len(got) == 5:
                    backend.unplug(emu)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    thread = threading.Thread(target=reader)
    thread.start()
    assert waiting.wait(10.0)
    cam.stop()
    thread.join(10.0)
    assert not thread.is_alive()
    assert errors == []
    assert got == [0, 1, 2, 3, 4]
    cam.close()


def test_close_from_another_thread_ends_a_real_time_stream():
    backend = EmulatedBackend([EmulatedCamera(TestPattern(seed=1), realtime=True)])
    cam = Camera.open(backend=backend, reconnect=True)
    three = threading.Event()
    got: list[int] = []

    def reader() -> None:
        for raw in cam.raw_frames():
            got.append(raw.sequence)
            if len(got) == 3:
                three.set()

    thread = threading.Thread(target=reader)
    thread.start()
    assert three.wait(10.0)
    cam.close()
    thread.join(10.0)
    assert not thread.is_alive()
    assert got[:3] == [0, 1, 2]
    assert got == list(range(len(got)))


def test_a_real_time_unplug_and_replug_on_a_reader_thread():
    """The real wait, the real clock: the camera is away for at least one 100 ms wait,
    then back; frames go on and the outage is counted as an estimate."""
    emu = EmulatedCamera(TestPattern(seed=1), realtime=True)
    backend = EmulatedBackend([emu])
    waiting, resumed = threading.Event(), threading.Event()

    def wait(seconds: float, cancel: threading.Event) -> None:
        waiting.set()  # the first look found nothing
        cancel.wait(seconds)

    def on_event(event) -> None:
        if event.kind is EventKind.RESUMED:
            resumed.set()

    policy = ReconnectPolicy(first_delay_s=0.1, wait=wait)
    cam = Camera.open(backend=backend, reconnect=policy, on_event=on_event)
    got: list[int] = []

    def reader() -> None:
        for raw in cam.raw_frames():
            got.append(raw.sequence)
            if len(got) == 5:
                backend.unplug(emu)

    thread = threading.Thread(target=reader)
    thread.start()
    assert waiting.wait(10.0)
    backend.replug(emu)
    assert resumed.wait(10.0)
    cam.stop()
    thread.join(10.0)
    assert not thread.is_alive()
    assert got[:6] == [0, 1, 2, 3, 4, 0]
    stats = cam.stats
    assert stats.reconnects == 1
    # away at least 100 ms, plus the first frame's 14 ms of taps: 5 frames at 50 fps
    assert stats.lost == stats.lost_estimated >= 5
    assert list(stats.gaps) == list(stats.estimated_gaps)
    assert stats.gaps[0][0] == 5
    cam.close()


def test_the_real_time_drill_measures_what_a_fault_cost():
    result = drill("a transfer cut short", FAULTS["a transfer cut short"], before=3, after=3)
    assert result.damaged == 1
    assert result.lost >= 1  # more only if this machine fell 4 frames behind meanwhile
    assert result.interruption_s >= 0.0
    assert "| a transfer cut short | read on |" in table([result])


# --- captures: a recorder killed at any moment -----------------------------------------------

RECORDER = """
import sys
from tofcut.driver import Camera, CaptureWriter, capture_metadata
from tofcut.sim import EmulatedBackend, EmulatedCamera, TestPattern
from tofcut.sim.drill import FAULTS, drill, table

backend = EmulatedBackend([EmulatedCamera(TestPattern(seed=1), realtime=False)])
with Camera.open(backend=backend) as cam, CaptureWriter(
    sys.argv[1], capture_metadata(cam.info, {}), cam.calibration_block
) as writer:
    for raw in cam.raw_frames():
        writer.write(raw)
        print(writer.frames, flush=True)
"""


def test_a_capture_from_a_recorder_killed_mid_write_replays_every_whole_record(tmp_path: Path):
    path = tmp_path / "killed.tofcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", RECORDER, str(path)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    for line in proc.stdout:
        if int(line) >= 40:
            break
    os.kill(proc.pid, signal.SIGKILL)  # no clean-up: whatever was half written stays
    proc.wait()
    reader = CaptureReader(path)
    seqs = [f.sequence for f in reader.raw_frames()]
    assert len(seqs) >= 40
    assert seqs == list(range(len(seqs)))
    assert reader.stats.damaged == reader.stats.lost == 0
    record = 8 + reader.info.frame_size
    assert reader.truncated_bytes < record
    assert len(reader) == len(seqs)
