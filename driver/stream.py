"""Bytes from the frame endpoint (or a capture) → whole, checked raw frames.

The parser reassembles frames that arrive in pieces, drops damaged ones and finds the
next header, and counts what was lost from gaps in the sequence numbers. It never
allocates by a size read from the wire: every header is checked against GET_INFO first.

Sequence numbers are reported in *run* numbering: the camera's own numbers, continued
across wrap-arounds and across outages in which the camera restarted its count (a power
cycle) or took no frames (unplugged). Such an outage is costed from time — the host's
clock for its length, the camera's timestamps for its frame period — and that part of
the loss is kept apart as an estimate (`lost_estimated`, `estimated_gaps`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tofcut.driver.errors import ProtocolError
from tofcut.driver.events import DeviceEvent, EventKind
from tofcut.driver.frames import RawFrame
from tofcut.driver.protocol import (
    FRAME_MAGIC,
    HEADER_SIZE,
    MOD_FREQ_MHZ,
    DeviceInfo,
    FrameHeader,
    check_header,
    crc32,
    parse_header,
)

SEQUENCE_MOD = 1 << 32
MAX_GAPS_KEPT = 1000
MAX_EVENTS_KEPT = 1000

Gap = tuple[int, int]


@dataclass
class StreamStats:
    """Running counts of a stream; `gaps` keeps the most recent lost sequence ranges."""

    frames: int = 0
    """Good frames delivered."""
    damaged: int = 0
    """Frames dropped because their header or payload was damaged or cut short."""
    lost: int = 0
    """Frames missing from the run (damaged ones and estimated ones included)."""
    lost_estimated: int = 0
    """The part of `lost` estimated from time rather than counted from sequence numbers:
    frames the camera never took, or whose numbers a restart erased, during an outage."""
    device_dropped_flags: int = 0
    """Frames that came with the device's 'frames were dropped before this one' flag."""
    bytes_skipped: int = 0
    """Bytes thrown away while looking for the next header."""
    sequence_restarts: int = 0
    """Times the sequence went backwards (a device that was reset or power-cycled)."""
    sequence_offset: int = 0
    """Run sequence = the camera's sequence + this (non-zero after a restart or outage)."""
    read_timeouts: int = 0
    """Bulk reads that timed out."""
    stalls_cleared: int = 0
    """Times the frame endpoint stalled and its halt was cleared."""
    reconnects: int = 0
    """Times the camera was reopened after it went away or hung."""
    gaps: deque[Gap] = field(default_factory=lambda: deque(maxlen=MAX_GAPS_KEPT))
    """(first, last) run sequence numbers of each run of lost frames, most recent last."""
    estimated_gaps: deque[Gap] = field(default_factory=lambda: deque(maxlen=MAX_GAPS_KEPT))
    """The gaps whose length is an estimate from time (also listed in `gaps`)."""
    events: deque[DeviceEvent] = field(default_factory=lambda: deque(maxlen=MAX_EVENTS_KEPT))
    """Disconnects, reconnects, stalls and restarts, most recent last."""
    on_event: Callable[[DeviceEvent], None] | None = field(default=None, repr=False, compare=False)
    """Called with every event as it happens (on the thread reading frames)."""

    def record_gap(self, first: int, last: int, *, estimated: bool = False) -> None:
        self.lost += last - first + 1
        self.gaps.append((first, last))
        if estimated:
            self.lost_estimated += last - first + 1
            self.estimated_gaps.append((first, last))

    def note(
        self, kind: EventKind, host_time_ns: int, detail: str, errno: int | None = None
    ) -> DeviceEvent:
        """Record an event and pass it to `on_event`."""
        event = DeviceEvent(kind, host_time_ns, detail, errno)
        self.events.append(event)
        if self.on_event is not None:
            self.on_event(event)
        return event


@dataclass(frozen=True)
class _Seen:
    """The last good frame: where the run stands."""

    header: FrameHeader
    host_time_ns: int
    run_sequence: int


def _check(header: FrameHeader, info: DeviceInfo) -> None:
    check_header(header, info)
    if header.mod_code not in MOD_FREQ_MHZ:
        raise ProtocolError(f"frame made at unsupported modulation code {header.mod_code}")


class FrameParser:
    """Feed it bytes as they arrive; it returns the frames they complete."""

    def __init__(
        self, info: DeviceInfo, stats: StreamStats | None = None, *, periodic: bool = False
    ) -> None:
        self.info = info
        self.stats = stats if stats is not None else StreamStats()
        self.periodic = periodic
        """Frames come at a steady rate (free run), so an outage can be costed from time."""
        self.nominal_period_us: float | None = None
        """The frame period to assume until one is measured from the frames' timestamps."""
        self._buf = bytearray()
        self._last: _Seen | None = None
        self._period_us: float | None = None
        self._outage: str | None = None
        self._transfer_bytes = 0
        self._transfer_settled = False
        self._damage_counted = False
        """A damaged frame was counted since the last frame or transfer: what follows in the
        same bytes until a frame is whole is that frame's damage (a run of false frame magic
        in garbage is one damaged frame, not one per match)."""

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    @property
    def period_us(self) -> float | None:
        """The frame period measured from the last two frames' timestamps, else the nominal."""
        return self._period_us or self.nominal_period_us

    def reset(self) -> None:
        """Forget a partial frame (after the stream was stopped or the device went away)."""
        self._skip(len(self._buf))
        self._transfer_bytes = 0
        self._transfer_settled = False
        self._damage_counted = False

    def end_transfer(self) -> None:
        """The bulk transfer ended (a short packet); a frame still incomplete is damaged.

        Every frame is one transfer (spec §6), so bytes left at a transfer's end can never
        be completed; dropping them here keeps them from swallowing the next frame.
        """
        if self._transfer_bytes and not self._transfer_settled:
            self.stats.damaged += 1
        self.reset()

    def resume_after_outage(self, why: str) -> None:
        """The stream was interrupted (`why`); cost the outage when the next frame comes."""
        self.reset()
        self._outage = why

    def feed(self, data: bytes | bytearray | memoryview, host_time_ns: int) -> list[RawFrame]:
        """Add received bytes; return the frames they complete, in order."""
        self._buf += data
        self._transfer_bytes += len(data)
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
                _check(header, self.info)
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
            with memoryview(buf) as view:  # one copy: a slice of `buf` would be another
                wire = bytes(view[:end])
            del buf[:end]
            out.append(self._accept(header, wire, host_time_ns))
        return out

    def _skip(self, n: int) -> None:
        if n:
            self.stats.bytes_skipped += n
            del self._buf[:n]

    def _damaged(self, skip: int) -> None:
        if not self._damage_counted:
            self.stats.damaged += 1
            self._damage_counted = True
        self._transfer_settled = True
        self._skip(skip)

    def _accept(self, hdr: FrameHeader, wire: bytes, host_time_ns: int) -> RawFrame:
        stats = self.stats
        self._transfer_settled = True
        self._damage_counted = False
        run = hdr.sequence + stats.sequence_offset
        if self._last is None:
            self._outage = None  # nothing came before it, so there is nothing to cost
        else:
            run = self._account(hdr, host_time_ns)
        stats.sequence_offset = run - hdr.sequence
        self._last = _Seen(hdr, host_time_ns, run)
        if hdr.dropped_before:
            stats.device_dropped_flags += 1
        stats.frames += 1
        taps = np.frombuffer(wire, dtype="<u2", offset=HEADER_SIZE).reshape(
            hdr.taps, hdr.height, hdr.width
        )
        return RawFrame(header=hdr, taps=taps, wire=wire, host_time_ns=host_time_ns)

    def _account(self, hdr: FrameHeader, host_time_ns: int) -> int:
        """Count what was lost between the last frame and this one; return its run number."""
        assert self._last is not None
        stats = self.stats
        last = self._last.header
        step = (hdr.sequence - last.sequence) % SEQUENCE_MOD
        restarted = (
            step == 0 or step >= SEQUENCE_MOD // 2 or hdr.device_time_us < last.device_time_us
        )
        exact = 0 if restarted else step - 1
        first_lost = self._last.run_sequence + 1
        if exact:
            stats.record_gap(first_lost, first_lost + exact - 1)
        outage, self._outage = self._outage, None
        if outage is None and not restarted:
            elapsed_us = hdr.device_time_us - last.device_time_us
            if elapsed_us > 0:
                self._period_us = elapsed_us / step
            return self._last.run_sequence + step
        span_ns = host_time_ns - self._last.host_time_ns
        estimated = self._estimate_missed(span_ns, exact)
        if estimated:
            first = first_lost + exact
            stats.record_gap(first, first + estimated - 1, estimated=True)
        run = first_lost + exact + estimated
        if restarted:
            stats.sequence_restarts += 1
        how = "the camera restarted its sequence at" if restarted else "the camera went on at"
        detail = (
            f"{how} {hdr.sequence}; {exact} frames lost by sequence number"
            f" and about {estimated} estimated from {span_ns / 1e9:.3f} s"
            f" (run sequence {first_lost}-{run - 1} lost, now at {run})"
            if exact + estimated
            else f"{how} {hdr.sequence}; no frames lost (run sequence now at {run})"
        )
        if outage is not None:
            stats.note(EventKind.RESUMED, host_time_ns, f"after {outage}: {detail}")
        else:
            stats.note(EventKind.SEQUENCE_RESTART, host_time_ns, detail)
        return run

    def _estimate_missed(self, span_ns: int, exact: int) -> int:
        """Frames the camera would have taken in `span_ns` beyond the `exact` ones counted."""
        period = self.period_us
        if not self.periodic or not period:
            return 0
        slots = math.floor(span_ns / 1000.0 / period + 0.5)
        return max(0, slots - 1 - exact)
