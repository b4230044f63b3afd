"""The emulated camera's firmware: registers, flash, the frame clock, the FIFO and the bulk pipe.

It knows nothing of pyusb; `tofcut.sim.usb_backend` puts it on an emulated bus. Frames are
taken on the device's own clock (real time, or a virtual clock that runs as fast as the
host reads); frames the host does not fetch in time overflow the FIFO and are dropped,
leaving a gap in the sequence and the drop flag on the next frame, as the spec says.

Tests inject faults on command: damaged, cut short or lost packets (`damage_next`), a
stalled endpoint (`stall_endpoint`), reads that time out (`time_out_next`), a hung
firmware (`hang`), FIFO overflow (`overflow_fifo`), and power loss (`detach`/`attach`, which
the bus's `unplug`/`replug` call). Losing power is a reboot, as on a real camera: the
registers go back to their reset values, the sequence starts again at 0 and the device
clock at 0 µs. A USB port reset (`usb_reset`) restarts the firmware the same way.

Fed a `Recording` (`tofcut.sim.replay`) instead of a scene, it is the camera that made the
recording: its flash and registers, and each exposure sends the recorded frame of its time
(with the camera's own sequence, time and drop flag written in), faults and all.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tofcut.driver.calibration import pack_calibration
from tofcut.driver.errors import ProtocolError
from tofcut.driver.protocol import (
    FLAG_DROPPED_BEFORE,
    FLAG_OVER_TEMPERATURE,
    FLAG_SATURATED,
    FLASH_BLOCK,
    HEADER_SIZE,
    MAX_COUNT,
    MAX_FPS,
    MAX_PACKET,
    MOD_FREQ_MHZ,
    RESET_VALUES,
    STATUS_FIFO_OVERFLOW,
    STATUS_OVER_TEMPERATURE,
    STATUS_STREAMING,
    TAPS,
    WRITABLE_REGISTERS,
    DeviceInfo,
    FrameHeader,
    Register,
    Request,
    crc32,
    integration_us,
    pack_header,
    pack_info,
    parse_header,
)
from tofcut.sim.source import Exposure, Recording, Rendered, TapSource

READOUT_US = 200
"""Time between the end of one tap's integration and the start of the next."""
FIFO_FRAMES = 4
TRUTH_KEPT = 32
"""Frames whose truth is kept. A frame's truth is made as it goes on the wire and asked for as
it arrives (`tofcut record`, tests), so a few frames are plenty; 32 leave room for a host that
reads several frames a transfer, at about 200 KB each at 176×144 (labels and range)."""


class Stall(Exception):
    """The device answers a control request with a STALL (the host sees EPIPE)."""


class BulkTimeout(Exception):
    """No answer within the host's timeout (on the bulk pipe, or from a hung firmware)."""


class Detached(Exception):
    """The device is not on the bus (unplugged, or without power): the host sees ENODEV."""


class BulkOverflow(Exception):
    """The host asked for a length that is not a whole number of packets and data overran it."""


class ReplayEnded(BulkTimeout):
    """A replay has sent its last frame: no data, as from a camera that stopped sending."""


def register_value_ok(register: Register, value: int) -> bool:
    """Whether a writable register takes `value` (a u16 already)."""
    return {
        Register.MOD_FREQ: value in MOD_FREQ_MHZ,
        Register.INTEGRATION: 0 <= value <= 255,
        Register.FRAME_PERIOD: True,
        Register.TRIGGER_MODE: value in (0, 1, 2),
    }[register]


def frame_period_us(registers: dict[Register, int]) -> int:
    """Time between frame starts: as asked, but no faster than the taps or 54 fps allow."""
    tap_interval = integration_us(registers[Register.INTEGRATION]) + READOUT_US
    fastest = max(TAPS * tap_interval, math.ceil(1e6 / MAX_FPS))
    return max(registers[Register.FRAME_PERIOD] * 100, fastest)


class EmulatedDevice(Protocol):
    """An emulated camera as the bus and the tests use it: an `EmulatedCamera`, or its proxy
    in a process of its own (`tofcut.sim.process.EmulatorProcess`)."""

    @property
    def info(self) -> DeviceInfo: ...
    @property
    def realtime(self) -> bool: ...
    @property
    def source(self) -> TapSource | None: ...
    @property
    def frames_sent(self) -> int: ...
    @property
    def frames_dropped(self) -> int: ...
    @property
    def boots(self) -> int: ...
    @property
    def frame_period_us(self) -> int: ...
    @property
    def replay_done(self) -> threading.Event: ...
    def now_us(self) -> int: ...
    def control_in(self, request: int, value: int, index: int, length: int) -> bytes: ...
    def control_out(self, request: int, value: int, index: int, data: bytes) -> None: ...
    def bulk_read_into(self, out: memoryview, timeout_ms: int) -> int: ...
    def clear_halt(self) -> None: ...
    def usb_reset(self) -> None: ...
    def attach(self) -> None: ...
    def detach(self, *, power_loss: bool = True) -> None: ...
    def pulse_trigger_input(self) -> None: ...
    def damage_next(self, kind: str = "payload", count: int = 1) -> None: ...
    def stall_endpoint(self, count: int = 1, after_packets: int = 0) -> None: ...
    def time_out_next(self, count: int = 1) -> None: ...
    def hang(self) -> None: ...
    def overflow_fifo(self, frames: int) -> None: ...
    def truth(self, sequence: int) -> object | None: ...


@dataclass
class _Queued:
    sequence: int
    t0_us: int
    flags: int
    wire: bytes | None = None
    """The frame rendered and on its way to the wire (rendering ahead), else None."""
    recorded: int | None = None
    """A replay's recorded frame (`Recording.take`)."""


EMULATOR_SERIAL = 0x4000002F
"""An emulated camera's serial number unless it is given another (several on one host)."""


class EmulatedCamera:
    """One emulated SR-USB camera, fed by a scene (`TapSource`) or a `Recording`.

    `realtime=False` runs the frame clock virtually: every bulk read gets the next frame at
    once, with device timestamps as if the camera ran at its frame rate; nothing is dropped.
    The device clock (`now_us`) is then virtual too: it starts at 0 at power-on and stands at
    the end of the last frame's exposure, so no host time leaks into a fast run and two runs
    of one scene and seed give the same frames, bit for bit.

    `render_ahead` (real time only) renders each frame on a thread of the camera's own as
    its exposure ends, as a real sensor fills its FIFO whether or not the host is reading;
    without it a frame is rendered when the host reads it. The emulator's own process uses
    it, so that a host late to ask does not make the renderer late too. The thread lives as
    long as the process: not for a camera made and dropped in a long-lived one.

    A `Recording` gives the flash and the registers (`registers` is then not used); its
    frames are taken by the time of their exposure on a clock that runs on through reboots
    (while the camera is off in real time, the line goes on and its frames are missed), and
    the stream ends with the recording: once its last frame is sent a bulk read raises
    `ReplayEnded` and sets `replay_done`. A register write it cannot replay stalls.
    """

    def __init__(
        self,
        source: TapSource,
        *,
        serial: int = EMULATOR_SERIAL,
        firmware: int = 0x0104,
        realtime: bool = True,
        registers: dict[Register, int] | None = None,
        fifo_frames: int = FIFO_FRAMES,
        monotonic: Callable[[], float] = time.monotonic,
        render_ahead: bool = False,
    ) -> None:
        self.source = source
        calib = source.calibration
        self._recording = source if isinstance(source, Recording) else None
        self.flash = (
            pack_calibration(calib)
            if self._recording is None
            else self._recording.calibration_block
        )
        self.info = DeviceInfo(
            protocol=1,
            firmware=firmware,
            serial=serial,
            width=calib.width,
            height=calib.height,
            calibration_size=len(self.flash),
            max_fps=MAX_FPS,
        )
        self.realtime = realtime
        self.fifo_frames = fifo_frames
        self.temperature_c = 36.5
        self.over_temperature = False
        self._monotonic = monotonic
        self._power_on = self._created = monotonic()
        self._regs: dict[Register, int] = dict(RESET_VALUES)
        self._regs.update(registers or {} if self._recording is None else self._recording.registers)
        self._lock = threading.Condition()
        self._streaming = False
        self._next_seq = 0
        self._clock_start_us = 0
        self._clock_index = 0
        """Frames taken on the current run of the frame clock."""
        self._virtual_us = 0
        """The device clock when not `realtime`: the end of the last exposure taken."""
        self._fifo: deque[_Queued] = deque()
        self._drop_pending = False
        self._overflow_latched = False
        self._tx = b""
        self._tx_pos = 0
        self._zlp_pending = False
        self._truth: OrderedDict[int, object] = OrderedDict()
        self._damage: deque[str] = deque()
        self.frames_sent = 0
        self.frames_dropped = 0
        self._powered = True
        self._attached = True
        self._halted = False
        self._halts_left = 0
        self._packets_before_halt = 0
        self._timeouts_left = 0
        self._hung = False
        self.boots = 1
        """Times the firmware started: power-on, then once per power cycle or USB reset."""
        self._line_us_at_boot = 0
        """A replay's clock (`Recording.take`) when the firmware last started."""
        self._replay_ended = False
        self.replay_done = threading.Event()
        """Set when a replay has sent its last frame and the host asked for more."""
        self.render_ahead = render_ahead and realtime
        if self.render_ahead:
            threading.Thread(target=self._sensor, name="tofcut-sensor", daemon=True).start()

    # --- timing ---------------------------------------------------------------------------

    def now_us(self) -> int:
        """Device time: µs since power-on (virtual when not `realtime`: see the class)."""
        if not self.realtime:
            return self._virtual_us
        return int((self._monotonic() - self._power_on) * 1e6)

    @property
    def tap_interval_us(self) -> int:
        return integration_us(self._regs[Register.INTEGRATION]) + READOUT_US

    @property
    def frame_period_us(self) -> int:
        """Time between frame starts: as asked, but no faster than the taps or 54 fps allow."""
        return frame_period_us(self._regs)

    # --- control requests -----------------------------------------------------------------

    def _check_answering(self) -> None:
        if not (self._powered and self._attached):
            raise Detached
        if self._hung:
            raise BulkTimeout  # a hung firmware answers nothing (reported at once)

    def control_in(self, request: int, value: int, index: int, length: int) -> bytes:
        with self._lock:
            self._check_answering()
            if request == Request.GET_INFO and value == 0 and index == 0:
                return pack_info(self.info)[:length]
            if request == Request.READ_REG:
                return self._read_register(index).to_bytes(2, "little")[:length]
            if request == Request.READ_FLASH:
                start = value * FLASH_BLOCK
                if start >= len(self.flash):
                    raise Stall(f"flash block {value} is past the end")
                return self.flash[start : start + min(length, FLASH_BLOCK)]
            raise Stall(f"unknown IN request 0x{request:02x}")

    def control_out(self, request: int, value: int, index: int, data: bytes) -> None:
        with self._lock:
            self._check_answering()
            if data:
                raise Stall("OUT requests of this device carry no data stage")
            if request == Request.WRITE_REG:
                self._write_register(index, value)
            elif request == Request.STREAM and index == 0 and value in (0, 1):
                self._set_streaming(value == 1)
            elif request == Request.TRIGGER and value == 0 and index == 0:
                if self._regs[Register.TRIGGER_MODE] != 1 or not self._streaming:
                    raise Stall("TRIGGER needs trigger mode 1 and a started stream")
                self._take_frame(self.now_us())
                self._lock.notify_all()
            else:
                raise Stall(f"unknown OUT request 0x{request:02x}")

    def _read_register(self, address: int) -> int:
        if address == Register.STATUS:
            status = STATUS_STREAMING if self._streaming else 0
            if self.over_temperature:
                status |= STATUS_OVER_TEMPERATURE
            if self._overflow_latched:
                status |= STATUS_FIFO_OVERFLOW
                self._overflow_latched = False
            return status
        if address == Register.TEMPERATURE:
            return round(self.temperature_c * 100) & 0xFFFF
        try:
            return self._regs[Register(address)]
        except ValueError:
            raise Stall(f"no register 0x{address:02x}") from None

    def _write_register(self, address: int, value: int) -> None:
        try:
            register = Register(address)
        except ValueError:
            raise Stall(f"no register 0x{address:02x}") from None
        if register not in WRITABLE_REGISTERS:
            raise Stall(f"register {register.name} is read-only")
        if not register_value_ok(register, value):
            raise Stall(f"value {value} is out of range for {register.name}")
        if self._recording is not None and (
            why := self._recording.refusal(register, value, self._regs)
        ):
            raise Stall(why)
        self._regs[register] = value
        if self._streaming and register in (Register.FRAME_PERIOD, Register.INTEGRATION):
            self._restart_clock()

    def _set_streaming(self, on: bool) -> None:
        if on and not self._streaming:
            self._streaming = True
            self._fifo.clear()
            self._restart_clock()
        elif not on:
            self._streaming = False
            self._fifo.clear()
            self._tx = b""
            self._tx_pos = 0
            self._zlp_pending = False
        self._lock.notify_all()

    def _restart_clock(self) -> None:
        self._clock_start_us = self.now_us()
        self._clock_index = 0
        self._lock.notify_all()  # a sensor rendering ahead waits for the next frame's end

    # --- the frame clock and the FIFO -----------------------------------------------------

    def _take_frame(self, t0_us: int) -> None:
        """The sensor takes a frame: into the FIFO if there is room, else it is dropped."""
        recorded = None
        if self._recording is not None:
            if self._replay_ended:
                return
            take = self._recording.take(self._line_us_at_boot + t0_us)
            if take.ended:
                self._replay_ended = True
                self._lock.notify_all()
                return
            recorded = take.frame
        seq = self._next_seq
        self._next_seq = (seq + 1) & 0xFFFFFFFF
        if not self.realtime:  # the virtual clock stands where the exposure ends
            self._virtual_us = max(self._virtual_us, t0_us + TAPS * self.tap_interval_us)
        if self._recording is not None and recorded is None:
            return  # lost where it was recorded: numbered, never sent
        if len(self._fifo) >= self.fifo_frames:
            self.frames_dropped += 1
            self._drop_pending = True
            self._overflow_latched = True
            return
        flags = FLAG_DROPPED_BEFORE if self._drop_pending else 0
        self._drop_pending = False
        self._fifo.append(_Queued(seq, t0_us, flags, recorded=recorded))

    def _free_run_due(self) -> bool:
        return self._streaming and self._regs[Register.TRIGGER_MODE] == 0 and not self._replay_ended

    def _catch_up(self) -> None:
        """Take every free-run frame whose exposure has ended by now."""
        if not self._free_run_due():
            return
        period = self.frame_period_us
        duration = TAPS * self.tap_interval_us
        if not self.realtime:
            while not self._fifo and self._free_run_due():  # (a replay's lost frames send none)
                self._take_frame(self._clock_start_us + self._clock_index * period)
                self._clock_index += 1
            return
        done = (self.now_us() - duration - self._clock_start_us) // period + 1
        while self._clock_index < done and len(self._fifo) < self.fifo_frames:
            if not self._free_run_due():
                return  # a replay that ended
            self._take_frame(self._clock_start_us + self._clock_index * period)
            self._clock_index += 1
        dropped = done - self._clock_index
        if dropped > 0 and self._free_run_due():  # the FIFO is full: the later frames are lost
            self._next_seq = (self._next_seq + dropped) & 0xFFFFFFFF
            self._clock_index = done
            self.frames_dropped += dropped
            self._drop_pending = self._overflow_latched = True

    def _next_due_us(self) -> int | None:
        if not self._free_run_due():
            return None
        t0 = self._clock_start_us + self._clock_index * self.frame_period_us
        return t0 + TAPS * self.tap_interval_us

    def pulse_trigger_input(self) -> None:
        """A pulse on the hardware trigger input (trigger mode 2)."""
        with self._lock:
            if self._streaming and self._regs[Register.TRIGGER_MODE] == 2:
                self._take_frame(self.now_us())
                self._lock.notify_all()

    # --- power and the bus ---------------------------------------------------------------

    def detach(self, *, power_loss: bool = True) -> None:
        """The cable is pulled. With `power_loss` (a bus-powered camera) the firmware stops;
        without it only the USB side goes, and the stream stops as when the host stops it."""
        with self._lock:
            self._attached = False
            self._set_streaming(False)
            if power_loss:
                self._powered = False

    def attach(self) -> None:
        """The cable is plugged in again; a camera that lost power boots."""
        with self._lock:
            self._attached = True
            if not self._powered:
                self._boot()

    def usb_reset(self) -> None:
        """A USB port reset: the firmware restarts as after a power cycle."""
        with self._lock:
            self._set_streaming(False)
            self._boot()

    def _boot(self) -> None:
        """Power-on state: reset registers, sequence 0, device clock 0, no faults pending."""
        now = self._monotonic()
        if self.realtime:  # the line went on while the camera was off
            self._line_us_at_boot = int((now - self._created) * 1e6)
        else:
            self._line_us_at_boot += self._virtual_us
        self._powered = True
        self._power_on = now
        self._virtual_us = 0
        self._regs = dict(RESET_VALUES)
        if self._recording is not None:  # it powers on as the recording was made
            self._regs.update(self._recording.registers)
        self._next_seq = 0
        self._clock_start_us = 0
        self._clock_index = 0
        self._drop_pending = self._overflow_latched = False
        self._halted = False
        self._halts_left = self._packets_before_halt = self._timeouts_left = 0
        self._hung = False
        self.boots += 1
        self._lock.notify_all()

    # --- faults, injected by tests ---------------------------------------------------------

    DAMAGE_KINDS = ("payload", "header", "truncate", "drop-packet", "corrupt-packet")

    def damage_next(self, kind: str = "payload", count: int = 1) -> None:
        """Damage the next `count` frames on the wire: a flipped payload or header byte, a
        transfer cut short (it ends at half the frame), a 512-byte packet lost from the
        middle of the frame, or a packet there garbled."""
        if kind not in self.DAMAGE_KINDS:
            raise ValueError(f"damage kind {kind!r} is not one of {self.DAMAGE_KINDS}")
        with self._lock:
            self._damage.extend([kind] * count)

    def _apply_damage(self, wire: bytes) -> bytes:
        if not self._damage:
            return wire
        kind = self._damage.popleft()
        if kind == "truncate":
            return wire[: len(wire) // 2]
        if kind in ("drop-packet", "corrupt-packet"):
            start = (len(wire) // MAX_PACKET // 2) * MAX_PACKET
            packet = wire[start : start + MAX_PACKET]
            if kind == "drop-packet":
                return wire[:start] + wire[start + len(packet) :]
            noise = np.random.default_rng(len(self._damage)).integers(0, 256, len(packet))
            return wire[:start] + noise.astype(np.uint8).tobytes() + wire[start + len(packet) :]
        pos = HEADER_SIZE + len(wire) // 3 if kind == "payload" else 10
        return wire[:pos] + bytes([wire[pos] ^ 0x5A]) + wire[pos + 1 :]

    def stall_endpoint(self, count: int = 1, after_packets: int = 0) -> None:
        """Halt the frame endpoint after `after_packets` more packets: bulk reads fail with
        EPIPE until the host clears the halt, and a frame cut in flight is lost. It halts
        again on the first read after each clear, `count` times in all."""
        with self._lock:
            self._halts_left = count
            self._packets_before_halt = after_packets

    def clear_halt(self) -> None:
        """The host's CLEAR_FEATURE(ENDPOINT_HALT) on the frame endpoint."""
        with self._lock:
            self._halted = False

    def _halt(self) -> Stall:
        self._halted = True
        self._halts_left -= 1
        self._packets_before_halt = 0
        self._tx = b""
        self._tx_pos = 0
        self._zlp_pending = False
        return Stall("the frame endpoint is halted")

    def time_out_next(self, count: int = 1) -> None:
        """The next `count` bulk reads get no data before the host's timeout; nothing is lost
        unless the FIFO overflows meanwhile (on the real-time clock)."""
        with self._lock:
            self._timeouts_left += count

    def hang(self) -> None:
        """The firmware hangs: no bulk data, no control answers, until a reset or power cycle."""
        with self._lock:
            self._hung = True

    def overflow_fifo(self, frames: int) -> None:
        """The host fell behind by `frames` frames: they are dropped for want of FIFO room,
        so the sequence skips them and the next frame carries the drop flag."""
        with self._lock:
            self._next_seq = (self._next_seq + frames) & 0xFFFFFFFF
            self._clock_index += frames
            self.frames_dropped += frames
            self._drop_pending = self._overflow_latched = True

    # --- the bulk pipe --------------------------------------------------------------------

    def bulk_read(self, size: int, timeout_ms: int) -> bytes:
        """What one bulk IN transfer of `size` bytes returns."""
        deadline = self._monotonic() + timeout_ms / 1000.0
        with self._lock:
            while True:
                if not (self._powered and self._attached):
                    raise Detached
                if self._halted:
                    raise Stall("the frame endpoint is halted")
                if self._halts_left and self._packets_before_halt == 0:
                    raise self._halt()
                if self._hung or self._timeouts_left:
                    self._timeouts_left = max(0, self._timeouts_left - 1)
                    if self.realtime:
                        self._lock.wait(max(0.0, deadline - self._monotonic()))
                    if not (self._powered and self._attached):
                        raise Detached
                    raise BulkTimeout
                if self._zlp_pending:
                    self._zlp_pending = False
                    return b""
                if self._tx_pos < len(self._tx):
                    return self._send_piece(size)
                self._catch_up()
                if self._streaming and self._fifo and not self._rendering(self._fifo[0]):
                    queued = self._fifo.popleft()
                    wire = queued.wire if queued.wire is not None else self._build(queued)
                    self._tx = self._apply_damage(wire)
                    self._tx_pos = 0
                    continue
                wait = deadline - self._monotonic()
                if self._replay_ended and self._streaming and not self._fifo:
                    self.replay_done.set()  # what waits for the end stops the host meanwhile
                    if wait <= 0:
                        raise ReplayEnded
                    self._lock.wait(wait)
                    continue
                due = self._next_due_us()
                if not self.realtime and (due is None or not self._streaming):
                    wait = min(wait, 0.0)  # nothing will come; don't make tests wait
                if wait <= 0:
                    raise BulkTimeout
                if due is not None:
                    wait = min(wait, max(0.0, (due - self.now_us()) / 1e6))
                self._lock.wait(wait)

    def bulk_read_into(self, out: memoryview, timeout_ms: int) -> int:
        """One bulk IN transfer of up to `len(out)` bytes, landed in `out`."""
        piece = self.bulk_read(len(out), timeout_ms)
        out[: len(piece)] = piece
        return len(piece)

    def _send_piece(self, size: int) -> bytes:
        left = len(self._tx) - self._tx_pos
        if left > size and size % MAX_PACKET:
            raise BulkOverflow
        n = min(size, left)
        if self._halts_left:
            packets = max(1, -(-n // MAX_PACKET))
            if packets > self._packets_before_halt:
                raise self._halt()
            self._packets_before_halt -= packets
        piece = self._tx[self._tx_pos : self._tx_pos + n]
        self._tx_pos += n
        if self._tx_pos == len(self._tx):
            self._tx = b""
            self._tx_pos = 0
            self._zlp_pending = n == size and len(piece) % MAX_PACKET == 0
            self.frames_sent += 1
        return piece

    def _rendering(self, queued: _Queued) -> bool:
        """Whether the sensor's thread is still to render this frame (rendering ahead)."""
        return self.render_ahead and queued.wire is None

    def _sensor(self) -> None:
        """Rendering ahead: take every frame as its exposure ends and render it into the FIFO.

        Rendering runs outside the lock (a bulk read of a frame rendered already, or a control
        request, does not wait for it); a frame the FIFO lost meanwhile (the stream stopped,
        the camera lost power) is thrown away.
        """
        with self._lock:
            while True:
                queued = None
                if self._powered and self._attached and not self._hung:
                    self._catch_up()
                    queued = next((q for q in self._fifo if q.wire is None), None)
                if queued is None:
                    due = self._next_due_us()
                    wait = None if due is None else max(0.0, (due - self.now_us()) / 1e6)
                    self._lock.wait(wait)
                    continue
                boots, exposure, header = self.boots, self._exposure(queued), self._regs.copy()
                self._lock.release()
                try:
                    rendered = self.source.render(exposure)
                finally:
                    self._lock.acquire()
                if self.boots == boots and any(q is queued for q in self._fifo):
                    queued.wire = self._wire(queued, rendered, header)
                    self._lock.notify_all()

    def _exposure(self, queued: _Queued) -> Exposure:
        return Exposure(
            sequence=queued.sequence,
            t0_s=queued.t0_us / 1e6,
            tap_interval_s=self.tap_interval_us / 1e6,
            integration_s=integration_us(self._regs[Register.INTEGRATION]) / 1e6,
            mod_code=self._regs[Register.MOD_FREQ],
            recorded=queued.recorded,
        )

    def _build(self, queued: _Queued) -> bytes:
        """Render one queued frame and put it on the wire."""
        return self._wire(queued, self.source.render(self._exposure(queued)), self._regs)

    def _wire(self, queued: _Queued, rendered: Rendered, regs: dict[Register, int]) -> bytes:
        """A rendered frame as it goes on the wire: header and taps."""
        if rendered.wire is not None:
            return self._restamped(queued, rendered.wire)
        taps = np.ascontiguousarray(rendered.taps, dtype="<u2")
        self._keep_truth(queued.sequence, rendered.truth)
        flags = queued.flags
        if bool((taps >= MAX_COUNT).any()):
            flags |= FLAG_SATURATED
        if self.over_temperature:
            flags |= FLAG_OVER_TEMPERATURE
        payload = taps.tobytes()
        header = FrameHeader(
            sequence=queued.sequence,
            device_time_us=queued.t0_us,
            width=self.info.width,
            height=self.info.height,
            mod_code=regs[Register.MOD_FREQ],
            integration=regs[Register.INTEGRATION],
            flags=flags,
            temperature_c=self.temperature_c,
            tap_interval_us=integration_us(regs[Register.INTEGRATION]) + READOUT_US,
            payload_size=len(payload),
            payload_crc=crc32(payload),
        )
        return pack_header(header) + payload

    def _restamped(self, queued: _Queued, wire: bytes) -> bytes:
        """A recorded frame with this camera's sequence, time and drop flag in its header;
        a damaged one (its header unreadable) goes as it was recorded."""
        try:
            recorded = parse_header(wire[:HEADER_SIZE])
        except ProtocolError:
            return wire
        flags = recorded.flags | queued.flags
        if self.over_temperature:
            flags |= FLAG_OVER_TEMPERATURE
        header = dataclasses.replace(
            recorded, sequence=queued.sequence, device_time_us=queued.t0_us, flags=flags
        )
        return pack_header(header) + wire[HEADER_SIZE:]

    def _keep_truth(self, sequence: int, truth: object) -> None:
        if truth is None:
            return
        self._truth[sequence] = truth
        while len(self._truth) > TRUTH_KEPT:
            self._truth.popitem(last=False)

    def truth(self, sequence: int) -> object | None:
        """Ground truth of a recently sent frame (the last `TRUTH_KEPT`), else None."""
        with self._lock:
            return self._truth.get(sequence)
