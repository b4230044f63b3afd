"""A SwissRanger-style TOF camera on USB: open, configure, stream frames.

    with Camera.open() as cam:            # first camera on the bus (libusb)
        cam.configure(CameraConfig.make(mod_freq_mhz=15, frame_rate=25))
        for frame in cam.frames(count=100):
            ...

Pass `backend=` (any pyusb backend, e.g. `tofcut.sim.EmulatedBackend`) to talk to an
emulated camera with exactly the same code.
"""

from __future__ import annotations

import array
import time
from collections import deque
from collections.abc import Iterator
from types import TracebackType
from typing import Any

from tofcut.driver.calibration import Calibration, parse_calibration
from tofcut.driver.config import CameraConfig
from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.errors import ConfigError, DeviceNotFound, DeviceTimeout, ProtocolError
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.protocol import (
    FLASH_BLOCK,
    INFO_SIZE,
    MAX_PACKET,
    PRODUCT_ID,
    VENDOR_ID,
    DeviceInfo,
    Register,
    Request,
    parse_info,
)
from tofcut.driver.stream import FrameParser, StreamStats
from tofcut.driver.transport import UsbId, UsbTransport, describe, find_devices

DEFAULT_READ_TIMEOUT_MS = 1000


def list_cameras(
    *, backend: Any = None, vendor_id: int = VENDOR_ID, product_id: int = PRODUCT_ID
) -> list[UsbId]:
    """Every camera on the bus (or on the given pyusb backend)."""
    return [
        describe(d)
        for d in find_devices(vendor_id=vendor_id, product_id=product_id, backend=backend)
    ]


class Camera:
    """One opened camera. Not thread-safe, except that `stats` may be read from anywhere."""

    def __init__(
        self,
        transport: UsbTransport,
        *,
        amplitude_threshold: float = 0.0,
        read_size: int | None = None,
    ) -> None:
        self._usb = transport
        self.amplitude_threshold = amplitude_threshold
        self.info: DeviceInfo = parse_info(transport.control_in(Request.GET_INFO, 0, 0, INFO_SIZE))
        self.calibration_block = self._read_flash()
        self.calibration: Calibration = parse_calibration(
            self.calibration_block, self.info.width, self.info.height
        )
        self.optics = Optics.from_calibration(self.calibration)
        self.stats = StreamStats()
        self._parser = FrameParser(self.info, self.stats)
        self._ready: deque[RawFrame] = deque()
        whole = -(-self.info.frame_size // MAX_PACKET) * MAX_PACKET
        if read_size is not None and (read_size <= 0 or read_size % MAX_PACKET):
            raise ConfigError(f"read_size must be a positive multiple of {MAX_PACKET} bytes")
        self._buffer = array.array("B", bytes(read_size or whole))
        self.streaming = False

    @classmethod
    def open(
        cls,
        serial: str | None = None,
        *,
        backend: Any = None,
        vendor_id: int = VENDOR_ID,
        product_id: int = PRODUCT_ID,
        amplitude_threshold: float = 0.0,
        read_size: int | None = None,
    ) -> Camera:
        """Open the camera with this serial number, or the first one found.

        `read_size` is the bulk read size (a multiple of 512); by default one whole frame.
        """
        devices = find_devices(vendor_id=vendor_id, product_id=product_id, backend=backend)
        ids = f"{vendor_id:04x}:{product_id:04x}"
        if serial is not None:
            devices = [d for d in devices if describe(d).serial == serial.upper()]
        if not devices:
            which = f" with serial {serial}" if serial else ""
            raise DeviceNotFound(f"no camera {ids}{which} found")
        return cls(
            UsbTransport(devices[0]),
            amplitude_threshold=amplitude_threshold,
            read_size=read_size,
        )

    # --- identity and registers -----------------------------------------------------------

    @property
    def serial(self) -> str:
        return self.info.serial_text

    def read_register(self, register: Register) -> int:
        data = self._usb.control_in(Request.READ_REG, 0, register, 2)
        if len(data) != 2:
            raise ProtocolError(f"register read returned {len(data)} bytes, expected 2")
        return int.from_bytes(data, "little")

    def write_register(self, register: Register, value: int) -> None:
        self._usb.control_out(Request.WRITE_REG, value, register)

    @property
    def config(self) -> CameraConfig:
        """The configuration as the camera's registers hold it now."""
        regs = {
            r: self.read_register(r)
            for r in (
                Register.MOD_FREQ,
                Register.INTEGRATION,
                Register.FRAME_PERIOD,
                Register.TRIGGER_MODE,
            )
        }
        return CameraConfig.from_registers(regs)

    def configure(self, config: CameraConfig) -> None:
        for register, value in config.registers().items():
            self.write_register(register, value)

    def temperature_c(self) -> float:
        raw = self.read_register(Register.TEMPERATURE)
        return (raw - 0x10000 if raw & 0x8000 else raw) / 100.0

    def _read_flash(self) -> bytes:
        size = self.info.calibration_size
        blocks = -(-size // FLASH_BLOCK)
        data = bytearray()
        for n in range(blocks):
            want = min(FLASH_BLOCK, size - n * FLASH_BLOCK)
            chunk = self._usb.control_in(Request.READ_FLASH, n, 0, FLASH_BLOCK)
            if len(chunk) != want:
                raise ProtocolError(f"flash block {n} returned {len(chunk)} bytes, expected {want}")
            data += chunk
        return bytes(data)

    # --- streaming ------------------------------------------------------------------------

    def start(self) -> None:
        self._usb.control_out(Request.STREAM, 1, 0)
        self.streaming = True

    def stop(self) -> None:
        """Stop streaming; a frame half received is discarded (and counted as skipped bytes)."""
        self.streaming = False
        self._usb.control_out(Request.STREAM, 0, 0)
        self._parser.reset()
        self._ready.clear()

    def trigger(self) -> None:
        """Take one frame (trigger mode 'software')."""
        self._usb.control_out(Request.TRIGGER, 0, 0)

    def read_raw(self, timeout_ms: int = DEFAULT_READ_TIMEOUT_MS) -> RawFrame:
        """The next whole, checked frame; raises DeviceTimeout if none comes in time."""
        deadline = time.monotonic() + timeout_ms / 1000.0
        while not self._ready:
            left_ms = max(1, round((deadline - time.monotonic()) * 1000.0))
            n = self._usb.read_frames(self._buffer, left_ms)
            if n:
                self._ready.extend(self._parser.feed(memoryview(self._buffer)[:n], time.time_ns()))
            if not self._ready and time.monotonic() >= deadline:
                raise DeviceTimeout(f"no frame within {timeout_ms} ms")
        return self._ready.popleft()

    def raw_frames(
        self, count: int | None = None, timeout_ms: int = DEFAULT_READ_TIMEOUT_MS
    ) -> Iterator[RawFrame]:
        """Raw frames while streaming (started here if it was not); `count` bounds them."""
        if not self.streaming:
            self.start()
        n = 0
        while count is None or n < count:
            yield self.read_raw(timeout_ms)
            n += 1

    def demodulate(self, raw: RawFrame) -> Frame:
        return demodulate(raw, self.optics, self.amplitude_threshold)

    def frames(
        self, count: int | None = None, timeout_ms: int = DEFAULT_READ_TIMEOUT_MS
    ) -> Iterator[Frame]:
        """Demodulated frames; see `raw_frames`."""
        for raw in self.raw_frames(count, timeout_ms):
            yield self.demodulate(raw)

    # --- lifetime -------------------------------------------------------------------------

    def close(self) -> None:
        if self.streaming:
            try:
                self.stop()
            except Exception:  # the camera may already be gone; closing must still work
                pass
        self._usb.close()

    def __enter__(self) -> Camera:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
