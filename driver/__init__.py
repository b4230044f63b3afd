"""The hardware a run talks to: the camera (USB transport, wire protocol, demodulation and
captures) and the conveyor (`driver.conveyor`: its Modbus link, map, exposure clock, log and
reject rules), with the values both share (`belt`, `frames`, `errors`).

The camera's layers, bottom up: `transport` (pyusb) → `protocol` (bytes) → `stream` (frames
from bytes) → `demod` (taps to range and points) → `camera` / `capture` (the things you
open). The driver imports nothing of the emulator, the tracker or the tools.
"""

from tofcut.driver.calibration import Calibration, parse_calibration, pixel_rays
from tofcut.driver.camera import Camera, list_cameras
from tofcut.driver.capture import CaptureReader, CaptureWriter, capture_metadata
from tofcut.driver.config import CameraConfig, TriggerMode
from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.errors import (
    AccessDenied,
    CaptureError,
    ConfigError,
    DeviceBusy,
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    FrameInputError,
    ProtocolError,
    RequestRejected,
    TofcutError,
)
from tofcut.driver.events import DeviceEvent, EventKind
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.intrinsics import Intrinsics
from tofcut.driver.protocol import DeviceInfo, FrameHeader, Register
from tofcut.driver.recovery import ReconnectPolicy
from tofcut.driver.stream import FrameParser, StreamStats

__all__ = [
    "AccessDenied",
    "Calibration",
    "Camera",
    "CameraConfig",
    "CaptureError",
    "CaptureReader",
    "CaptureWriter",
    "ConfigError",
    "DeviceBusy",
    "DeviceError",
    "DeviceEvent",
    "DeviceInfo",
    "DeviceNotFound",
    "DeviceTimeout",
    "Disconnected",
    "EventKind",
    "Frame",
    "FrameHeader",
    "FrameInputError",
    "FrameParser",
    "Intrinsics",
    "Optics",
    "ProtocolError",
    "RawFrame",
    "ReconnectPolicy",
    "Register",
    "RequestRejected",
    "StreamStats",
    "TofcutError",
    "TriggerMode",
    "capture_metadata",
    "demodulate",
    "list_cameras",
    "parse_calibration",
    "pixel_rays",
]
