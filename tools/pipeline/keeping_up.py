"""Whether the machine keeps up with the camera's frame rate, judged from what was lost.

A live run that cannot keep up loses frames in two measured ways: the camera's FIFO
overflows because the host read too late (the camera flags the next frame it sends, and the
driver counts the gap from sequence numbers), and the tracker's queue drops frames it fell
behind on. `PaceWatch` watches both over the last few seconds of a run and, the first time
they pass `SHARE` of the frames, says so in one line with what to lower.
"""

from __future__ import annotations

import sys
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from tofcut.driver.stream import StreamStats
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import TrackedFrame

WINDOW_S = 5.0
"""The span judged: the last few seconds, not the start (where caches warm)."""
SHARE = 0.02
"""Losses above this share of the frames mean the machine is too small for the rate."""
LEAST = 5
"""Fewer frames lost than this are a hiccup, whatever their share."""


@dataclass(frozen=True)
class Tally:
    """Counts at one moment of a run."""

    time_s: float
    received: int
    overflowed: int
    """Frames lost to the camera's FIFO overflowing (gaps counted from sequence numbers,
    once the camera has flagged an overflow)."""
    behind: int
    """Frames the tracker's queue dropped."""

    @classmethod
    def of(cls, time_s: float, stats: StreamStats, behind: int) -> Tally:
        counted = stats.lost - stats.lost_estimated - stats.damaged
        overflowed = counted if stats.device_dropped_flags else 0
        return cls(time_s, stats.frames, overflowed, behind)


def verdict(first: Tally, last: Tally, fps: float | None, emulated: bool) -> str | None:
    """The line saying the machine did not keep up between two tallies, or None if it did."""
    overflowed = last.overflowed - first.overflowed
    behind = last.behind - first.behind
    lost = overflowed + behind
    taken = last.received - first.received + overflowed
    span = last.time_s - first.time_s
    if lost < LEAST or taken <= 0 or lost / taken < SHARE:
        return None
    causes = []
    if overflowed:
        causes.append("the camera's FIFO overflowed (frames read too late)")
    if behind:
        causes.append("the tracker fell behind")
    rate = f"{fps:g} fps" if fps else "the camera's rate"
    kept = (taken - lost) / span if span > 0 else 0.0
    fits = max(1, int(kept / 5) * 5 if kept >= 10 else int(kept))  # what it delivered
    load = "a smaller scene, other busy programs" if emulated else "other busy programs"
    return (
        f"this machine does not keep up with {rate}: {' and '.join(causes)}, losing {lost} of "
        f"{taken} frames ({lost / taken:.0%}) in {span:.0f} s; lower --fps ({fits} should fit) "
        f"or the load ({load})"
    )


class PaceWatch:
    """A pipeline output that says once, on stderr, when the run stops keeping up."""

    def __init__(
        self,
        stats: Callable[[], StreamStats],
        behind: Callable[[], int],
        clock: Callable[[], float],
        fps: float | None,
        *,
        emulated: bool = False,
        say: Callable[[str], object] | None = None,
    ) -> None:
        self._stats = stats
        self._behind = behind
        self._clock = clock
        self.fps = fps
        self.emulated = emulated
        self._say = say or _warn
        self._tallies: deque[Tally] = deque()
        self.said: str | None = None
        """The line, once it was said."""

    def _tally(self) -> Tally:
        return Tally.of(self._clock(), self._stats(), self._behind())

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        if self.said is not None:
            return
        now = self._tally()
        tallies = self._tallies
        if not tallies or now.time_s - tallies[-1].time_s >= 0.5:
            tallies.append(now)
        while len(tallies) > 1 and now.time_s - tallies[1].time_s >= WINDOW_S:
            tallies.popleft()
        if now.time_s - tallies[0].time_s >= WINDOW_S:
            self._judge(tallies[0], now)

    def close(self) -> None:
        """A run shorter than the window is judged whole."""
        if self.said is None and self._tallies:
            self._judge(self._tallies[0], self._tally())

    def _judge(self, first: Tally, last: Tally) -> None:
        line = verdict(first, last, self.fps, self.emulated)
        if line is not None:
            self.said = line
            self._say(line)


def _warn(text: str) -> None:
    line = f"tofcut: warning: {text}"
    if sys.stderr.isatty():
        line = f"\r{line:<120}"  # over the live status line
    print(line, file=sys.stderr, flush=True)
