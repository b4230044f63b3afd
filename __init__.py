"""tofcut: time-of-flight camera driver, emulator and graph-cut tracker.

What a Python user meets first (the rest lives in `tofcut.driver`, `tofcut.tracker`,
`tofcut.sim`):

- `tofcut.open(SOURCE)`: a camera or a capture by the names the command line uses (`usb`,
  `usb:SERIAL`, `emulator[:SCENE]`, `emulator:run.tofcap`, `run.tofcap`), each with the
  same `frames()`;
- `tofcut.Tracker`, whose one call is `update(frame) -> TrackedFrame`;
- the values that cross layers (`Frame`, `Track`, `TrackedFrame`) and the errors
  (`TofcutError` and its kinds);
- `Frame.from_arrays` and `Intrinsics`: a frame from any depth camera's arrays.

Names are imported when first used, so `import tofcut` stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

if TYPE_CHECKING:
    from tofcut.driver.camera import Camera
    from tofcut.driver.capture import CaptureReader
    from tofcut.driver.errors import TofcutError
    from tofcut.driver.frames import Frame
    from tofcut.driver.intrinsics import Intrinsics
    from tofcut.tracker.tracker import Tracker, TrackerParams
    from tofcut.tracker.tracks import Track, TrackedFrame

__all__ = [
    "Frame",
    "Intrinsics",
    "TofcutError",
    "Track",
    "TrackedFrame",
    "Tracker",
    "TrackerParams",
    "open",
]  # fmt: skip

_LAZY = {
    "Frame": "tofcut.driver.frames",
    "Intrinsics": "tofcut.driver.intrinsics",
    "TofcutError": "tofcut.driver.errors",
    "Tracker": "tofcut.tracker.tracker",
    "TrackerParams": "tofcut.tracker.tracker",
    "Track": "tofcut.tracker.tracks",
    "TrackedFrame": "tofcut.tracker.tracks",
}


def open(
    source: str = "emulator",
    *,
    seed: int = 0,
    realtime: bool = True,
    reconnect: bool = False,
    loop: bool = False,
) -> Camera | CaptureReader:
    """Open `source` as the command line names it: `usb` (the first camera), `usb:SERIAL`,
    `emulator[:SCENE]` (a built-in scene, a scene file or `family:conveyor:N`, set up with
    the scene's own camera settings; or `emulator:run.tofcap`, the emulated camera
    replaying a capture, its frames ending with it) or `run.tofcap` (a capture, read). Each
    has `frames()` and is a context manager; `seed`, `realtime` and `loop` (a replay starts
    again at its end) are the emulator's, `reconnect` a camera's (its stream outlives
    unplugs and stalls). A real-time emulator runs in a process of its own
    (`tofcut.sim.process.EmulatorProcess`), which ends when the camera is collected or
    Python exits. A name that is none of these is a `TofcutError`."""
    from tofcut.tools.pipeline.sources import SourceSpec, open_source

    return open_source(
        SourceSpec.parse(source), seed=seed, realtime=realtime, reconnect=reconnect, loop=loop
    ).device


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tofcut' has no attribute {name!r}")
