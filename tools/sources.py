"""Naming a camera on the command line: `usb`, `usb:SERIAL`, `emulator[:SCENE]`, or a capture.

The emulator is chosen here and nowhere else: it is a pyusb backend handed to the same
`Camera.open` that talks to real hardware.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tofcut.driver.camera import Camera
from tofcut.driver.capture import CaptureReader
from tofcut.driver.errors import TofcutError
from tofcut.sim.catalog import open_scene
from tofcut.sim.device import EmulatedCamera
from tofcut.sim.pattern import TestPattern
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import SceneError
from tofcut.sim.source import TapSource
from tofcut.sim.usb_backend import EmulatedBackend

TEST_PATTERN = "test-pattern"
DEFAULT_SCENE = "conveyor"


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


def scene_source(name: str | None, seed: int = 0) -> TapSource:
    """The emulator's scene: a built-in name, a scene file, or the small test pattern."""
    name = name or DEFAULT_SCENE
    if name == TEST_PATTERN:
        return TestPattern(176, 144, seed=seed)
    try:
        return open_scene(name, seed)
    except SceneError as exc:
        raise SourceError(f"{exc} (or {TEST_PATTERN})") from None


@dataclass(frozen=True, eq=False)
class Opened:
    """An opened source, and the emulated device behind it when there is one (ground truth)."""

    device: Camera | CaptureReader
    emulator: EmulatedCamera | None = None


def open_source(
    spec: SourceSpec, *, realtime: bool = True, seed: int = 0, amplitude_threshold: float = 0.0
) -> Opened:
    """Open a USB or emulated camera, or a capture that replays like one."""
    if spec.kind == "capture":
        assert spec.arg is not None
        return Opened(CaptureReader(spec.arg, amplitude_threshold=amplitude_threshold))
    if spec.kind == "usb":
        return Opened(Camera.open(spec.arg, amplitude_threshold=amplitude_threshold))
    source = scene_source(spec.arg, seed)
    registers = source.settings.registers if isinstance(source, SceneSource) else None
    emulator = EmulatedCamera(source, realtime=realtime, registers=registers)
    backend = EmulatedBackend([emulator])
    camera = Camera.open(backend=backend, amplitude_threshold=amplitude_threshold)
    return Opened(camera, emulator)
