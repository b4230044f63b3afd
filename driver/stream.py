"""Bytes from the frame endpoint (or a capture) → whole, checked raw frames.

The parser reassembles frames that arrive in pieces, drops damaged ones and finds the
next header, and counts what was lost from gaps in the sequence numbers. It never
allocates by a size read from the wire: every header is checked against GET_INFO first.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from tofcut.driver.errors import ProtocolError
from tofcut.driver.frames import RawFrame
from tofcut.driver.protocol import (
    FRAME_MAGIC,
    HEADER_SIZE,
    DeviceInfo,
    FrameHeader,
    check_header,
    crc32,
    parse_header,
)

SEQUENCE_MOD = 1 << 32
MAX_GAPS_KEPT = 1000


@dataclass
class StreamStats:
    """Running counts of a stream; `gaps` keeps the most recent lost sequence ranges."""

    frames: int = 0
    """Good frames delivered."""
    damaged: int = 0
    """Frames dropped because their header or payload was damaged."""
    lost: int = 0
    """Frames missing from the sequence (damaged ones included)."""
    device_dropped_flags: int = 0
    """Frames that came with the device's 'frames were dropped before this one' flag."""
    bytes_skipped: int = 0
    """Bytes thrown away while looking for the next header."""
    sequence_restarts: int = 0
    """Times the sequence went backwards (a device that was reset)."""
    gaps: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=MAX_GAPS_KEPT))
    """(first, last) sequence numbers of each run of lost frames, most recent last."""

    def record_gap(self, first: int, last: int) -> None:
        self.lost += (last - first) % SEQUENCE_MOD + 1
        self.gaps.append((first, last))


class FrameParser:
    """Feed it bytes as they arrive; it returns the frames they complete."""

    def __init__(self, info: DeviceInfo, stats: StreamStats | None = None) -> None:
        self.info = info
        self.stats = stats if stats is not None else StreamStats()
        self._buf = bytearray()
        self._last_seq: int | None = None

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget a partial frame (after the stream was stopped or the device went away)."""
        self.stats.bytes_skipped += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes | bytearray | memoryview, host_time_ns: int) -> list[RawFrame]:
        """Add received bytes; return the frames they complete, in order."""
        self._buf += data
        out: list[RawFrame] = []
        buf = self._buf
        while True:
            start = buf.find(FRAME_MAGIC)
            if start < 0:
                keep = min(len(buf), len(FRAME_MAGIC) - 1)
                self._skip(len(buf) - keep)
                break
            if start:
                self._skip(start)
            if len(buf) < HEADER_SIZE:
                break
            try:
                header = parse_header(bytes(buf[:HEADER_SIZE]))
                check_header(header, self.info)
            except ProtocolError:
                header = None
            if header is None:
                self._damaged(1)
                continue
            end = HEADER_SIZE + header.payload_size
            if len(buf) < end:
                break
            if crc32(memoryview(buf)[HEADER_SIZE:end]) != header.payload_crc:
                self._damaged(len(FRAME_MAGIC))
                continue
            wire = bytes(buf[:end])
            del buf[:end]
            out.append(self._accept(header, wire, host_time_ns))
        return out

    def _skip(self, n: int) -> None:
        if n:
            self.stats.bytes_skipped += n
            del self._buf[:n]

    def _damaged(self, skip: int) -> None:
        self.stats.damaged += 1
        self._skip(skip)

    def _accept(self, hdr: FrameHeader, wire: bytes, host_time_ns: int) -> RawFrame:
        stats = self.stats
        if self._last_seq is not None:
            step = (hdr.sequence - self._last_seq) % SEQUENCE_MOD
            if step == 0 or step >= SEQUENCE_MOD // 2:
                stats.sequence_restarts += 1
            elif step > 1:
                stats.record_gap((self._last_seq + 1) % SEQUENCE_MOD, hdr.sequence - 1)
        self._last_seq = hdr.sequence
        if hdr.dropped_before:
            stats.device_dropped_flags += 1
        stats.frames += 1
        taps = np.frombuffer(wire, dtype="<u2", offset=HEADER_SIZE).reshape(
            hdr.taps, hdr.height, hdr.width
        )
        return RawFrame(header=hdr, taps=taps, wire=wire, host_time_ns=host_time_ns)
