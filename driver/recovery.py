"""Getting a camera back: where to look for it, how long to wait between looks, when to give up.

The wait between looks is a function that takes the delay and an Event that `stop()` or
`close()` sets; the default waits on that Event, so a stop ends the wait at once, and a
test can pass its own function to wait without sleeping.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from tofcut.driver.errors import DeviceNotFound
from tofcut.driver.transport import UsbTransport, describe, find_devices

Waiter = Callable[[float, threading.Event], None]
"""wait(seconds, cancel): return after `seconds`, or as soon as `cancel` is set."""


def wait_or_cancel(seconds: float, cancel: threading.Event) -> None:
    """The real wait: sleeps, but wakes the moment `cancel` is set."""
    cancel.wait(seconds)


@dataclass(frozen=True)
class ReconnectPolicy:
    """How the driver recovers a camera that went away, hung, or kept stalling."""

    first_delay_s: float = 0.05
    """Wait before the second look for the camera; it doubles after each miss..."""
    max_delay_s: float = 1.0
    """...up to this, so a camera that comes back is found within about this long."""
    give_up_after_s: float | None = None
    """Stop looking after waiting this long in total (None: look until stopped)."""
    silence_s: float = 2.0
    """In free run, this long without a frame (and at least three frame periods) means the
    camera hung: it is reset and reopened."""
    stalls_before_reset: int = 3
    """Stalls of the frame endpoint in a row, with no frame between, before a reset."""
    wait: Waiter = field(default=wait_or_cancel, compare=False, repr=False)

    def delays(self) -> Iterator[float]:
        """The waits between looks: doubling from `first_delay_s`, capped at `max_delay_s`."""
        delay = self.first_delay_s
        while True:
            yield delay
            delay = min(2.0 * delay, self.max_delay_s)


@dataclass(frozen=True)
class DeviceLocator:
    """Where to look for a camera: the pyusb backend and the USB ids."""

    backend: Any
    vendor_id: int
    product_id: int

    def open(self, serial: str | None) -> UsbTransport:
        """Open the camera with this serial number (any bus address), or the first one found."""
        devices = find_devices(
            vendor_id=self.vendor_id, product_id=self.product_id, backend=self.backend
        )
        if serial is not None:
            devices = [d for d in devices if describe(d).serial == serial.upper()]
        if not devices:
            which = f" with serial {serial}" if serial else ""
            raise DeviceNotFound(
                f"no camera {self.vendor_id:04x}:{self.product_id:04x}{which} found"
            )
        return UsbTransport(devices[0])
