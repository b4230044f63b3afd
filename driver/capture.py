"""Capture files (`.tofcap`, spec §8): the wire stream on disk, replayed through the parser.

A capture cut short by a killed recorder stays readable up to its last whole record;
the reader reports how many bytes it skipped at the end. Every length in the file is
checked against the sensor size and the bytes actually left before anything is read.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from tofcut._closing import Closing
from tofcut.driver.calibration import Calibration, parse_calibration
from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.errors import CaptureError, ProtocolError
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.protocol import (
    CALIB_HEADER_SIZE,
    MAX_SENSOR_SIDE,
    DeviceInfo,
    check_sensor_size,
)
from tofcut.driver.stream import FrameParser, StreamStats

MAGIC = b"TOFCAP01"
MAX_METADATA = 1 << 20
"""Metadata larger than this is damage, not metadata."""
SERIAL_TEXT = re.compile(r"[0-9A-Fa-f]{1,8}")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")


@dataclass(frozen=True)
class CaptureInfo:
    """What a capture says about the camera it was recorded from."""

    metadata: dict[str, Any]
    calibration_block: bytes

    @property
    def serial(self) -> str:
        return str(self.metadata["serial"])

    @property
    def width(self) -> int:
        return int(self.metadata["width"])

    @property
    def height(self) -> int:
        return int(self.metadata["height"])


def capture_metadata(info: DeviceInfo, registers: dict[str, int], **extra: Any) -> dict[str, Any]:
    """The metadata a capture needs (spec §8), plus anything the recorder wants to keep."""
    return {**info.described(), "registers": registers, **extra}


CAMERA_KEYS = ("serial", "firmware", "protocol", "width", "height", "max_fps", "registers")
"""The metadata a camera itself gives a capture: what `capture_metadata` holds without extras."""


def bare_metadata(metadata: dict[str, Any]) -> dict[str, Any]:
    """Only the camera's own keys of a capture's metadata, as a real camera's capture has them.

    An emulated camera's recorder adds what a real camera never tells (the scene, its belt's
    geometry and speed, a marked target, the source's name); a tracker evaluated on captures
    that carry them can lean on them. Dropping them leaves nothing but the camera's stream.
    """
    return {key: metadata[key] for key in CAMERA_KEYS if key in metadata}


@dataclass(frozen=True, eq=False)
class Record:
    """One record of a capture, as it is in the file."""

    offset: int
    """Where its frame bytes start in the file."""
    host_time_ns: int
    wire: bytes
    """The frame as it was on the wire: one frame's size, whole or damaged."""


class CaptureWriter(Closing):
    """Writes records as frames arrive; each record is flushed so a kill loses at most one."""

    def __init__(self, path: str | os.PathLike[str], metadata: dict[str, Any], calib: bytes):
        self.path = Path(path)
        self.frames = 0
        self._file: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        meta = json.dumps(metadata).encode()
        self._file.write(MAGIC + _U32.pack(len(meta)) + meta + _U32.pack(len(calib)) + calib)
        self._file.flush()

    def write(self, raw: RawFrame) -> None:
        self._file.write(_U64.pack(raw.host_time_ns) + raw.wire)
        self._file.flush()
        self.frames += 1

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def _left(f: BinaryIO) -> int:
    """Bytes from the current position to the end of the file."""
    return os.fstat(f.fileno()).st_size - f.tell()


def _show(value: object) -> str:
    """A metadata value for a message: its repr, cut short (metadata may be 1 MiB)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:40] + "…"


def _read_exact(f: BinaryIO, n: int, what: str) -> bytes:
    if n > _left(f):  # checked first, so a damaged length cannot make us allocate
        raise CaptureError(f"capture ends inside its {what}")
    data = f.read(n)
    if len(data) != n:
        raise CaptureError(f"capture ends inside its {what}")
    return data


def _int_field(
    meta: dict[str, Any], key: str, low: int, high: int, default: int | None = None
) -> int:
    value = meta.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise CaptureError(f"metadata {key!r} is missing or implausible: {_show(value)}")
    return value


class CaptureReader(Closing):
    """A recorded camera: same `info`, `calibration`, `raw_frames()`, `frames()` as Camera."""

    def __init__(self, path: str | os.PathLike[str], *, amplitude_threshold: float = 0.0):
        self.path = Path(path)
        self.amplitude_threshold = amplitude_threshold
        self.truncated_bytes = 0
        """Bytes at the end that did not make a whole record (a recorder killed mid-write)."""
        self.stats = StreamStats()
        with open(self.path, "rb") as f:
            self.capture = self._read_head(f)
            self._records_start = f.tell()
        meta = self.capture.metadata
        width, height = self.capture.width, self.capture.height
        try:
            self.calibration: Calibration = parse_calibration(
                self.capture.calibration_block, width, height
            )
            self.optics = Optics.from_calibration(self.calibration)
        except ProtocolError as exc:
            raise CaptureError(f"the capture's calibration block is unusable: {exc}") from exc
        self.info = DeviceInfo(
            protocol=int(meta["protocol"]),
            firmware=int(meta["firmware"]),
            serial=int(str(meta["serial"]), 16),
            width=width,
            height=height,
            calibration_size=len(self.capture.calibration_block),
            max_fps=int(meta.get("max_fps", 0)),
        )

    @staticmethod
    def _read_head(f: BinaryIO) -> CaptureInfo:
        if f.read(len(MAGIC)) != MAGIC:
            raise CaptureError("not a .tofcap file (bad magic)")
        (meta_len,) = _U32.unpack(_read_exact(f, 4, "metadata length"))
        if meta_len > MAX_METADATA:
            raise CaptureError(f"metadata length {meta_len} is implausible")
        try:
            meta = json.loads(_read_exact(f, meta_len, "metadata").decode())
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            raise CaptureError(f"metadata is not UTF-8 JSON: {exc}") from exc
        if not isinstance(meta, dict):
            raise CaptureError("metadata is not a JSON object")
        serial = meta.get("serial")
        if not isinstance(serial, str) or not SERIAL_TEXT.fullmatch(serial):
            raise CaptureError(f"metadata 'serial' is not 1 to 8 hex digits: {_show(serial)}")
        _int_field(meta, "firmware", 0, 0xFFFF)
        _int_field(meta, "protocol", 0, 0xFFFF)
        _int_field(meta, "max_fps", 0, 0xFFFF, default=0)
        width = _int_field(meta, "width", 1, MAX_SENSOR_SIDE)
        height = _int_field(meta, "height", 1, MAX_SENSOR_SIDE)
        if why := check_sensor_size(width, height):
            raise CaptureError(f"metadata gives {why}")
        if not isinstance(meta.get("registers"), dict):
            raise CaptureError("metadata lacks 'registers' (object)")
        (calib_len,) = _U32.unpack(_read_exact(f, 4, "calibration length"))
        expected = CALIB_HEADER_SIZE + 2 * width * height
        if calib_len != expected:
            raise CaptureError(f"calibration length {calib_len} != {expected} for the sensor")
        calib = _read_exact(f, calib_len, "calibration block")
        return CaptureInfo(meta, calib)

    @property
    def serial(self) -> str:
        return self.info.serial_text

    def parser(self) -> FrameParser:
        """A parser for this capture's frames, counting into a fresh `stats`."""
        self.stats = StreamStats()
        trigger_mode = self.capture.metadata["registers"].get("TRIGGER_MODE", 0)
        return FrameParser(self.info, self.stats, periodic=trigger_mode == 0)

    def records(self) -> Iterator[Record]:
        """Every whole record in order, as it is in the file (unparsed: it may be damaged);
        a cut-short end is skipped and its size left in `truncated_bytes`."""
        self.truncated_bytes = 0
        frame_size = self.info.frame_size
        with open(self.path, "rb") as f:
            f.seek(self._records_start)
            while True:
                offset = f.tell()
                stamp = f.read(_U64.size)
                if not stamp:
                    return
                if len(stamp) < _U64.size:
                    self.truncated_bytes = len(stamp)
                    return
                (host_ns,) = _U64.unpack(stamp)
                record = self._read_record(f, frame_size)
                if record is None:
                    self.truncated_bytes += _U64.size
                    return
                yield Record(offset + _U64.size, host_ns, record)

    def raw_frames(self, count: int | None = None) -> Iterator[RawFrame]:
        """Every good frame in order; damaged records are dropped and counted in `stats`."""
        parser = self.parser()
        delivered = 0
        if count is not None and count <= 0:
            return
        for record in self.records():
            for raw in parser.feed(record.wire, record.host_time_ns):
                yield raw
                delivered += 1
            parser.end_transfer()  # a record is one frame: what is left of it is damage
            if count is not None and delivered >= count:
                return

    def _read_record(self, f: BinaryIO, frame_size: int) -> bytes | None:
        """One record's frame bytes, or None (with `truncated_bytes` set) at a cut-short end.

        Every record holds one frame of the sensor's size; a size read from the record's
        own header is never trusted, so damage there cannot make us read too much.
        """
        left = _left(f)
        if left < frame_size:
            self.truncated_bytes = left
            return None
        return f.read(frame_size)

    def frames(self, count: int | None = None) -> Iterator[Frame]:
        for raw in self.raw_frames(count):
            yield demodulate(raw, self.optics, self.amplitude_threshold)

    def __len__(self) -> int:
        """Whole records in the file (good or damaged)."""
        size = self.path.stat().st_size - self._records_start
        return size // (_U64.size + self.info.frame_size)

    def close(self) -> None:
        """Nothing is held open between reads; here for symmetry with Camera."""


def bare_copy(source: str | os.PathLike[str], target: str | os.PathLike[str]) -> int:
    """Copy a capture with only the camera's metadata (`bare_metadata`); returns its frames.

    The calibration block and every record are copied byte for byte, so the copy replays
    the same frames; a cut-short tail is copied as it is (the reader skips it as before).
    """
    if Path(source).resolve() == Path(target).resolve():
        raise CaptureError(f"a bare copy must go to another file than {source}")
    reader = CaptureReader(source)
    meta = bare_metadata(reader.capture.metadata)
    calib = reader.capture.calibration_block
    with open(reader.path, "rb") as src, CaptureWriter(target, meta, calib) as out:
        src.seek(reader._records_start)  # this module's own reader and writer
        shutil.copyfileobj(src, out._file)
    return len(reader)
