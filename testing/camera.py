"""An emulated camera for a test, opened as `tofcut.open` opens one, with its faults as
context managers and what each cost.

    with emulated_camera("conveyor", seed=1) as camera:
        with camera.unplugged(seconds=0.3) as fault:
            frames = list(camera.frames(count=30))
        assert fault.reconnects == 1

The camera is the driver's own `Camera` (`camera.camera`) on the emulated USB bus, opened
through the source names the command line uses (`tools.pipeline.sources`), so a test runs
the same path as `tofcut live`: the real driver, its reconnects and its loss accounting.
It renders a scene, or replays a capture (`emulated_camera("run.tofcap")`, as
`emulator:run.tofcap`): a recording of a real line, through the same faults.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterator
from typing import Any, Protocol

from tofcut._closing import Closing
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.camera import Camera
from tofcut.driver.events import DeviceEvent
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.stream import StreamStats
from tofcut.sim.device import EmulatedCamera
from tofcut.sim.renderer import SceneSource
from tofcut.sim.replay import ReplayIndex
from tofcut.sim.scene import Scene
from tofcut.sim.source import TapSource
from tofcut.testing.common import Later, RigError, check_seconds, end_all
from tofcut.tools.pipeline.sources import Opened, SourceSpec, belt_of, open_source

COUNTS = (
    "frames", "lost", "lost_estimated", "damaged", "reconnects", "stalls_cleared",
    "read_timeouts", "device_dropped_flags", "sequence_restarts",
)  # fmt: skip
"""The stream's counters a fault window reports the change of."""


class _Emulator(Protocol):
    """What the rig uses of an emulated camera (in this process, or in one of its own)."""

    @property
    def source(self) -> TapSource | None: ...
    def now_us(self) -> int: ...
    def truth(self, sequence: int) -> object | None: ...
    def stall_endpoint(self, count: int = 1, after_packets: int = 0) -> None: ...
    def time_out_next(self, count: int = 1) -> None: ...
    def damage_next(self, kind: str = "payload", count: int = 1) -> None: ...
    def overflow_fifo(self, frames: int) -> None: ...
    def hang(self) -> None: ...


class FaultWindow:
    """What happened to the stream from a fault's start to the end of its block (or until
    now, inside it): the change in the driver's counters (`StreamStats`), and the events."""

    def __init__(self, fault: str, stats: StreamStats) -> None:
        self.fault = fault
        self._stats = stats
        self._start = self._counts()
        self._before = {id(e) for e in stats.events}
        self._end: dict[str, int] | None = None
        self._events: tuple[DeviceEvent, ...] | None = None

    def __repr__(self) -> str:
        counts = ", ".join(f"{name}={self._delta(name)}" for name in COUNTS)
        return f"FaultWindow({self.fault!r}, {counts}, events={self.event_kinds})"

    def _counts(self) -> dict[str, int]:
        return {name: int(getattr(self._stats, name)) for name in COUNTS}

    def close(self) -> None:
        """The block ended: the counts stop here."""
        if self._end is None:
            self._events = self.events
            self._end = self._counts()

    def _delta(self, name: str) -> int:
        end = self._end if self._end is not None else self._counts()
        return end[name] - self._start[name]

    @property
    def frames(self) -> int:
        """Good frames delivered meanwhile."""
        return self._delta("frames")

    @property
    def lost(self) -> int:
        """Frames lost meanwhile, counted or estimated (damaged ones included)."""
        return self._delta("lost")

    @property
    def lost_estimated(self) -> int:
        """The part of `lost` estimated from time (an outage), not counted from numbers."""
        return self._delta("lost_estimated")

    @property
    def damaged(self) -> int:
        return self._delta("damaged")

    @property
    def reconnects(self) -> int:
        return self._delta("reconnects")

    @property
    def stalls_cleared(self) -> int:
        return self._delta("stalls_cleared")

    @property
    def read_timeouts(self) -> int:
        return self._delta("read_timeouts")

    @property
    def fifo_overflows(self) -> int:
        """Frames that came flagged 'frames were dropped before this one'."""
        return self._delta("device_dropped_flags")

    @property
    def events(self) -> tuple[DeviceEvent, ...]:
        """The device events that happened meanwhile, in order."""
        if self._events is not None:
            return self._events
        return tuple(e for e in list(self._stats.events) if id(e) not in self._before)

    @property
    def event_kinds(self) -> list[str]:
        """The events' kinds, as `EventKind` values ('disconnected', 'reconnected', ...)."""
        return [e.kind.value for e in self.events]


class CameraRig(Closing):
    """An emulated camera opened for a test (`emulated_camera`), its faults at hand."""

    def __init__(self, opened: Opened, *, scene: str, seed: int, realtime: bool) -> None:
        if not isinstance(opened.device, Camera) or opened.emulator is None or opened.bus is None:
            raise RigError(f"{scene!r} did not open an emulated camera")
        self.opened = opened
        """The source as `tools.pipeline.sources.open_source` opened it (for the tools)."""
        self.camera: Camera = opened.device
        """The driver's camera: frames, configuration, `stats`."""
        self.scene = scene
        self.seed = seed
        self.realtime = realtime
        self._closed = False
        self._pending: list[Later] = []

    # --- the camera -----------------------------------------------------------------------

    def frames(self, count: int | None = None) -> Iterator[Frame]:
        """Demodulated frames (`Camera.frames`)."""
        return self.camera.frames(count)

    def raw_frames(self, count: int | None = None) -> Iterator[RawFrame]:
        """Frames as received (`Camera.raw_frames`)."""
        return self.camera.raw_frames(count)

    @property
    def stats(self) -> StreamStats:
        """The driver's counts: frames, lost, damaged, gaps, events."""
        return self.camera.stats

    @property
    def metadata(self) -> dict[str, Any]:
        """What the scene tells a run: its name, belt, marked target (as captures keep it);
        for a replay, what its capture's metadata tells beyond the camera."""
        return self.opened.metadata

    @property
    def replay(self) -> ReplayIndex | None:
        """The capture the camera replays (its frames, what was damaged in it), or None."""
        return self.opened.replay

    @property
    def belt(self) -> BeltGeometry | None:
        """The scene's (or the replayed capture's) belt, for `tofcut.Tracker(belt=...)`, or
        None."""
        known = belt_of(self.metadata, "scene" if self.replay is None else "capture")
        return None if known is None else known.geometry

    @property
    def scene_model(self) -> Scene | None:
        """The emulated scene itself (objects, belt, camera pose), or None for the pattern."""
        source = self._device.source
        return source.scene if isinstance(source, SceneSource) else None

    def truth(self, sequence: int) -> Any:
        """Ground truth (`tofcut.sim.FrameTruth`) of a recent frame by sequence, or None."""
        return self._device.truth(sequence)

    def now_us(self) -> int:
        """The emulated camera's device clock, microseconds since it powered on."""
        return int(self._device.now_us())

    @property
    def _device(self) -> _Emulator:
        assert self.opened.emulator is not None
        return self.opened.emulator

    # --- faults ---------------------------------------------------------------------------

    @contextlib.contextmanager
    def unplugged(
        self, seconds: float | None = None, *, power_loss: bool = True, held_for: float = 0.0
    ) -> Iterator[FaultWindow]:
        """The cable is pulled at the start of the block and plugged back (at a new address)
        after `seconds`, or at the block's end without them (then read no frames inside it:
        a reconnecting camera waits for the camera to come back); the block ends no sooner
        than the camera is back. With `power_loss` it reboots (sequence and clock from 0);
        `held_for` seconds after it is back another program holds it (EBUSY)."""
        check_seconds("unplugged", seconds)
        if not 0 <= held_for <= 3600 or (held_for and seconds is None):
            raise RigError("unplugged: held_for (0..3600 s) needs seconds")
        bus, device = self.opened.bus, self.opened.emulator
        assert bus is not None
        assert device is not None

        def back(cancel: threading.Event) -> None:
            bus.replug(device)
            if held_for:
                bus.hold(device)
                cancel.wait(held_for)
                bus.release(device)

        name = "unplugged" if seconds is None else f"unplugged for {seconds:g} s"
        window = FaultWindow(name, self.stats)
        bus.unplug(device, power_loss=power_loss)
        if seconds is None:
            try:
                yield window
            finally:
                back(threading.Event())
                window.close()
            return
        later = self._later(seconds, back)
        try:
            yield window
        except BaseException:
            later.cancel.set()  # the block failed: back at once
            raise
        finally:
            later.join()
            window.close()

    @contextlib.contextmanager
    def stalled(self, count: int = 1, *, after_packets: int = 0) -> Iterator[FaultWindow]:
        """The frame endpoint halts (EPIPE) on the next read, `count` times in all (the
        driver clears each; after 3 in a row it resets the camera); `after_packets` > 0
        lets that many 512-byte packets through first, so the frame in flight is lost."""
        with self._one_shot(f"stalled x{count}") as window:
            self._device.stall_endpoint(count=count, after_packets=after_packets)
            yield window

    @contextlib.contextmanager
    def timing_out(self, reads: int = 1) -> Iterator[FaultWindow]:
        """The next `reads` bulk reads get nothing before the driver's timeout."""
        with self._one_shot(f"{reads} reads timed out") as window:
            self._device.time_out_next(reads)
            yield window

    @contextlib.contextmanager
    def damaged(self, kind: str = "payload", frames: int = 1) -> Iterator[FaultWindow]:
        """The next `frames` frames are damaged on the wire: `kind` is one of
        `EmulatedCamera.DAMAGE_KINDS` (a flipped payload or header byte, a transfer cut
        short, a 512-byte packet lost or garbled)."""
        if kind not in EmulatedCamera.DAMAGE_KINDS:
            raise RigError(f"damaged: kind must be one of {', '.join(EmulatedCamera.DAMAGE_KINDS)}")
        with self._one_shot(f"{frames} frames damaged ({kind})") as window:
            self._device.damage_next(kind, count=frames)
            yield window

    @contextlib.contextmanager
    def fifo_overflow(self, frames: int = 10) -> Iterator[FaultWindow]:
        """The host fell behind: `frames` frames are dropped for want of FIFO room; the
        camera's numbers skip them and the next frame carries the drop flag."""
        with self._one_shot(f"FIFO overflow, {frames} frames") as window:
            self._device.overflow_fifo(frames)
            yield window

    @contextlib.contextmanager
    def hung(self) -> Iterator[FaultWindow]:
        """The firmware hangs: no frames, no answers, until a USB reset (the driver sends
        one after 2 s without a frame, with reconnect) or a power cycle (`unplugged`)."""
        with self._one_shot("hung") as window:
            self._device.hang()
            yield window

    @contextlib.contextmanager
    def _one_shot(self, name: str) -> Iterator[FaultWindow]:
        """A fault injected once as the block starts, counted to its end (a block that does
        not read past it leaves it pending: the emulated camera cannot take it back)."""
        window = FaultWindow(name, self.stats)
        try:
            yield window
        finally:
            window.close()

    def _later(self, seconds: float, action: Callable[[threading.Event], None]) -> Later:
        """Run `action(cancel)` on a thread after `seconds`, or as soon as `cancel` is set
        (by the block failing, or the rig closing)."""
        later = Later(seconds, action)
        self._pending.append(later)
        return later

    # --- life -----------------------------------------------------------------------------

    def close(self) -> None:
        """Close the camera (and the emulator's process, where it has one); twice is fine."""
        if self._closed:
            return
        self._closed = True
        try:
            end_all(self._pending)
        finally:
            self.opened.close()  # the camera, then the emulator's process if it has one


def emulated_camera(
    scene: str | os.PathLike[str] = "conveyor",
    *,
    realtime: bool = False,
    seed: int = 0,
    reconnect: bool = True,
    amplitude_threshold: float = 0.0,
    loop: bool = False,
) -> CameraRig:
    """Open an emulated camera as `tofcut.open(f"emulator:{scene}")` does: `scene` is a
    built-in scene, a scene `.toml` file, `family:conveyor:N`, `test-pattern`, or a capture
    (`.tofcap`) the camera replays (its frames end with the capture, unless `loop`); in
    real time (frames at the camera's rate) or fast (as fast as they are read, on a virtual
    clock: the same frames every time for a seed); `reconnect` lets the stream outlive
    unplugs, stalls and hangs, as `tofcut live` opens cameras."""
    name = os.fspath(scene)
    opened = open_source(
        SourceSpec("emulator", name), realtime=realtime, seed=seed, reconnect=reconnect,
        amplitude_threshold=amplitude_threshold, loop=loop,
    )  # fmt: skip
    return CameraRig(opened, scene=name, seed=seed, realtime=realtime)
