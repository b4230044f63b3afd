"""The USB layer: finding cameras with pyusb, control and bulk transfers, errors wrapped.

Any pyusb backend works here: libusb on a real machine, or the emulated camera's
backend from `tofcut.sim`, passed as `backend=` exactly as to `usb.core.find`.
"""

from __future__ import annotations

import array
import errno as errno_codes
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import usb.core
import usb.util

from tofcut.driver.errors import (
    UDEV_HINT,
    AccessDenied,
    DeviceBusy,
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    RequestRejected,
)
from tofcut.driver.protocol import (
    ENDPOINT_FRAMES,
    INTERFACE,
    PRODUCT_ID,
    REQ_TYPE_IN,
    REQ_TYPE_OUT,
    VENDOR_ID,
)

T = TypeVar("T")
CONTROL_TIMEOUT_MS = 1000

_DISCONNECTED = {errno_codes.ENODEV, errno_codes.ENXIO, errno_codes.ESHUTDOWN}


def wrap_usb_error(exc: usb.core.USBError, what: str) -> DeviceError:
    """Map a pyusb error to tofcut's hierarchy, keeping its errno."""
    code = exc.errno
    if isinstance(exc, usb.core.USBTimeoutError) or code == errno_codes.ETIMEDOUT:
        return DeviceTimeout(f"{what}: timed out", code)
    if code == errno_codes.EPIPE:
        return RequestRejected(f"{what}: the camera stalled the request", code)
    if code in _DISCONNECTED:
        return Disconnected(f"{what}: the camera is gone ({exc.strerror})", code)
    if code == errno_codes.EACCES:
        return AccessDenied(f"{what}: access denied; {UDEV_HINT}", code)
    if code == errno_codes.EBUSY:
        return DeviceBusy(f"{what}: the camera is in use by another program", code)
    return DeviceError(f"{what}: {exc.strerror or exc}", code)


def _call(what: str, fn: Callable[[], T]) -> T:
    try:
        return fn()
    except usb.core.USBError as exc:
        raise wrap_usb_error(exc, what) from exc


@dataclass(frozen=True)
class UsbId:
    """Where a camera sits on the bus, and who it says it is."""

    vendor_id: int
    product_id: int
    bus: int | None
    address: int | None
    serial: str | None
    """From the string descriptor; None when the device could not be asked."""
    firmware: int
    """bcdDevice."""


def find_devices(
    *, vendor_id: int = VENDOR_ID, product_id: int = PRODUCT_ID, backend: Any = None
) -> list[Any]:
    """All pyusb devices with this vendor/product id, on the given pyusb backend."""
    try:
        found = usb.core.find(
            find_all=True, idVendor=vendor_id, idProduct=product_id, backend=backend
        )
        return list(found or [])
    except usb.core.NoBackendError as exc:
        raise DeviceNotFound(
            "no USB backend: install libusb-1.0 (e.g. 'apt install libusb-1.0-0'), "
            "or use the emulated camera ('emulator')"
        ) from exc
    except usb.core.USBError as exc:
        raise wrap_usb_error(exc, "enumerating USB devices") from exc


def describe(device: Any) -> UsbId:
    """The ids of a pyusb device; the serial number is read if the device lets us."""
    try:
        serial = device.serial_number
    except (usb.core.USBError, ValueError):
        serial = None
    return UsbId(
        device.idVendor, device.idProduct, device.bus, device.address, serial, device.bcdDevice
    )


class UsbTransport:
    """One opened camera: vendor control transfers and bulk reads of the frame endpoint."""

    def __init__(self, device: Any) -> None:
        self._dev = device
        self.ids = describe(device)
        self._claimed = False
        try:
            _call("configuring the camera", self._configure)
        except DeviceError:
            self.close()  # e.g. another program holds it: let go of the handle we opened
            raise

    def _configure(self) -> None:
        dev = self._dev
        try:
            if dev.is_kernel_driver_active(INTERFACE):
                dev.detach_kernel_driver(INTERFACE)
        except (NotImplementedError, usb.core.USBError):
            pass  # not every backend or OS has kernel drivers to detach
        try:
            active = dev.get_active_configuration()
        except usb.core.USBError:
            active = None
        if active is None or active.bConfigurationValue != 1:
            dev.set_configuration(1)
        usb.util.claim_interface(dev, INTERFACE)
        self._claimed = True

    def control_in(self, request: int, value: int, index: int, length: int) -> bytes:
        data = _call(
            f"control request 0x{request:02x}",
            lambda: self._dev.ctrl_transfer(
                REQ_TYPE_IN, request, value, index, length, CONTROL_TIMEOUT_MS
            ),
        )
        return bytes(data)

    def control_out(self, request: int, value: int, index: int) -> None:
        _call(
            f"control request 0x{request:02x}",
            lambda: self._dev.ctrl_transfer(
                REQ_TYPE_OUT, request, value, index, None, CONTROL_TIMEOUT_MS
            ),
        )

    def read_frames(self, buffer: array.array[int], timeout_ms: int) -> int:
        """One bulk read of the frame endpoint into `buffer`; returns the bytes read."""
        n: int = _call(
            "reading frames", lambda: self._dev.read(ENDPOINT_FRAMES, buffer, timeout_ms)
        )
        return n

    def clear_halt(self) -> None:
        """Clear a stall of the frame endpoint (the bulk reads failed with EPIPE)."""
        _call("clearing the frame endpoint's stall", lambda: self._dev.clear_halt(ENDPOINT_FRAMES))

    def reset(self) -> None:
        """USB port reset: the camera restarts its firmware; this handle is done afterwards."""
        self._claimed = False
        _call("resetting the camera", self._dev.reset)

    def close(self) -> None:
        """Release the interface and the OS handle; safe to call twice or on a vanished device."""
        if self._claimed:
            self._claimed = False
            try:
                usb.util.release_interface(self._dev, INTERFACE)
            except usb.core.USBError:
                pass
        try:
            usb.util.dispose_resources(self._dev)
        except usb.core.USBError:
            pass
