"""The emulated hardware: a camera behind pyusb, the scenes it sees, and the conveyor."""

from tofcut.sim.catalog import open_scene, scene_names
from tofcut.sim.device import EmulatedCamera
from tofcut.sim.pattern import TestPattern
from tofcut.sim.renderer import SceneSource
from tofcut.sim.source import Exposure, Rendered, TapSource
from tofcut.sim.truth import FrameTruth, ObjectTruth, load_truth, save_truth
from tofcut.sim.usb_backend import EmulatedBackend

__all__ = [
    "EmulatedBackend",
    "EmulatedCamera",
    "Exposure",
    "FrameTruth",
    "ObjectTruth",
    "Rendered",
    "SceneSource",
    "TapSource",
    "TestPattern",
    "load_truth",
    "open_scene",
    "save_truth",
    "scene_names",
]
