"""The soak's bookkeeping: faults injected one at a time, every lost frame attributed to the
fault that caused it (or to nothing), and the process's memory sampled as the run goes.

    audit = LossAudit(camera.stats)
    feed = LiveFeed(camera, on_frame=audit.see)       # the reader thread reports each frame
    injector = FaultInjector(faults, audit, rng).start()

A fault opens a *window*: it is injected after `begin(kind)`, and the window closes once
`settle_frames` frames have come after it. Losses the stream records while a window is open
are that fault's; outside any window they are the camera's own FIFO overflow when the next
frame carries the camera's "frames were dropped before this one" flag (the host read too
slowly), and *unexplained* otherwise.
"""

from __future__ import annotations

import os
import random
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from tofcut.driver.frames import RawFrame
from tofcut.driver.stream import Gap, StreamStats
from tofcut.tools.pipeline.losses import format_ranges

HOST_OVERFLOW = "no fault: the camera's FIFO overflowed (host read too slowly)"
UNEXPLAINED = "no fault: unexplained"
RANGES_KEPT = 5
"""Lost sequence ranges kept per cause (the most recent)."""


@dataclass
class Tally:
    """What one cause of loss cost over the run."""

    injected: int = 0
    lost: int = 0
    estimated: int = 0
    """The part of `lost` estimated from outage time."""
    damaged: int = 0
    reconnects: int = 0
    gaps: int = 0
    ranges: deque[Gap] = field(default_factory=lambda: deque(maxlen=RANGES_KEPT))
    estimated_ranges: deque[Gap] = field(default_factory=lambda: deque(maxlen=RANGES_KEPT))

    def describe_ranges(self) -> str:
        earlier = self.gaps - len(self.ranges)
        text = format_ranges(self.ranges, self.estimated_ranges)
        return f"{earlier} earlier ranges, then {text}" if earlier else text


@dataclass
class _Window:
    kind: str
    frames: int = 0


class LossAudit:
    """Attributes the stream's losses to the faults injected (see the module docstring)."""

    def __init__(self, stats: StreamStats, settle_frames: int = 20) -> None:
        self.stats = stats
        self.settle_frames = settle_frames
        self.tallies: dict[str, Tally] = {}
        self._cond = threading.Condition()
        self._window: _Window | None = None
        self._seen = (0, 0, 0, 0)
        """(lost, estimated, damaged, reconnects) as of the last frame seen."""
        self._last_gap_end = -1
        self._last_estimated_end = -1

    def tally(self, cause: str) -> Tally:
        return self.tallies.setdefault(cause, Tally())

    def begin(self, kind: str) -> None:
        """A fault of `kind` is about to be injected: open its window."""
        with self._cond:
            if self._window is not None:
                raise RuntimeError(f"fault {self._window.kind!r} has not settled yet")
            self._window = _Window(kind)
            self.tally(kind).injected += 1

    @property
    def open_window(self) -> str | None:
        """The fault whose window is open, if any."""
        with self._cond:
            return None if self._window is None else self._window.kind

    def wait_settled(self, timeout_s: float | None = None) -> bool:
        """Wait until no window is open; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._window is None, timeout_s)

    def see(self, raw: RawFrame) -> None:
        """One frame received (on the reader thread, right after the parser counted it)."""
        self._account(raw.header.dropped_before)

    def finish(self) -> None:
        """After the reader stopped: what it counted but never handed on (a frame parsed
        as the run stopped) goes to the open window, else is unexplained."""
        self._account(flagged=False, frame=False)

    def _account(self, flagged: bool, frame: bool = True) -> None:
        s = self.stats
        now = (s.lost, s.lost_estimated, s.damaged, s.reconnects)
        lost, estimated, damaged, reconnects = (a - b for a, b in zip(now, self._seen, strict=True))
        self._seen = now
        with self._cond:
            window = self._window
            if lost or damaged or reconnects:
                if window is not None:
                    cause = window.kind
                elif flagged and not estimated:
                    cause = HOST_OVERFLOW
                else:
                    cause = UNEXPLAINED
                t = self.tally(cause)
                t.lost += lost
                t.estimated += estimated
                t.damaged += damaged
                t.reconnects += reconnects
                self._take_gaps(t)
            if window is not None and frame:
                window.frames += 1
                if window.frames >= self.settle_frames:
                    self._window = None
                    self._cond.notify_all()

    def _take_gaps(self, tally: Tally) -> None:
        """Move the gaps the stream recorded since the last frame into `tally`."""
        for first, last in self.stats.gaps:
            if first > self._last_gap_end:
                tally.gaps += 1
                tally.ranges.append((first, last))
        for first, last in self.stats.estimated_gaps:
            if first > self._last_estimated_end:
                tally.estimated_ranges.append((first, last))
        if self.stats.gaps:
            self._last_gap_end = self.stats.gaps[-1][1]
        if self.stats.estimated_gaps:
            self._last_estimated_end = self.stats.estimated_gaps[-1][1]

    @property
    def accounted(self) -> int:
        """Lost frames attributed to some cause (every one the stream counted, by design)."""
        with self._cond:
            return sum(t.lost for t in self.tallies.values())


Inject = Callable[[], object]


class FaultInjector:
    """Injects faults one at a time on its own thread: waits a random quiet spell, picks the
    next kind (every kind once per round, in a shuffled order), injects it, and waits for
    its window to close before the next; all from one seeded `random.Random`."""

    def __init__(
        self,
        faults: dict[str, Inject],
        audit: LossAudit,
        rng: random.Random,
        *,
        quiet_s: float = 3.0,
        settle_timeout_s: float = 30.0,
        on_inject: Callable[[str], object] = lambda kind: None,
        on_stuck: Callable[[], object] = lambda: None,
    ) -> None:
        """`on_inject(kind)` is told of each fault as it is injected; `on_stuck()` is called
        when a fault's window has not closed after `settle_timeout_s` (the stream is dead:
        e.g. stop the camera, so the run ends)."""
        if not faults:
            raise ValueError("no faults to inject")
        self.faults = faults
        self.audit = audit
        self.rng = rng
        self.quiet_s = quiet_s
        self.settle_timeout_s = settle_timeout_s
        self._on_inject = on_inject
        self._on_stuck = on_stuck
        self.unsettled: list[str] = []
        """Faults whose window did not close within `settle_timeout_s` (the stream died)."""
        self._stop = threading.Event()
        self._round: list[str] = []
        self._thread = threading.Thread(target=self._run, name="tofcut-faults", daemon=True)

    def start(self) -> FaultInjector:
        self._thread.start()
        return self

    def next_kind(self) -> str:
        if not self._round:
            self._round = sorted(self.faults)
            self.rng.shuffle(self._round)
        return self._round.pop()

    def _run(self) -> None:
        while not self._stop.wait(self.rng.uniform(0.5, 1.5) * self.quiet_s):
            kind = self.next_kind()
            self.audit.begin(kind)
            self._on_inject(kind)
            self.faults[kind]()
            deadline = time.monotonic() + self.settle_timeout_s
            while not self.audit.wait_settled(0.2):
                if self._stop.is_set():
                    return
                if time.monotonic() > deadline:
                    self.unsettled.append(kind)
                    self._on_stuck()
                    return

    def stop(self) -> None:
        """Inject no more (a fault in flight finishes on its own timers)."""
        self._stop.set()
        self._thread.join(timeout=5.0)


def rss_bytes() -> int:
    """The process's resident set size, from /proc/self/statm (Linux)."""
    with open("/proc/self/statm", encoding="ascii") as f:
        fields = f.read().split()
    return int(fields[1]) * os.sysconf("SC_PAGE_SIZE")


@dataclass(frozen=True)
class MemoryGrowth:
    """Resident memory over a run, and how much it grew over the second half."""

    start_b: int
    half_b: int
    end_b: int
    peak_b: int
    second_half_growth_b: float
    """The least-squares slope of RSS over the second half, times its length: growth that
    warm-up (the first half) cannot explain, with sampling noise averaged out."""
    samples: int


class MemorySampler:
    """Samples RSS on its own thread every `interval_s` (at most `max_samples` are kept: the
    interval doubles, and every other sample is dropped, when they fill up)."""

    def __init__(self, interval_s: float = 0.5, max_samples: int = 512) -> None:
        self.interval_s = interval_s
        self.max_samples = max_samples
        self._samples: list[tuple[float, int]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._start = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="tofcut-memory", daemon=True)

    def start(self) -> MemorySampler:
        self._sample()
        self._thread.start()
        return self

    def _sample(self) -> None:
        with self._lock:
            self._samples.append((time.monotonic() - self._start, rss_bytes()))
            if len(self._samples) >= self.max_samples:
                self._samples = self._samples[::2]
                self.interval_s *= 2

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self._sample()

    def stop(self) -> MemoryGrowth:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._sample()
        with self._lock:
            return growth(self._samples)


def growth(samples: list[tuple[float, int]]) -> MemoryGrowth:
    """`MemoryGrowth` of (seconds, RSS bytes) samples in time order (at least one)."""
    end_t = samples[-1][0]
    second = [(t, b) for t, b in samples if t >= end_t / 2]
    half_b = second[0][1]
    slope = 0.0
    if len(second) >= 2:
        ts = [t for t, _ in second]
        mean_t = sum(ts) / len(ts)
        mean_b = sum(b for _, b in second) / len(second)
        var = sum((t - mean_t) ** 2 for t in ts)
        if var > 0:
            slope = sum((t - mean_t) * (b - mean_b) for t, b in second) / var
    return MemoryGrowth(
        start_b=samples[0][1],
        half_b=half_b,
        end_b=samples[-1][1],
        peak_b=max(b for _, b in samples),
        second_half_growth_b=slope * (end_t - second[0][0]),
        samples=len(samples),
    )
