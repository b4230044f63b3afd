"""A SwissRanger-style TOF camera on USB: open, configure, stream frames.

    with Camera.open() as cam:            # first camera on the bus (libusb)
        cam.configure(CameraConfig.make(mod_freq_mhz=15, frame_rate=25))
        for frame in cam.frames(count=100):
            ...

Pass `backend=` (any pyusb backend, e.g. `tofcut.sim.EmulatedBackend`) to talk to an
emulated camera with exactly the same code. Pass `reconnect=True` for a stream that
outlives unplugs, hub resets, stalls and hangs (see `raw_frames`).
"""

from __future__ import annotations

import array
import errno
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

from tofcut._closing import Closing
from tofcut.driver.calibration import Calibration, parse_calibration
from tofcut.driver.config import FRAME_PERIOD_UNIT_S, CameraConfig, TriggerMode
from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.errors import (
    ConfigError,
    DeviceBusy,
    DeviceError,
    DeviceTimeout,
    Disconnected,
    ProtocolError,
    RequestRejected,
    TofcutError,
)
from tofcut.driver.events import DeviceEvent, EventKind
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.protocol import (
    FLASH_BLOCK,
    INFO_SIZE,
    MAX_PACKET,
    PRODUCT_ID,
    VENDOR_ID,
    WRITABLE_REGISTERS,
    DeviceInfo,
    Register,
    Request,
    parse_info,
)
from tofcut.driver.recovery import DeviceLocator, ReconnectPolicy
from tofcut.driver.stream import FrameParser, StreamStats
from tofcut.driver.transport import UsbId, UsbTransport, describe, find_devices

DEFAULT_READ_TIMEOUT_MS = 1000
READ_SLICE_MS = 200
"""Longest single bulk read: how long `stop()` or `close()` from another thread may wait."""


def list_cameras(
    *, backend: Any = None, vendor_id: int = VENDOR_ID, product_id: int = PRODUCT_ID
) -> list[UsbId]:
    """Every camera on the bus (or on the given pyusb backend)."""
    return [
        describe(d)
        for d in find_devices(vendor_id=vendor_id, product_id=product_id, backend=backend)
    ]


class Camera(Closing):
    """One opened camera.

    Frames are read on one thread; `stop()`, `close()` and `stats` may be used from any
    other (a stop ends a reading iteration, or a wait for the camera to come back, within
    one read slice). On a camera that is streaming, register access waits for the read
    in progress.
    """

    def __init__(
        self,
        transport: UsbTransport,
        *,
        amplitude_threshold: float = 0.0,
        read_size: int | None = None,
        locator: DeviceLocator | None = None,
        reconnect: ReconnectPolicy | None = None,
        on_event: Callable[[DeviceEvent], None] | None = None,
        clock_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        if reconnect is not None and locator is None:
            raise ConfigError("reconnecting needs to know where to look: use Camera.open")
        self._usb = transport
        self._connected = True
        self._locator = locator
        self.reconnect = reconnect
        """How the camera is recovered when it goes away; None: errors are raised."""
        self._clock_ns = clock_ns
        self._io = threading.RLock()
        self._cancel = threading.Event()
        self.amplitude_threshold = amplitude_threshold
        self.info: DeviceInfo = parse_info(transport.control_in(Request.GET_INFO, 0, 0, INFO_SIZE))
        self.calibration_block = self._read_flash()
        self.calibration: Calibration = parse_calibration(
            self.calibration_block, self.info.width, self.info.height
        )
        self.optics = Optics.from_calibration(self.calibration)
        self.stats = StreamStats(on_event=on_event)
        self._parser = FrameParser(self.info, self.stats)
        self._ready: deque[RawFrame] = deque()
        whole = -(-self.info.frame_size // MAX_PACKET) * MAX_PACKET
        if read_size is not None and (read_size <= 0 or read_size % MAX_PACKET):
            raise ConfigError(f"read_size must be a positive multiple of {MAX_PACKET} bytes")
        self._buffer = array.array("B", bytes(read_size or whole))
        self.streaming = False
        self._silent_ms = 0
        """Milliseconds of bulk reads that timed out since the last frame."""
        self._stalls_in_a_row = 0
        self._registers: dict[Register, int] = {}
        """The writable registers as last set: what a reconnect restores."""
        for register in sorted(WRITABLE_REGISTERS):
            self._set_remembered(register, self.read_register(register))

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
        reconnect: bool | ReconnectPolicy = False,
        on_event: Callable[[DeviceEvent], None] | None = None,
        clock_ns: Callable[[], int] = time.time_ns,
    ) -> Camera:
        """Open the camera with this serial number, or the first one found.

        `read_size` is the bulk read size (a multiple of 512); by default one whole frame.
        `reconnect` (True or a `ReconnectPolicy`) makes `raw_frames()` recover the camera
        by its serial number when it goes away. `on_event` is called with every
        `DeviceEvent` (also kept in `stats.events`); `clock_ns` is the host clock that
        stamps frames and events (ns since the epoch).
        """
        locator = DeviceLocator(backend, vendor_id, product_id)
        policy = ReconnectPolicy() if reconnect is True else reconnect or None
        transport = locator.open(serial)
        try:
            return cls(
                transport,
                amplitude_threshold=amplitude_threshold,
                read_size=read_size,
                locator=locator,
                reconnect=policy,
                on_event=on_event,
                clock_ns=clock_ns,
            )
        except BaseException:
            transport.close()
            raise

    # --- identity and registers -----------------------------------------------------------

    @property
    def serial(self) -> str:
        return self.info.serial_text

    def _device(self) -> UsbTransport:
        if not self._connected:
            raise Disconnected(f"camera {self.serial} is away; the driver is waiting for it")
        return self._usb

    def read_register(self, register: Register) -> int:
        with self._io:
            data = self._device().control_in(Request.READ_REG, 0, register, 2)
        if len(data) != 2:
            raise ProtocolError(f"register read returned {len(data)} bytes, expected 2")
        return int.from_bytes(data, "little")

    def write_register(self, register: Register, value: int) -> None:
        with self._io:
            self._device().control_out(Request.WRITE_REG, value, register)
            if register in WRITABLE_REGISTERS:
                self._set_remembered(Register(register), value)

    def _set_remembered(self, register: Register, value: int) -> None:
        """Keep a register's value for reconnects, and tell the parser the frame timing."""
        regs = self._registers
        regs[register] = value
        self._parser.periodic = regs.get(Register.TRIGGER_MODE) == TriggerMode.FREE_RUN
        asked_us = regs.get(Register.FRAME_PERIOD, 0) * FRAME_PERIOD_UNIT_S * 1e6
        fastest_us = 1e6 / self.info.max_fps if self.info.max_fps else 0.0
        self._parser.nominal_period_us = max(asked_us, fastest_us) or None

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
        with self._io:
            self._cancel.clear()
            self._device().control_out(Request.STREAM, 1, 0)
            self.streaming = True
            self._silent_ms = 0
            self._stalls_in_a_row = 0

    def stop(self) -> None:
        """Stop streaming; a frame half received is discarded (and counted as skipped bytes).

        Ends a `raw_frames()` iteration, and a wait for the camera to come back, also when
        called from another thread.
        """
        self._cancel.set()
        with self._io:
            self.streaming = False
            self._parser.reset()
            self._ready.clear()
            if self._connected:
                self._usb.control_out(Request.STREAM, 0, 0)

    def trigger(self) -> None:
        """Take one frame (trigger mode 'software')."""
        with self._io:
            self._device().control_out(Request.TRIGGER, 0, 0)

    def read_raw(self, timeout_ms: int = DEFAULT_READ_TIMEOUT_MS) -> RawFrame:
        """The next whole, checked frame; raises DeviceTimeout if none comes in time."""
        raw = self._read(timeout_ms, cancellable=False)
        assert raw is not None
        return raw

    def _read(self, timeout_ms: int, *, cancellable: bool) -> RawFrame | None:
        """Read slices of at most READ_SLICE_MS until a frame is whole; None when cancelled."""
        deadline = time.monotonic() + timeout_ms / 1000.0
        waited_ms = 0
        while not self._ready:
            with self._io:
                if cancellable and self._cancel.is_set():
                    return None
                slice_ms = max(1, min(READ_SLICE_MS, timeout_ms - waited_ms))
                try:
                    n = self._device().read_frames(self._buffer, slice_ms)
                except DeviceTimeout:
                    self.stats.read_timeouts += 1
                    self._silent_ms += slice_ms
                    waited_ms += slice_ms
                else:
                    got = self._parser.feed(memoryview(self._buffer)[:n], self._clock_ns())
                    if n < len(self._buffer):  # a short packet ended the transfer
                        self._parser.end_transfer()
                    self._ready.extend(got)
            if not self._ready and (waited_ms >= timeout_ms or time.monotonic() >= deadline):
                raise DeviceTimeout(f"no frame within {timeout_ms} ms", errno.ETIMEDOUT)
        self._silent_ms = 0
        self._stalls_in_a_row = 0
        return self._ready.popleft()

    def raw_frames(
        self, count: int | None = None, timeout_ms: int = DEFAULT_READ_TIMEOUT_MS
    ) -> Iterator[RawFrame]:
        """Raw frames while streaming (started here if it was not); `count` bounds them.

        The iteration ends when `stop()` or `close()` is called, from any thread. A stalled
        frame endpoint is cleared and reading goes on. With a reconnect policy the stream
        also outlives the camera going away (reopened by serial number, registers
        restored, streaming restarted), a hung camera (reset after `silence_s` without a
        frame) and an endpoint that keeps stalling; what that cost is in `stats` and its
        events. Without one, those raise `Disconnected`, `DeviceTimeout` (no frame within
        `timeout_ms`) or `RequestRejected`.
        """
        if not self.streaming and not self._start_streaming():
            return
        n = 0
        while count is None or n < count:
            raw = self._next_frame(timeout_ms)
            if raw is None:
                return
            yield raw
            n += 1

    def _start_streaming(self) -> bool:
        """Start, or with a policy recover a camera found gone; False if stopped meanwhile."""
        try:
            self.start()
        except DeviceError as exc:
            if self.reconnect is None:
                raise
            self.streaming = True  # what the reopened camera is to do
            return self._recover(self.reconnect, exc, "starting the stream failed")
        return True

    def _next_frame(self, timeout_ms: int) -> RawFrame | None:
        """The next frame, recovering from what can be recovered; None when stopped."""
        policy = self.reconnect
        while True:
            try:
                return self._read(timeout_ms, cancellable=True)
            except RequestRejected as exc:  # only the frame endpoint can stall here
                trouble: DeviceError = exc
                why = f"the frame endpoint stalled {self._stalls_in_a_row + 1} times in a row"
                stalls_allowed = policy.stalls_before_reset if policy else 1
                if self._stalls_in_a_row < stalls_allowed:
                    try:
                        self._clear_stall(exc)
                        continue
                    except DeviceError as failed:
                        trouble, why = failed, "clearing a stall failed"
            except DeviceTimeout as exc:
                if policy is None:
                    raise
                if not self._silent_too_long(policy):
                    continue
                trouble, why = exc, f"no frame for {self._silent_ms} ms"
            except Disconnected as exc:
                trouble, why = exc, "the camera went away"
            except DeviceError as exc:  # e.g. EIO when a cable is pulled mid-transfer
                trouble, why = exc, "reading frames failed"
            if policy is None:
                raise trouble
            if not self._recover(policy, trouble, why):
                return None

    def _silent_too_long(self, policy: ReconnectPolicy) -> bool:
        """In free run, a camera silent this long has hung (triggered ones may just wait)."""
        if not (self.streaming and self._parser.periodic):
            return False
        period_ms = (self._parser.period_us or 0.0) / 1000.0
        return self._silent_ms >= max(policy.silence_s * 1000.0, 3.0 * period_ms)

    def _clear_stall(self, exc: RequestRejected) -> None:
        with self._io:
            self._stalls_in_a_row += 1
            self._parser.reset()  # the frame in flight is gone; its number becomes a gap
            self._device().clear_halt()
            self.stats.stalls_cleared += 1
        self._note(EventKind.STALL_CLEARED, "the frame endpoint stalled; halt cleared", exc.errno)

    # --- recovery -------------------------------------------------------------------------

    def _note(self, kind: EventKind, detail: str, errno: int | None = None) -> None:
        self.stats.note(kind, self._clock_ns(), detail, errno)

    def _recover(self, policy: ReconnectPolicy, cause: DeviceError, why: str) -> bool:
        """Get the same camera back and streaming as before; False if stopped meanwhile."""
        self._note(EventKind.DISCONNECTED, f"{why}: {cause}", cause.errno)
        with self._io:
            self._parser.resume_after_outage(why)
            self._ready.clear()
            reset = False
            if self._connected and not isinstance(cause, Disconnected):
                try:  # a hung or stalling camera: restart its firmware
                    self._usb.reset()
                    reset = True
                except DeviceError:
                    pass  # gone, or re-enumerating: the search below finds it
            self._usb.close()
            self._connected = False
        if reset:
            self._note(EventKind.RESET, f"USB reset sent to camera {self.serial}")
        delays = policy.delays()
        waited = 0.0
        looks = 0
        busy_noted = False
        while True:
            with self._io:
                if self._cancel.is_set():
                    return False
                looks += 1
                try:
                    self._reopen()
                except DeviceBusy as exc:
                    busy = exc
                except DeviceError:
                    busy = None  # not back yet, or gone again while being set up
                else:
                    self.stats.reconnects += 1
                    self._silent_ms = 0
                    self._stalls_in_a_row = 0
                    ids = self._usb.ids
                    break
            if busy is not None and not busy_noted:
                busy_noted = True
                self._note(EventKind.DEVICE_BUSY, str(busy), busy.errno)
            delay = next(delays)
            limit = policy.give_up_after_s
            if limit is not None and waited + delay > limit:
                self._note(EventKind.GAVE_UP, f"camera {self.serial} not back after {waited:g} s")
                raise Disconnected(
                    f"camera {self.serial} did not come back within {limit:g} s", cause.errno
                ) from cause
            policy.wait(delay, self._cancel)
            waited += delay
        self._note(
            EventKind.RECONNECTED,
            f"camera {self.serial} back at bus {ids.bus} address {ids.address} after {looks} "
            f"looks and {waited:g} s of waiting; registers restored",
        )
        return True

    def _reopen(self) -> None:
        """Open the camera by serial number, check it, restore its registers and stream."""
        assert self._locator is not None
        transport = self._locator.open(self.serial)
        try:
            reply = transport.control_in(Request.GET_INFO, 0, 0, INFO_SIZE)
            try:
                info = parse_info(reply)
            except ProtocolError as exc:
                raise DeviceError(f"camera answered GET_INFO with garbage: {exc}") from exc
            if info != self.info:
                raise ProtocolError(f"camera {self.serial} came back as another device: {info}")
            for register, value in self._registers.items():
                transport.control_out(Request.WRITE_REG, value, register)
            if self.streaming:
                transport.control_out(Request.STREAM, 1, 0)
        except BaseException:
            transport.close()
            raise
        self._usb = transport
        self._connected = True

    # --- frames ---------------------------------------------------------------------------

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
        """Stop and let go of the camera; safe from another thread, twice, or when it is gone."""
        self._cancel.set()
        with self._io:
            if self.streaming and self._connected:
                try:
                    self._usb.control_out(Request.STREAM, 0, 0)
                except TofcutError:
                    pass  # the camera may already be gone; closing must still work
            self.streaming = False
            self._usb.close()
            self._connected = False
