"""A capture replayed by the emulated camera: `emulator:run.tofcap`.

    index = read_index("run.tofcap")             # checked and indexed once
    EmulatedCamera(CaptureReplay(index))         # the camera that made it, on the emulated bus

The camera gets the capture's flash (calibration block), registers, serial and firmware, and
each exposure sends the recorded frame of its time, read from the file as it is taken: the
recorded bytes, with the camera's own sequence, time and drop flag written into the header.
So the driver reads a recording as it read the live camera, through the same transfers,
faults and reconnects as a rendered scene.

Time: the recording's frames sit on its frame clock, each at its run sequence (gaps where
the recording lost frames, which the replay numbers and never sends, so the driver counts
them lost again). An exposure takes the frame of its time on a clock that starts with the
first frame and runs on through reboots: in real time a camera that was off misses the
frames of that time, as on a line that never stops; a slower frame rate takes fewer of
them. A capture made in a trigger mode has no pace: its frames are taken one by one, in
order. A damaged record is sent as it is (the driver counts it damaged, as `CaptureReader`
does); a cut-short end is left out. The stream ends with the last frame, or starts the
recording again with `loop`.
"""

from __future__ import annotations

import os
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tofcut.driver.calibration import Calibration, parse_calibration
from tofcut.driver.capture import CAMERA_KEYS, CaptureReader
from tofcut.driver.errors import CaptureError
from tofcut.driver.frames import RawFrame
from tofcut.driver.protocol import (
    HEADER_SIZE,
    MOD_FREQ_MHZ,
    RESET_VALUES,
    TAPS,
    WRITABLE_REGISTERS,
    Register,
    integration_us,
)
from tofcut.sim.device import frame_period_us, register_value_ok
from tofcut.sim.source import Exposure, Rendered, Take

MAX_GAP = 1 << 20
"""The most frames a recording may have lost between two of its records (over 5 hours at
50 fps): more is damage, and a replay would number them one by one."""
_FROM_FRAMES = (Register.MOD_FREQ, Register.INTEGRATION)
"""Registers every frame's header also gives: each frame must agree with the capture's."""


@dataclass(frozen=True, eq=False)
class ReplayIndex:
    """A capture checked and indexed for replay: what the camera was, where each record is."""

    path: Path
    metadata: dict[str, Any]
    calibration_block: bytes
    registers: dict[Register, int]
    """The writable registers it was recorded with (from its metadata, else its frames)."""
    serial: int
    firmware: int
    width: int
    height: int
    offsets: npt.NDArray[np.int64]
    """Where each whole record's frame bytes start in the file."""
    slots: npt.NDArray[np.int64]
    """Each record's place on the recording's frame clock (strictly increasing from 0)."""
    damaged: int
    """Records damaged in the file (sent as they are)."""
    truncated_bytes: int
    """Bytes of a cut-short record at the end, left out."""

    @property
    def frames(self) -> int:
        """Whole records: the frames the replay sends."""
        return len(self.offsets)

    @property
    def triggered(self) -> bool:
        """Made in a trigger mode: no pace of its own (its frames are taken in order)."""
        return self.registers[Register.TRIGGER_MODE] != 0

    @property
    def period_us(self) -> int:
        """The recording's frame period."""
        return frame_period_us(self.registers)

    @property
    def installation(self) -> dict[str, Any]:
        """What the metadata tells beyond the camera (scene, belt, target), as a scene's."""
        return {k: v for k, v in self.metadata.items() if k not in CAMERA_KEYS}

    def refusal(self, register: Register, value: int, registers: dict[Register, int]) -> str:
        """Why a replay of this capture cannot take `value` in `register` (the registers
        being `registers`), or '': the modulation and the integration are the recording's,
        and the frame rate no faster than it was."""
        recorded = self.registers[register]
        if register in _FROM_FRAMES and value != recorded:
            return (
                f"the capture was recorded at {_setting(register, recorded)}: its frames "
                f"cannot be replayed at {_setting(register, value)}"
            )
        if register == Register.FRAME_PERIOD and not self.triggered:
            period = frame_period_us({**registers, register: value})
            if period < self.period_us:
                return (
                    f"the capture was recorded at {1e6 / self.period_us:.4g} fps: it cannot "
                    f"be replayed faster ({1e6 / period:.4g} fps)"
                )
        return ""

    def describe(self) -> str:
        """A closing line: what the capture held."""
        text = f"replayed {self.path}: {self.frames} recorded frames"
        if self.damaged:
            text += f", {self.damaged} of them damaged in the file"
        if self.truncated_bytes:
            text += f"; {self.truncated_bytes} bytes cut short at the end, left out"
        return text


def read_index(path: str | os.PathLike[str]) -> ReplayIndex:
    """Check a capture for replay and index its records; `CaptureError` (one line) if it
    cannot be replayed: a bad head (as `CaptureReader` checks it), registers that are not
    the camera's, frames made at another setting, no whole record."""
    reader = CaptureReader(path)
    info = reader.info
    if info.protocol != 1:
        raise CaptureError(
            f"the capture was recorded with protocol {info.protocol}; the emulated camera speaks 1"
        )
    registers = _registers(reader.capture.metadata["registers"])
    parser = reader.parser()
    offsets: list[int] = []
    slots: list[int] = []
    base: int | None = None
    for record in reader.records():
        got = parser.feed(record.wire, record.host_time_ns)
        parser.end_transfer()
        slot = slots[-1] + 1 if slots else 0
        if got:
            raw = got[0]
            _take_setting(registers, raw, len(offsets))
            run = raw.sequence + parser.stats.sequence_offset
            if base is None:
                base = run - slot
            if run - base - slot > MAX_GAP:
                raise CaptureError(
                    f"record {len(offsets)} says {run - base - slot} frames were lost before "
                    f"it (its sequence number or host time is damaged): a replay numbers at "
                    f"most {MAX_GAP}"
                )
            slot = max(slot, run - base)
        offsets.append(record.offset)
        slots.append(slot)
    if not offsets:
        raise CaptureError(f"{path} holds no whole frame to replay")
    for register in _FROM_FRAMES:  # every record damaged, and the metadata silent
        registers.setdefault(register, RESET_VALUES[register])
    return ReplayIndex(
        path=reader.path,
        metadata=reader.capture.metadata,
        calibration_block=reader.capture.calibration_block,
        registers=registers,
        serial=info.serial,
        firmware=info.firmware,
        width=info.width,
        height=info.height,
        offsets=np.array(offsets, np.int64),
        slots=np.array(slots, np.int64),
        damaged=reader.stats.damaged,
        truncated_bytes=reader.truncated_bytes,
    )


def _registers(recorded: dict[str, Any]) -> dict[Register, int]:
    """The writable registers of a capture's metadata, each checked; the frame clock's take
    their reset values where missing, the modulation and integration the frames' own."""
    registers: dict[Register, int] = {}
    for register in sorted(WRITABLE_REGISTERS):
        if register.name not in recorded:
            continue
        value = recorded[register.name]
        if (
            isinstance(value, bool)
            or not isinstance(value, int)
            or not 0 <= value <= 0xFFFF
            or not register_value_ok(register, value)
        ):
            raise CaptureError(
                f"metadata register {register.name} is not a value the camera takes: {value!r:.40}"
            )
        registers[register] = value
    for register in (Register.FRAME_PERIOD, Register.TRIGGER_MODE):
        registers.setdefault(register, RESET_VALUES[register])
    return registers


def _setting(register: Register, value: int) -> str:
    """A modulation or integration register's value, as a user gives it."""
    if register == Register.MOD_FREQ:
        return f"{MOD_FREQ_MHZ[value]:g} MHz" if value in MOD_FREQ_MHZ else f"code {value}"
    return f"an integration of {integration_us(value) / 1000:g} ms"


def _take_setting(registers: dict[Register, int], raw: RawFrame, record: int) -> None:
    """Each frame's modulation and integration: the capture's (or the first frame's, where
    the metadata has none); a frame made otherwise cannot be replayed by one camera."""
    for register, value in (
        (Register.MOD_FREQ, raw.header.mod_code),
        (Register.INTEGRATION, raw.header.integration),
    ):
        expected = registers.setdefault(register, value)
        if value != expected:
            raise CaptureError(
                f"record {record} was made at {register.name} {value}, the capture at "
                f"{expected}: a replay keeps one setting"
            )


class CaptureReplay:
    """A capture as the emulated camera replays it (a `tofcut.sim.source.Recording`)."""

    def __init__(self, index: ReplayIndex, *, loop: bool = False) -> None:
        self.index = index
        self.loop = loop
        """Start again at the first frame after the last, instead of ending."""
        self.calibration: Calibration = parse_calibration(
            index.calibration_block, index.width, index.height
        )
        self._frame_size = HEADER_SIZE + TAPS * index.width * index.height * 2
        self._fd = os.open(index.path, os.O_RDONLY)
        weakref.finalize(self, os.close, self._fd)
        self._record_at = {int(slot): i for i, slot in enumerate(index.slots)}
        self._span = int(index.slots[-1]) + 1
        self._origin_us: int | None = None
        self._last_slot = -1

    @property
    def calibration_block(self) -> bytes:
        return self.index.calibration_block

    @property
    def registers(self) -> dict[Register, int]:
        return dict(self.index.registers)

    def take(self, line_us: int) -> Take:
        """The recorded frame of this time (see the module)."""
        if self._origin_us is None:
            self._origin_us = line_us
        slot = self._last_slot + 1
        if not self.index.triggered:
            period = self.index.period_us
            slot = max(slot, (line_us - self._origin_us + period // 2) // period)
        if slot >= self._span and not self.loop:
            return Take(None, ended=True)
        self._last_slot = slot
        return Take(self._record_at.get(slot % self._span))

    def render(self, exposure: Exposure) -> Rendered:
        """The recorded frame the exposure took, read from the file."""
        if exposure.recorded is None:
            raise ValueError("a replay sends only the recorded frames it took")
        offset = int(self.index.offsets[exposure.recorded])
        wire = os.pread(self._fd, self._frame_size, offset)
        if len(wire) != self._frame_size:
            raise CaptureError(f"{self.index.path} was cut short while it was replayed")
        shape = (TAPS, self.index.height, self.index.width)
        taps = np.frombuffer(wire, "<u2", offset=HEADER_SIZE).reshape(shape)
        return Rendered(taps=taps, wire=wire)

    def refusal(self, register: Register, value: int, registers: dict[Register, int]) -> str:
        """Why the replay cannot take this register write, or '' (`ReplayIndex.refusal`)."""
        return self.index.refusal(register, value, registers)
