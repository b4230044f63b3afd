"""The conveyor log beside a capture (`run.tofcap` → `run.conveyor.jsonl`): what the conveyor
link told the recording run, so that replaying the capture gives the tracker the belt prior
the live run had.

One JSON object a line, each flushed as it is written (a killed recorder loses at most the
line it was writing), told apart by `kind`::

    {"kind": "log", "version": 1, "port": "/dev/pts/3", "exposure_offset_ns": 1234 | null,
     "max_extrapolation_s": 0.5}
    {"kind": "reading", "time_ns": 1700000000000000000, "count": 2500, "distance_m": 0.25,
     "speed_mps": 0.25, "running": true, "fault": false}
    {"kind": "belt", "time_ns": 1700000000000000000, "source": "found",
     "belt": {"point": [...], "direction": [...], "normal": [...], "width_m": 0.6,
              "speed_mps": 0.25}}

The `log` line comes first; `reading` lines are `BeltReading`s (host times in ns since the
Unix epoch, the clock of `Frame.host_time_ns`) in time order; a `belt` line is a belt
geometry that became known during the run (`KnownBelt.to_dict()`). Read back, every value is
checked: a line that is not a JSON object, lacks a field, holds a value of the wrong type, a
number that is not finite or out of range, or a reading earlier than the one before it, is
skipped and counted, never trusted. Fields may be added; none will be renamed or removed.
"""

from __future__ import annotations

import json
import math
import os
import threading
from collections import deque
from collections.abc import Generator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, Any

from tofcut._closing import Closing
from tofcut.driver.belt import MAX_BELT_SPEED_MPS, BeltHistory, BeltReading, KnownBelt
from tofcut.driver.conveyor.exposure_clock import ExposureClock
from tofcut.driver.errors import CaptureError, ConfigError
from tofcut.driver.frames import Frame

SUFFIX = ".conveyor.jsonl"
VERSION = 1
MAX_LINE = 1 << 16
"""A line longer than this is damage (a reading takes about 150 bytes)."""
MAX_DISTANCE_M = 1e9
"""Belt travel beyond this is damage, not a reading."""
MAX_EXTRAPOLATION_S = 60.0
HISTORY = 256
"""Readings a replay keeps around the frame's time (5 s at 50 Hz)."""
SOURCES = ("given", "map", "scene", "capture", "found")
"""The words `KnownBelt.source` takes."""


class BeltLogError(CaptureError):
    """A conveyor log cannot be read, or one of its lines is damaged."""


def belt_log_path(capture: str | os.PathLike[str]) -> Path:
    """Where a capture's conveyor log goes: `run.tofcap` → `run.conveyor.jsonl`."""
    p = Path(capture)
    return p.with_name(p.stem + SUFFIX)


@dataclass(frozen=True)
class LogHeader:
    """The log's first line: how the recording run placed frames on the link's clock."""

    port: str
    """The link it was recorded from (for the reader's information)."""
    exposure_offset_ns: int | None
    """Host − device time of the camera when it was fixed (an emulated camera), else None:
    the replay then estimates it from the frames as the live run did (`ExposureClock`)."""
    max_extrapolation_s: float
    """How long past its last reading the live link still gave the belt's state."""


@dataclass(frozen=True, eq=False)
class LoggedBelt:
    """A belt geometry that became known during the run (a found belt), and when."""

    time_ns: int
    belt: KnownBelt


Entry = LogHeader | BeltReading | LoggedBelt


PENDING_KEPT = 10_000
"""Lines kept before the log's header is written (10 s of readings at 1000 polls a second)."""


class BeltLogWriter(Closing):
    """Writes a conveyor log as readings arrive; `reading` is a `ConveyorClient` listener.

    Lines written before `begin` (readings that came while the link opened) are kept and go
    out right after the header: the newest `PENDING_KEPT` of them (a camera slow to open
    must not grow memory without end); `pending_dropped` counts the older ones. A write that
    fails (disk full) stops the log; `error` says why, and the run goes on: the capture
    matters more than its log.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.readings = 0
        self.error: str | None = None
        self._lock = threading.Lock()
        self._pending: deque[str] | None = deque(maxlen=PENDING_KEPT)
        self.pending_dropped = 0
        """Lines written before `begin` and dropped: `PENDING_KEPT` newer ones were waiting."""
        try:
            self._file: IO[str] = self.path.open("w", encoding="utf-8")
        except OSError as exc:
            raise BeltLogError(f"{self.path}: {exc.strerror or exc}") from None

    def begin(
        self, *, port: str, exposure_offset_ns: int | None, max_extrapolation_s: float
    ) -> None:
        """Write the header line, then whatever came before it."""
        header = {
            "kind": "log",
            "version": VERSION,
            "port": port,
            "exposure_offset_ns": exposure_offset_ns,
            "max_extrapolation_s": max_extrapolation_s,
        }
        with self._lock:
            pending, self._pending = list(self._pending or ()), None
            for line in [_dumps(header), *pending]:
                self._put(line)

    def reading(self, reading: BeltReading) -> None:
        """Log one reading (on the link's thread: quick)."""
        self._write(
            {
                "kind": "reading",
                "time_ns": reading.time_ns,
                "count": reading.count,
                "distance_m": reading.distance_m,
                "speed_mps": reading.speed_mps,
                "running": reading.running,
                "fault": reading.fault,
            },
            reading=True,
        )

    def belt(self, belt: KnownBelt, time_ns: int) -> None:
        """Log a belt geometry that became known at host time `time_ns`."""
        self._write(
            {"kind": "belt", "time_ns": time_ns, "source": belt.source, "belt": belt.to_dict()}
        )

    def _write(self, doc: dict[str, Any], reading: bool = False) -> None:
        line = _dumps(doc)
        with self._lock:
            if self._pending is not None:
                if len(self._pending) == self._pending.maxlen:
                    self.pending_dropped += 1
                self._pending.append(line)
            else:
                self._put(line)
            if reading:
                self.readings += 1

    def _put(self, line: str) -> None:
        if self.error is not None or self._file.closed:
            return
        try:
            self._file.write(line + "\n")
            self._file.flush()
        except OSError as exc:
            self.error = f"{self.path}: {exc.strerror or exc}"

    def close(self) -> None:
        with self._lock:
            if self._pending is not None:  # never begun: the readings still go out
                for line in self._pending:
                    self._put(line)
                self._pending = None
            try:
                self._file.close()
            except OSError as exc:
                self.error = self.error or f"{self.path}: {exc.strerror or exc}"


def _dumps(doc: dict[str, Any]) -> str:
    return json.dumps(doc, separators=(",", ":"), allow_nan=False)


# --- reading it back ------------------------------------------------------------------------


def parse_line(text: str | bytes) -> Entry:
    """One line of a conveyor log; `BeltLogError` (one line) if it is damaged."""
    try:
        doc = json.loads(text)
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise BeltLogError("not a JSON line") from None
    if not isinstance(doc, dict):
        raise BeltLogError("not a JSON object")
    kind = doc.get("kind")
    if kind == "reading":
        return BeltReading(
            time_ns=_int(doc, "time_ns", 0, 2**63 - 1),
            count=_int(doc, "count", 0, 2**32 - 1),
            distance_m=_float(doc, "distance_m", MAX_DISTANCE_M),
            speed_mps=_float(doc, "speed_mps", MAX_BELT_SPEED_MPS),
            running=_bool(doc, "running"),
            fault=_bool(doc, "fault"),
        )
    if kind == "belt":
        source = doc.get("source")
        if source not in SOURCES:
            raise BeltLogError(f"belt: 'source' is not one of {', '.join(SOURCES)}")
        try:
            belt = KnownBelt.from_dict(doc.get("belt"), str(source))
        except ConfigError as exc:
            raise BeltLogError(f"belt: {exc}") from None
        return LoggedBelt(_int(doc, "time_ns", 0, 2**63 - 1), belt)
    if kind == "log":
        if _int(doc, "version", 1, 2**31) > VERSION:
            raise BeltLogError(f"log: version {doc['version']} is newer than this tofcut's")
        port = doc.get("port")
        if not isinstance(port, str):
            raise BeltLogError("log: 'port' is not a string")
        offset = None
        if doc.get("exposure_offset_ns") is not None:
            offset = _int(doc, "exposure_offset_ns", -(2**63), 2**63 - 1)
        extrapolation = _float(doc, "max_extrapolation_s", MAX_EXTRAPOLATION_S)
        if extrapolation < 0:
            raise BeltLogError("log: 'max_extrapolation_s' is negative")
        return LogHeader(port, offset, extrapolation)
    raise BeltLogError(f"unknown kind {str(kind)[:20]!r}")


def _int(doc: dict[str, Any], key: str, low: int, high: int) -> int:
    value = doc.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise BeltLogError(f"{doc.get('kind')}: {key!r} is not an integer in range")
    return value


def _float(doc: dict[str, Any], key: str, bound: float) -> float:
    value = doc.get(key)
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or abs(value) > bound
    ):
        raise BeltLogError(f"{doc.get('kind')}: {key!r} is not a finite number within ±{bound:g}")
    return float(value)


def _bool(doc: dict[str, Any], key: str) -> bool:
    value = doc.get(key)
    if not isinstance(value, bool):
        raise BeltLogError(f"{doc.get('kind')}: {key!r} is not true or false")
    return value


class BeltLogReader:
    """A conveyor log's entries in file order; damaged lines are skipped and counted.

    A reading earlier than the one before it is damage too (the link never logs one), so
    the readings that come out are in time order. Lines are read one at a time: a log of
    any length takes the same memory.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.skipped = 0
        """Lines skipped as damaged (or of a kind this tofcut does not know)."""
        self.readings = 0
        self.first_error = ""
        """Why the first skipped line was skipped, with its line number."""

    def __iter__(self) -> Generator[Entry, None, None]:
        try:
            f = self.path.open("rb")
        except OSError as exc:
            raise BeltLogError(f"{self.path}: {exc.strerror or exc}") from None
        last_ns = -1
        with f:
            number = 0
            while line := f.readline(MAX_LINE + 1):
                number += 1
                if len(line) > MAX_LINE:
                    while line and not line.endswith(b"\n"):  # the rest of the long line
                        line = f.readline(MAX_LINE + 1)
                    self._skip(number, "line too long")
                    continue
                if not line.strip():
                    continue
                try:
                    entry = parse_line(line)
                except BeltLogError as exc:
                    self._skip(number, str(exc))
                    continue
                if isinstance(entry, BeltReading):
                    if entry.time_ns < last_ns:
                        self._skip(number, "reading: earlier than the reading before it")
                        continue
                    last_ns = entry.time_ns
                    self.readings += 1
                yield entry

    def _skip(self, number: int, why: str) -> None:
        self.skipped += 1
        if not self.first_error:
            self.first_error = f"line {number}: {why}"


class ReplayedLink:
    """A conveyor log replayed in place of the link: the belt at each frame's exposure.

    Asked for the belt at a host time, it answers as the live link did (`BeltHistory`):
    travel interpolated between the readings around that time, the speed and flags of the
    reading before it; nothing before the first reading, nor more than the header's
    `max_extrapolation_s` after the reading before it (the live link was silent then, and
    gave no prior); across a longer silence, travel extrapolated from the reading before it
    (live, the reading after it had not come yet). Times must come in order, as frames do:
    the log is read as they go. Frames are placed in time by the same clock as live
    (`frame_time_ns`).
    """

    def __init__(self, path: str | os.PathLike[str], capacity: int = HISTORY) -> None:
        self.reader = BeltLogReader(path)
        self._entries = self.reader.__iter__()
        self._next: Entry | None = None
        self.header: LogHeader | None = None
        first = self._pull()
        if isinstance(first, LogHeader):
            self.header = first
        else:
            self._next = first
        extrapolation = 0.5 if self.header is None else self.header.max_extrapolation_s
        self._max_gap_ns = round(extrapolation * 1e9)
        self._history = BeltHistory(capacity, extrapolation)
        self.exposures = ExposureClock(
            offset_ns=None if self.header is None else self.header.exposure_offset_ns
        )
        self._belts: deque[LoggedBelt] = deque()
        self.used = 0
        """Readings replayed so far."""

    def _pull(self) -> Entry | None:
        return next(self._entries, None)

    def _fill(self, time_ns: int) -> None:
        """Read on until the history holds the first reading after `time_ns` (or the end)."""
        while True:
            latest = self._history.latest()
            if latest is not None and latest.time_ns > time_ns:
                return
            entry = self._next if self._next is not None else self._pull()
            self._next = None
            if entry is None:
                return
            if isinstance(entry, BeltReading):
                self._history.append(entry)
                self.used += 1
            elif isinstance(entry, LoggedBelt):
                self._belts.append(entry)
            # a second header is ignored: the first one placed the frames

    def frame_time_ns(self, frame: Frame) -> int:
        """The host time of a frame's exposure, as the live run placed it."""
        return self.exposures.host_time_ns(frame)

    def reading_at(self, time_ns: int) -> BeltReading | None:
        """The belt at a host time, as the live link would have given it (None: unknown)."""
        self._fill(time_ns)
        before = self._history.before(time_ns)
        if before is None or time_ns - before.time_ns > self._max_gap_ns:
            return None
        after = self._history.latest()
        if after is not None and after.time_ns - before.time_ns > self._max_gap_ns:
            # the link fell silent after `before`: live, the next reading was not there yet
            moved = before.speed_mps * (time_ns - before.time_ns) * 1e-9
            return replace(before, time_ns=time_ns, distance_m=before.distance_m + moved)
        return self._history.at(time_ns)

    def belts_until(self, time_ns: int) -> list[LoggedBelt]:
        """Belts logged at or before `time_ns` and not handed out yet (oldest first)."""
        self._fill(time_ns)
        out = []
        while self._belts and self._belts[0].time_ns <= time_ns:
            out.append(self._belts.popleft())
        return out

    def finish(self) -> None:
        """Read the rest of the log, so that `reader` counts every line in it, and close it."""
        for _ in self._entries:
            pass

    def close(self) -> None:
        """Close the log (what is left unread is not counted)."""
        self._entries.close()

    def summary(self) -> str:
        """One closing line: readings used and lines skipped."""
        r = self.reader
        text = f"conveyor log {r.path.name}: {self.used} of {r.readings} readings used"
        if self.header is None:
            text += "; no header line (frames placed in time from their own timestamps)"
        if r.skipped:
            text += f"; {r.skipped} damaged lines skipped (first: {r.first_error})"
        return text
