"""The closing lines about a stream's losses: how many frames, which sequence numbers, and
which part of the count is an estimate (outages costed from time) rather than counted."""

from __future__ import annotations

from collections.abc import Iterable

from tofcut.driver.events import DeviceEvent, EventKind
from tofcut.driver.stream import Gap, StreamStats

RANGES_SHOWN = 8
"""Most recent lost sequence ranges listed in the closing lines."""

EVENT_LEVELS = {
    EventKind.DISCONNECTED: "WARN",
    EventKind.RESET: "WARN",
    EventKind.DEVICE_BUSY: "WARN",
    EventKind.RECONNECTED: "INFO",
    EventKind.GAVE_UP: "ERROR",
    EventKind.STALL_CLEARED: "WARN",
    EventKind.RESUMED: "INFO",
    EventKind.SEQUENCE_RESTART: "WARN",
}
"""The rerun log level of each kind of device event."""


def event_level(event: DeviceEvent) -> str:
    return EVENT_LEVELS.get(event.kind, "INFO")


def format_ranges(gaps: Iterable[Gap], estimated: Iterable[Gap] = (), limit: int = 0) -> str:
    """`5, 9-12 (estimated), ...`: each range of lost run sequence numbers; with `limit`,
    only the last `limit`, after a note of how many came before."""
    ranges = list(gaps)
    guessed = set(estimated)
    shown = ranges[-limit:] if limit else ranges
    parts = [
        (f"{a}" if a == b else f"{a}-{b}") + (" (estimated)" if (a, b) in guessed else "")
        for a, b in shown
    ]
    earlier = len(ranges) - len(shown)
    return (f"{earlier} earlier ranges, then " if earlier else "") + ", ".join(parts)


def describe_losses(stats: StreamStats) -> list[str]:
    """The closing lines: frames received and lost (counted vs estimated), damaged,
    reconnects, and the last lost sequence ranges (run numbering)."""
    counted = stats.lost - stats.lost_estimated
    line = f"received {stats.frames} frames; lost {stats.lost}"
    if stats.lost:
        line += (
            f" ({counted} counted from sequence numbers, "
            f"{stats.lost_estimated} estimated from outage time)"
        )
    line += f"; {stats.damaged} damaged"
    if stats.reconnects:
        line += f"; {stats.reconnects} reconnects"
    if stats.device_dropped_flags:
        line += f"; {stats.device_dropped_flags} frames came flagged after a FIFO overflow"
    lines = [line]
    if stats.gaps:
        more = " (older ones not kept)" if len(stats.gaps) == stats.gaps.maxlen else ""
        ranges = format_ranges(stats.gaps, stats.estimated_gaps, RANGES_SHOWN)
        lines.append(f"lost sequence numbers{more}: {ranges}")
    return lines


def describe_untracked(received: int, tracked: int, dropped: int) -> str | None:
    """The closing line for frames received but neither tracked nor dropped: those still
    queued, or arriving, when the run stopped (its time or frames were up, or Ctrl-C);
    None when every frame is accounted for."""
    left = received - tracked - dropped
    if left <= 0:
        return None
    return f"received but not tracked when the run stopped: {left}"


def stats_summary(stats: StreamStats) -> str:
    """One line of a stream's counts and its last lost sequence numbers: what `record` and
    `convert` say when they are done."""
    text = f"{stats.frames} frames, {stats.lost} lost, {stats.damaged} damaged"
    if stats.gaps:
        ranges = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in list(stats.gaps)[-5:])
        text += f" (lost sequence numbers: {ranges})"
    return text
