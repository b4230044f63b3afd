"""Test fixtures for projects built on tofcut: an emulated camera, an emulated conveyor
controller on a pseudo-terminal, and their faults as context managers (docs/testing.md).

`tofcut.testing.plugin` is the pytest plugin (pytest loads it by itself, through the
`pytest11` entry point): fixtures `tofcut_camera`, `tofcut_conveyor` and their factories.
Without pytest, `emulated_camera(...)` and `emulated_conveyor(...)` make the same rigs.

Names are imported when first used, so that loading the plugin imports nothing else.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tofcut.testing.camera import CameraRig, FaultWindow, emulated_camera
    from tofcut.testing.common import RigError
    from tofcut.testing.conveyor import ConveyorRig, emulated_conveyor

__all__ = [
    "CameraRig",
    "ConveyorRig",
    "FaultWindow",
    "RigError",
    "emulated_camera",
    "emulated_conveyor",
]

_LAZY = {
    "CameraRig": "tofcut.testing.camera",
    "FaultWindow": "tofcut.testing.camera",
    "emulated_camera": "tofcut.testing.camera",
    "RigError": "tofcut.testing.common",
    "ConveyorRig": "tofcut.testing.conveyor",
    "emulated_conveyor": "tofcut.testing.conveyor",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tofcut.testing' has no attribute {name!r}")
