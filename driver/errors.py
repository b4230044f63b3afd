"""The driver's exceptions: one small hierarchy, USB errno kept where there was one."""

from __future__ import annotations

UDEV_HINT = (
    "install the udev rule shipped with tofcut (udev/60-tofcut.rules) into /etc/udev/rules.d/, "
    "run 'udevadm control --reload && udevadm trigger', and replug the camera"
)


class TofcutError(Exception):
    """Base class of every error tofcut raises on purpose."""


class DeviceError(TofcutError):
    """A USB operation failed; `errno` is the OS error number when the transport gave one."""

    def __init__(self, message: str, errno: int | None = None) -> None:
        super().__init__(message)
        self.errno = errno


class DeviceNotFound(DeviceError):
    """No camera matched the vendor/product id or serial number asked for."""


class AccessDenied(DeviceError):
    """The OS refused access to the camera (usually a missing udev rule)."""


class DeviceBusy(DeviceError):
    """Another program holds the camera's interface."""


class RequestRejected(DeviceError):
    """The camera stalled a control request: unknown request or register, or a bad value."""


class DeviceTimeout(DeviceError):
    """The camera did not answer in time."""


class Disconnected(DeviceError):
    """The camera went away (unplugged, hub reset, power loss)."""


class ProtocolError(TofcutError):
    """Bytes from the camera or a file do not follow the wire protocol."""


class CaptureError(ProtocolError):
    """A capture file is not a valid .tofcap file."""


class ConfigError(TofcutError, ValueError):
    """A configuration value the camera cannot take."""


class FrameInputError(TofcutError, ValueError):
    """Arrays, intrinsics or times that cannot make a `Frame` (`Frame.from_arrays`)."""


class LinkError(DeviceError):
    """The conveyor controller's link (a serial port or a Modbus TCP gateway) cannot be opened."""
