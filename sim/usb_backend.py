"""A pyusb backend whose bus holds emulated cameras.

    backend = EmulatedBackend([EmulatedCamera(source)])
    usb.core.find(idVendor=0x0852, backend=backend)     # or Camera.open(backend=backend)

A camera on the bus is an `EmulatedCamera`, or one in a process of its own
(`tofcut.sim.process.EmulatorProcess`): the bus and the driver above it cannot tell.

Everything above pyusb — the driver — runs unchanged: descriptors are parsed by pyusb,
string descriptors are read with GET_DESCRIPTOR, and device errors surface as pyusb's
`USBError` with the errno libusb would give (EPIPE for a stall, ETIMEDOUT, ENODEV, EBUSY).

A test drives the bus: `unplug` and `replug` a camera (it comes back at a new address,
as after a real replug, and reboots if it lost power), or let another program `hold` it.
"""

from __future__ import annotations

import errno
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import usb.backend
import usb.core

from tofcut.driver.protocol import (
    ENDPOINT_FRAMES,
    INTERFACE,
    MANUFACTURER,
    MAX_PACKET,
    PRODUCT,
    PRODUCT_ID,
    VENDOR_ID,
)
from tofcut.sim.device import BulkOverflow, BulkTimeout, Detached, EmulatedDevice, Stall

_GET_DESCRIPTOR = 0x06
_DESC_DEVICE, _DESC_CONFIG, _DESC_STRING = 1, 2, 3
_LANG_EN_US = 0x0409
_STR_MANUFACTURER, _STR_PRODUCT, _STR_SERIAL = 1, 2, 3
_SPEED_HIGH = 3  # pyusb's SPEED_HIGH


class _Descriptor:
    """A plain attribute bag, the shape pyusb reads descriptors in."""

    def __init__(self, **fields: Any) -> None:
        self.__dict__.update(fields)


@dataclass(eq=False)
class Slot:
    """One camera plugged into the emulated bus."""

    camera: EmulatedDevice
    bus: int
    address: int
    vendor_id: int = VENDOR_ID
    product_id: int = PRODUCT_ID
    plugged: bool = True
    claimed_by: object | None = None
    configuration: int = 0


@dataclass(eq=False)
class _Handle:
    slot: Slot


class _OtherProgram:
    """Stands for another process that claimed a camera's interface."""


def _usb_error(code: int, text: str) -> usb.core.USBError:
    if code == errno.ETIMEDOUT:
        return usb.core.USBTimeoutError(text, None, code)
    return usb.core.USBError(text, None, code)


class EmulatedBackend(usb.backend.IBackend):  # type: ignore[misc]
    """A bus of emulated cameras behind pyusb's backend interface."""

    def __init__(self, cameras: Iterable[EmulatedDevice] = (), bus: int = 1) -> None:
        super().__init__()
        self._bus = bus
        self._lock = threading.Lock()
        self._slots: list[Slot] = []
        self._next_address = 1
        self._last_slot: dict[int, Slot] = {}
        for cam in cameras:
            self.plug(cam)

    # --- the bus, as a test or the CLI drives it ------------------------------------------

    def plug(
        self,
        camera: EmulatedDevice,
        vendor_id: int = VENDOR_ID,
        product_id: int = PRODUCT_ID,
        *,
        address: int | None = None,
    ) -> Slot:
        """Plug a camera in; it gets the next free address, as after a real replug, unless
        `address` says which."""
        with self._lock:
            if any(s.camera is camera for s in self._slots):
                raise ValueError("that camera is plugged in already")
            if address is None:
                address = self._next_address
                self._next_address += 1
            elif any(s.address == address for s in self._slots):
                raise ValueError(f"address {address} is taken")
            slot = Slot(camera, self._bus, address, vendor_id, product_id)
            self._slots.append(slot)
            self._last_slot[id(camera)] = slot
        camera.attach()
        return slot

    def unplug(self, camera: EmulatedDevice, *, power_loss: bool = True) -> None:
        """Pull the cable: open handles fail with ENODEV from now on. With `power_loss` (a
        bus-powered camera) the camera reboots when it is plugged in again."""
        with self._lock:
            for slot in self._slots:
                if slot.camera is camera and slot.plugged:
                    slot.plugged = False
            self._slots = [s for s in self._slots if s.plugged]
        camera.detach(power_loss=power_loss)

    def replug(self, camera: EmulatedDevice, *, address: int | None = None) -> Slot:
        """Plug an unplugged camera in again, with the USB ids it had."""
        last = self._last_slot[id(camera)]
        return self.plug(camera, last.vendor_id, last.product_id, address=address)

    def hold(self, camera: EmulatedDevice) -> None:
        """Another program claims the camera's interface: our claims fail with EBUSY."""
        slot = self._slot_of(camera)
        with self._lock:
            if slot.claimed_by is not None:
                raise _usb_error(errno.EBUSY, "Resource busy")
            slot.claimed_by = _OtherProgram()

    def release(self, camera: EmulatedDevice) -> None:
        """The other program lets go of the camera."""
        slot = self._slot_of(camera)
        with self._lock:
            if isinstance(slot.claimed_by, _OtherProgram):
                slot.claimed_by = None

    def _slot_of(self, camera: EmulatedDevice) -> Slot:
        with self._lock:
            for slot in self._slots:
                if slot.camera is camera:
                    return slot
        raise ValueError("that camera is not plugged in")

    @property
    def cameras(self) -> list[EmulatedDevice]:
        return [s.camera for s in self._slots]

    # --- IBackend -------------------------------------------------------------------------

    def enumerate_devices(self) -> list[Slot]:
        with self._lock:
            return list(self._slots)

    def get_device_descriptor(self, dev: Slot) -> _Descriptor:
        return _Descriptor(
            bLength=18,
            bDescriptorType=_DESC_DEVICE,
            bcdUSB=0x0200,
            bDeviceClass=0,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=64,
            idVendor=dev.vendor_id,
            idProduct=dev.product_id,
            bcdDevice=dev.camera.info.firmware,
            iManufacturer=_STR_MANUFACTURER,
            iProduct=_STR_PRODUCT,
            iSerialNumber=_STR_SERIAL,
            bNumConfigurations=1,
            address=dev.address,
            bus=dev.bus,
            port_number=dev.address,
            port_numbers=(dev.address,),
            speed=_SPEED_HIGH,
        )

    def get_configuration_descriptor(self, dev: Slot, config: int) -> _Descriptor:
        if config != 0:
            raise IndexError(config)
        return _Descriptor(
            bLength=9,
            bDescriptorType=_DESC_CONFIG,
            wTotalLength=9 + 9 + 7,
            bNumInterfaces=1,
            bConfigurationValue=1,
            iConfiguration=0,
            bmAttributes=0x80,
            bMaxPower=250,
            extra_descriptors=[],
        )

    def get_interface_descriptor(self, dev: Slot, intf: int, alt: int, config: int) -> _Descriptor:
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError((intf, alt, config))
        return _Descriptor(
            bLength=9,
            bDescriptorType=4,
            bInterfaceNumber=INTERFACE,
            bAlternateSetting=0,
            bNumEndpoints=1,
            bInterfaceClass=0xFF,
            bInterfaceSubClass=0,
            bInterfaceProtocol=0,
            iInterface=0,
            extra_descriptors=[],
        )

    def get_endpoint_descriptor(
        self, dev: Slot, ep: int, intf: int, alt: int, config: int
    ) -> _Descriptor:
        if (ep, intf, alt, config) != (0, 0, 0, 0):
            raise IndexError((ep, intf, alt, config))
        return _Descriptor(
            bLength=7,
            bDescriptorType=5,
            bEndpointAddress=ENDPOINT_FRAMES,
            bmAttributes=0x02,  # bulk
            wMaxPacketSize=MAX_PACKET,
            bInterval=0,
            bRefresh=0,
            bSynchAddress=0,
            extra_descriptors=[],
        )

    def open_device(self, dev: Slot) -> _Handle:
        self._check(dev)
        return _Handle(dev)

    def close_device(self, dev_handle: _Handle) -> None:
        slot = dev_handle.slot
        if slot.claimed_by is dev_handle:
            slot.claimed_by = None

    def set_configuration(self, dev_handle: _Handle, config_value: int) -> None:
        self._check(dev_handle.slot)
        if config_value not in (0, 1):
            raise _usb_error(errno.EINVAL, "no such configuration")
        dev_handle.slot.configuration = config_value

    def get_configuration(self, dev_handle: _Handle) -> int:
        self._check(dev_handle.slot)
        return dev_handle.slot.configuration

    def set_interface_altsetting(self, dev_handle: _Handle, intf: int, altsetting: int) -> None:
        self._check(dev_handle.slot)
        if (intf, altsetting) != (0, 0):
            raise _usb_error(errno.EINVAL, "no such alternate setting")

    def claim_interface(self, dev_handle: _Handle, intf: int) -> None:
        slot = dev_handle.slot
        self._check(slot)
        with self._lock:
            if slot.claimed_by is not None and slot.claimed_by is not dev_handle:
                raise _usb_error(errno.EBUSY, "Resource busy")
            slot.claimed_by = dev_handle

    def release_interface(self, dev_handle: _Handle, intf: int) -> None:
        slot = dev_handle.slot
        with self._lock:
            if slot.claimed_by is dev_handle:
                slot.claimed_by = None

    def is_kernel_driver_active(self, dev_handle: _Handle, intf: int) -> bool:
        return False

    def detach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        pass

    def clear_halt(self, dev_handle: _Handle, ep: int) -> None:
        self._check(dev_handle.slot)
        if ep != ENDPOINT_FRAMES:
            raise _usb_error(errno.EPIPE, "no such endpoint")
        dev_handle.slot.camera.clear_halt()

    def reset_device(self, dev_handle: _Handle) -> None:
        self._check(dev_handle.slot)
        dev_handle.slot.camera.usb_reset()

    def ctrl_transfer(
        self,
        dev_handle: _Handle,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: Any,
        timeout: int,
    ) -> int:
        slot = dev_handle.slot
        self._check(slot)
        kind = bmRequestType & 0x60
        device_to_host = bool(bmRequestType & 0x80)
        try:
            if kind == 0x00 and device_to_host and bRequest == _GET_DESCRIPTOR:
                reply = self._standard_descriptor(slot, wValue >> 8, wValue & 0xFF, wIndex)
            elif kind == 0x40:
                self._check_claimed(dev_handle)
                if device_to_host:
                    reply = slot.camera.control_in(bRequest, wValue, wIndex, len(data))
                else:
                    slot.camera.control_out(bRequest, wValue, wIndex, bytes(data))
                    return len(data)
            else:
                raise Stall("unsupported standard request")
        except Stall as exc:
            raise _usb_error(errno.EPIPE, f"Pipe error ({exc})") from None
        except BulkTimeout:
            raise _usb_error(errno.ETIMEDOUT, "Operation timed out") from None
        except Detached:
            raise _usb_error(
                errno.ENODEV, "No such device (it may have been disconnected)"
            ) from None
        n = min(len(reply), len(data))
        data[:n] = type(data)(data.typecode, reply[:n])
        return n

    def bulk_read(self, dev_handle: _Handle, ep: int, intf: int, buff: Any, timeout: int) -> int:
        slot = dev_handle.slot
        self._check(slot)
        self._check_claimed(dev_handle)
        if ep != ENDPOINT_FRAMES:
            raise _usb_error(errno.EPIPE, "no such endpoint")
        try:
            n = slot.camera.bulk_read_into(memoryview(buff).cast("B"), timeout)
        except BulkTimeout:
            raise _usb_error(errno.ETIMEDOUT, "Operation timed out") from None
        except BulkOverflow:
            raise _usb_error(errno.EOVERFLOW, "Overflow") from None
        except Stall:
            raise _usb_error(errno.EPIPE, "Pipe error (endpoint halted)") from None
        except Detached:
            raise _usb_error(
                errno.ENODEV, "No such device (it may have been disconnected)"
            ) from None
        self._check(slot)  # unplugged while we waited
        return n

    # --- helpers --------------------------------------------------------------------------

    def _check(self, slot: Slot) -> None:
        if not slot.plugged:
            raise _usb_error(errno.ENODEV, "No such device (it may have been disconnected)")

    def _check_claimed(self, handle: _Handle) -> None:
        owner = handle.slot.claimed_by
        if owner is not None and owner is not handle:
            raise _usb_error(errno.EBUSY, "Resource busy")

    def _standard_descriptor(self, slot: Slot, kind: int, index: int, lang: int) -> bytes:
        if kind != _DESC_STRING:
            raise Stall("only string descriptors are served by GET_DESCRIPTOR here")
        if index == 0:
            return bytes([4, _DESC_STRING]) + _LANG_EN_US.to_bytes(2, "little")
        text = {
            _STR_MANUFACTURER: MANUFACTURER,
            _STR_PRODUCT: PRODUCT,
            _STR_SERIAL: slot.camera.info.serial_text,
        }.get(index)
        if text is None:
            raise Stall(f"no string descriptor {index}")
        encoded = text.encode("utf-16-le")
        return bytes([2 + len(encoded), _DESC_STRING]) + encoded
