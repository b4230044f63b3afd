"""Naming a camera on the command line: `usb`, `usb:SERIAL`, `emulator[:SCENE]`,
`emulator:FILE.tofcap`, or a capture.

The emulator is chosen here and nowhere else: it is a pyusb backend handed to the same
`Camera.open` that talks to real hardware. `emulator:FILE.tofcap` is the emulated camera
replaying a capture (`tofcut.sim.replay`); `FILE.tofcap` alone is read by `CaptureReader`.
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tofcut.driver.belt import KnownBelt
from tofcut.driver.camera import Camera
from tofcut.driver.capture import MAGIC, CaptureReader
from tofcut.driver.config import CameraConfig
from tofcut.driver.errors import ConfigError, TofcutError
from tofcut.driver.events import DeviceEvent
from tofcut.driver.protocol import MAX_SENSOR_SIDE
from tofcut.sim.catalog import open_scene
from tofcut.sim.device import EMULATOR_SERIAL, EmulatedCamera, EmulatedDevice
from tofcut.sim.pattern import TestPattern
from tofcut.sim.process import EmulatorProcess
from tofcut.sim.renderer import SceneSource
from tofcut.sim.replay import CaptureReplay, ReplayIndex, read_index
from tofcut.sim.scene_file import SceneError, UnknownScene
from tofcut.sim.source import TapSource
from tofcut.sim.usb_backend import EmulatedBackend

TEST_PATTERN = "test-pattern"
DEFAULT_SCENE = "conveyor"
FAST_HOST_EPOCH_NS = 1_767_225_600 * 1_000_000_000
"""The host time (2026-01-01 00:00 UTC) at which a fast emulated camera's virtual clock
starts, when the run's host clock follows it (`open_source(..., virtual_host_clock=True)`)."""


class SourceError(TofcutError, ValueError):
    """A camera or source name that does not name anything."""


@dataclass(frozen=True)
class SourceSpec:
    """A parsed source name."""

    kind: str
    """'usb', 'emulator' or 'capture'."""
    arg: str | None = None
    """Serial number, scene name, or capture path."""

    @classmethod
    def parse(cls, text: str) -> SourceSpec:
        kind, _, arg = text.partition(":")
        if kind in ("usb", "emulator"):
            return cls(kind, arg or None)
        if Path(text).suffix == ".tofcap" or Path(text).is_file():
            return cls("capture", text)
        raise SourceError(
            f"{text!r} is not a source: use usb, usb:SERIAL, emulator[:SCENE] or FILE.tofcap"
        )

    def __str__(self) -> str:
        return self.kind if self.arg is None else f"{self.kind}:{self.arg}"


def scene_recipe(name: str | None, seed: int = 0) -> Callable[[], TapSource]:
    """What makes the emulator's scene (picklable: an emulator process makes its own)."""
    name = name or DEFAULT_SCENE
    if name == TEST_PATTERN:
        return functools.partial(TestPattern, 176, 144, seed=seed)
    return functools.partial(open_scene, name, seed)


def scene_source(name: str | None, seed: int = 0) -> TapSource:
    """The emulator's scene: a built-in name, a scene file, or the small test pattern."""
    try:
        return scene_recipe(name, seed)()
    except UnknownScene as exc:
        raise SourceError(f"{exc}, or {TEST_PATTERN}") from None
    except SceneError as exc:
        raise SourceError(str(exc)) from None


@dataclass(frozen=True, eq=False)
class Opened:
    """An opened source, and the emulated device behind it when there is one (ground truth)."""

    device: Camera | CaptureReader
    emulator: EmulatedDevice | None = None
    """The emulated camera, in this process or in its own (`EmulatorProcess`)."""
    metadata: dict[str, Any] = field(default_factory=dict)
    """What the emulated scene tells the tracker (belt, marked target); kept in captures."""
    bus: EmulatedBackend | None = None
    """The emulated camera's bus (to unplug and replug it: the soak's faults)."""
    replay: ReplayIndex | None = None
    """The capture the emulated camera replays (`emulator:FILE.tofcap`), else None."""
    end_of_replay: EndOfReplay | None = None
    """What stops the camera's stream when the replayed capture ends."""

    def close(self) -> None:
        """Close the device, then end the emulator's process if it has one."""
        try:
            if self.end_of_replay is not None:
                self.end_of_replay.close()
            self.device.close()
        finally:
            if isinstance(self.emulator, EmulatorProcess):
                self.emulator.close()


class EndOfReplay:
    """Ends a replaying camera's stream with its capture: a thread waits for the emulated
    camera's `replay_done` (its last frame sent, and more asked for) and stops the camera,
    so that `frames()` ends there as `CaptureReader.frames()` does. It holds the camera
    weakly: a camera dropped unclosed (`tofcut.open`) is still collected, its emulator's
    process with it, and the thread ends."""

    def __init__(self, camera: Camera, done: threading.Event) -> None:
        self._camera = weakref.ref(camera)
        self._done = done
        self._closing = False
        weakref.finalize(camera, done.set)
        self._thread = threading.Thread(target=self._run, name="tofcut-replay-end", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            self._done.wait()
            camera = self._camera()
            if self._closing or camera is None:
                return
            self._done.clear()
            with contextlib.suppress(TofcutError):  # gone meanwhile: the reading ends anyway
                camera.stop()
            del camera

    def close(self) -> None:
        self._closing = True
        self._done.set()
        self._thread.join()


def names_capture(arg: str | None) -> bool:
    """Whether `emulator:ARG` names a capture to replay: a `.tofcap` name, or a file that
    starts as one."""
    if arg is None:
        return False
    path = Path(arg)
    if path.suffix == ".tofcap":
        return True
    try:
        with path.open("rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def scene_metadata(source: TapSource) -> dict[str, Any]:
    """The installation facts of an emulated scene: its name, belt and marked target."""
    if not isinstance(source, SceneSource):
        return {}
    meta: dict[str, Any] = {"scene": source.name}
    if source.belt is not None:
        meta["belt"] = source.belt.to_dict()
    if source.target is not None:
        meta["target_pixel"] = list(source.target.seed_pixel)
    return meta


def belt_of(meta: dict[str, Any], source: str = "capture") -> KnownBelt | None:
    """The belt in a capture's (`source="capture"`) or a scene's (`"scene"`) metadata, or
    None; every value checked (`SourceError`, one line, if one is off)."""
    if "belt" not in meta:
        return None
    try:
        return KnownBelt.from_dict(meta["belt"], source)
    except ConfigError as exc:
        whose = "capture's" if source == "capture" else "scene's"
        raise SourceError(f"the belt in the {whose} metadata is unusable: {exc}") from None


def scene_target(meta: dict[str, Any]) -> tuple[int, int] | None:
    """The marked target's seed pixel (u, v) from scene or capture metadata, or None when
    there is none; `SourceError` (one line) when it is not a pixel of the image."""
    seed = meta.get("target_pixel")
    if seed is None:
        return None
    width, height = meta.get("width", MAX_SENSOR_SIDE), meta.get("height", MAX_SENSOR_SIDE)
    if not (
        isinstance(seed, list)
        and len(seed) == 2
        and all(isinstance(x, int) and not isinstance(x, bool) for x in seed)
        and isinstance(width, int)
        and isinstance(height, int)
        and 0 <= seed[0] < width
        and 0 <= seed[1] < height
    ):
        raise SourceError(f"the metadata's target_pixel is not a pixel of the image: {seed!r:.40}")
    return (seed[0], seed[1])


def configure(opened: Opened, config: CameraConfig | None) -> None:
    """Set an opened camera's configuration (None: leave it as it is). For an emulated camera
    replaying a capture, a setting the capture cannot be replayed at is a `SourceError`
    that says why, before anything is written (the camera itself would stall the write)."""
    if config is None:
        return
    camera = opened.device
    assert isinstance(camera, Camera)
    if opened.replay is not None:
        registers = config.registers()
        for register, value in registers.items():
            if why := opened.replay.refusal(register, value, registers):
                raise SourceError(why)
    camera.configure(config)


def open_source(
    spec: SourceSpec,
    *,
    realtime: bool = True,
    seed: int = 0,
    amplitude_threshold: float = 0.0,
    reconnect: bool = False,
    on_event: Callable[[DeviceEvent], None] | None = None,
    virtual_host_clock: bool = False,
    own_process: bool | None = None,
    loop: bool = False,
    serial: int | None = None,
) -> Opened:
    """Open a USB or emulated camera, or a capture that replays like one.

    `reconnect` makes a camera's stream outlive unplugs, stalls and hangs (else they raise);
    `on_event` gets the camera's device events, on the thread that reads frames. With
    `virtual_host_clock`, an emulated camera that is not `realtime` stamps frames with its
    own virtual clock (from `FAST_HOST_EPOCH_NS`) instead of the host's, so that a fast run
    is the same, bit for bit, every time; not for a run with a conveyor link, whose readings
    are stamped on the host's clock. `own_process` runs an emulated camera in a process of
    its own (`EmulatorProcess`), so that rendering its scene does not take the tracker's
    core; by default it does when it runs in real time (where the host must keep up), and
    not when it is not (no clock to keep up with, and no process to start). `loop` replays
    an emulated camera's capture over and over. An emulated camera has the serial number
    `serial` if given (several on one host need their own), else its scene's default or its
    capture's. Close the result with `Opened.close()`.
    """
    if spec.kind == "capture":
        assert spec.arg is not None
        return Opened(CaptureReader(spec.arg, amplitude_threshold=amplitude_threshold))
    if spec.kind == "usb":
        camera = Camera.open(
            spec.arg, amplitude_threshold=amplitude_threshold, reconnect=reconnect,
            on_event=on_event,
        )  # fmt: skip
        return Opened(camera)
    if own_process is None:
        own_process = realtime and os.name == "posix"
    replay = None
    emulator: EmulatedDevice
    if names_capture(spec.arg):
        assert spec.arg is not None
        replay = read_index(spec.arg)
        recipe = functools.partial(CaptureReplay, replay, loop=loop)
        firmware = replay.firmware
        serial = replay.serial if serial is None else serial
        if own_process:
            emulator = EmulatorProcess(recipe, realtime=realtime, serial=serial, firmware=firmware)
        else:
            emulator = EmulatedCamera(recipe(), realtime=realtime, serial=serial, firmware=firmware)
        metadata = replay.installation
    else:
        source = scene_source(spec.arg, seed)
        registers = source.settings.registers if isinstance(source, SceneSource) else None
        serial = EMULATOR_SERIAL if serial is None else serial
        if own_process:
            emulator = EmulatorProcess(
                scene_recipe(spec.arg, seed), source=source, realtime=realtime,
                registers=registers, serial=serial,
            )  # fmt: skip
        else:
            emulator = EmulatedCamera(source, realtime=realtime, registers=registers, serial=serial)
        metadata = scene_metadata(source)
    backend = EmulatedBackend([emulator])
    clock_ns = time.time_ns
    if virtual_host_clock and not realtime:
        clock_ns = lambda: FAST_HOST_EPOCH_NS + emulator.now_us() * 1000  # noqa: E731
    try:
        camera = Camera.open(
            backend=backend, amplitude_threshold=amplitude_threshold, reconnect=reconnect,
            on_event=on_event, clock_ns=clock_ns,
        )  # fmt: skip
    except BaseException:
        if isinstance(emulator, EmulatorProcess):
            emulator.close()
        raise
    end = None if replay is None else EndOfReplay(camera, emulator.replay_done)
    return Opened(camera, emulator, metadata, backend, replay, end)
