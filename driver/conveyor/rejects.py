"""Rejects: which tracked objects the diverter pushes off the belt, and when.

Each frame, `observe(tracks, frame_time_ns)` measures every visible track and records where
it sits on the belt: its position along the belt minus the belt's travel at that frame (by
the encoder), a number that stays put while the object rides the belt. The object reaches
the diverter when the belt's travel is `diverter_m` minus that number. Each belt reading
(`on_reading`, called by the conveyor link for every poll) fires, once, every object that
has got there and that the rule matched in most of the frames it was seen in; objects that
pass without matching are forgotten.

Thread-safe: frames come from the tracker's thread, readings from the link's.
"""

from __future__ import annotations

import logging
import statistics
import threading
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from tofcut.driver.belt import BeltGeometry, BeltReading
from tofcut.driver.conveyor.reject_rule import RejectRule, TrackMeasures, TrackView, measure_track

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class RejectEvent:
    """One object sent to the diverter."""

    track_id: int
    target_m: float
    """Belt travel at which the object's centre is at the diverter."""
    distance_m: float
    """Belt travel of the reading that fired it."""
    count: int
    """Encoder count of that reading."""
    time_ns: int
    """Host time of that reading."""
    measures: TrackMeasures
    """The object's measures in the frame that showed most of it."""

    def describe(self) -> str:
        m = self.measures
        return (
            f"reject track {self.track_id}: height {m.height:.3f} m, footprint "
            f"{m.footprint:.4f} m², volume {m.volume * 1e3:.2f} L; diverter at belt "
            f"{self.target_m:.3f} m, fired at {self.distance_m:.3f} m (encoder {self.count})"
        )


@dataclass(frozen=True)
class RejectStats:
    views: int = 0
    """Track observations placed on the belt."""
    unplaced: int = 0
    """Observations dropped because the belt's position at that frame was unknown."""
    fired: int = 0
    passed: int = 0
    """Objects that reached the diverter without matching the rule."""
    no_belt: int = 0
    """Track observations dropped because the belt's geometry was not known yet."""
    belt_changes: int = 0
    """Times the belt's geometry was replaced during the run (`set_belt`)."""
    forgotten: int = 0
    """Objects dropped unfired because `CANDIDATES_KEPT` newer ones were waiting (a stuck or
    backwards encoder never brings them to the diverter)."""


@dataclass
class _Candidate:
    offsets: deque[float] = field(default_factory=lambda: deque(maxlen=_MAX_VIEWS))
    """Belt offsets from views that show the whole object."""
    cut_offsets: deque[float] = field(default_factory=lambda: deque(maxlen=_MAX_VIEWS))
    """From views cut by the image border (used only when there are no others)."""
    votes: int = 0
    views: int = 0
    best: TrackMeasures | None = None
    """The measures of the view with the most pixels."""


_MAX_VIEWS = 200
_MAX_DONE = 4096
EVENTS_KEPT = 1024
"""Fired rejects kept for `events` (the newest); `stats.fired` counts every one."""
CANDIDATES_KEPT = 1024
"""Objects waiting to reach the diverter that are kept (the newest seen); older ones are
dropped and counted in `stats.forgotten`. A working line has a handful in flight."""


class RejectScheduler:
    """Matches tracks against a rule and fires the diverter when matching ones reach it."""

    def __init__(
        self,
        rule: RejectRule,
        belt: BeltGeometry | None,
        diverter_m: float,
        belt_at: Callable[[int], BeltReading | None],
        fire: Callable[[RejectEvent], None],
    ) -> None:
        """`belt`: the belt's geometry, or None until it is known (`set_belt`; till then
        nothing is placed); `belt_at(time_ns)`: the belt at a frame's time
        (`ConveyorClient.reading_at`); `fire(event)`: send the command (e.g.
        `lambda e: client.divert(e.track_id)`)."""
        self.rule = rule
        self.belt = belt
        self.diverter_m = diverter_m
        self._belt_at = belt_at
        self._fire = fire
        self._lock = threading.Lock()
        self._candidates: dict[int, _Candidate] = {}
        self._done: dict[int, None] = {}
        """Tracks that reached the diverter (an ordered set, the newest `_MAX_DONE`)."""
        self._events: deque[RejectEvent] = deque(maxlen=EVENTS_KEPT)
        self._stats = dict.fromkeys(
            ("views", "unplaced", "fired", "passed", "no_belt", "belt_changes", "forgotten"), 0
        )

    def set_belt(self, belt: BeltGeometry) -> None:
        """Measure on this belt from now on (one that became known during the run). Objects
        placed on the old one are dropped: their positions along it mean nothing on this one;
        the rule votes again from their next view."""
        with self._lock:
            self.belt = belt
            self._candidates.clear()
            self._stats["belt_changes"] += 1

    @property
    def events(self) -> list[RejectEvent]:
        """The newest `EVENTS_KEPT` rejects fired, oldest first."""
        with self._lock:
            return list(self._events)

    @property
    def stats(self) -> RejectStats:
        with self._lock:
            return RejectStats(**self._stats)

    def observe(
        self, tracks: Iterable[TrackView], time_ns: int, frame_shape: tuple[int, int] | None = None
    ) -> None:
        """Record one frame's tracks (camera coordinates) taken at host time `time_ns` (the
        exposure's: see `tofcut.driver.conveyor.exposure_clock`). With the frame's (H, W),
        objects cut by the image border vote on the rule but are not used to place the
        object."""
        belt = self.belt
        if belt is None:
            with self._lock:
                self._stats["no_belt"] += sum(t.visible for t in tracks)
            return
        measured = [m for t in tracks if t.visible and (m := measure_track(t, belt))]
        if not measured:
            return
        reading = self._belt_at(time_ns)
        with self._lock:
            if belt is not self.belt:  # replaced meanwhile: these were measured on the old one
                return
            if reading is None:
                self._stats["unplaced"] += len(measured)
                return
            for m in measured:
                if m.track_id in self._done:
                    continue
                c = self._candidate(m.track_id)
                cut = frame_shape is not None and _touches_border(m.track.bbox, frame_shape)
                (c.cut_offsets if cut else c.offsets).append(m.along - reading.distance_m)
                c.views += 1
                c.votes += bool(self.rule(m))
                if c.best is None or m.pixels >= c.best.pixels:
                    c.best = _without_points(m)
                self._stats["views"] += 1

    def _candidate(self, track_id: int) -> _Candidate:
        """Under the lock: the track's candidate; a new one pushes out the oldest when
        `CANDIDATES_KEPT` are waiting."""
        c = self._candidates.get(track_id)
        if c is None:
            while len(self._candidates) >= CANDIDATES_KEPT:
                del self._candidates[next(iter(self._candidates))]
                self._stats["forgotten"] += 1
            c = self._candidates[track_id] = _Candidate()
        return c

    def on_reading(self, reading: BeltReading) -> list[RejectEvent]:
        """Fire every matching object the belt has brought to the diverter; the events."""
        fired: list[RejectEvent] = []
        with self._lock:
            for track_id, c in list(self._candidates.items()):
                target = self.diverter_m - statistics.median(c.offsets or c.cut_offsets)
                if reading.distance_m < target:
                    continue
                del self._candidates[track_id]
                self._done[track_id] = None
                if len(self._done) > _MAX_DONE:
                    del self._done[next(iter(self._done))]
                if 2 * c.votes <= c.views or c.best is None:
                    self._stats["passed"] += 1
                    continue
                event = RejectEvent(
                    track_id, target, reading.distance_m, reading.count, reading.time_ns, c.best
                )
                self._events.append(event)
                self._stats["fired"] += 1
                fired.append(event)
        for event in fired:
            log.info("%s", event.describe())
            self._fire(event)
        return fired


def _without_points(m: TrackMeasures) -> TrackMeasures:
    """The measures with the track's point cloud left out (the scheduler keeps the best view
    of every object in flight; its points would be most of the memory and are not needed)."""
    empty = np.zeros((0, 3), np.float32)
    return replace(m, track=replace(m.track, points=empty))


def _touches_border(bbox: tuple[int, int, int, int], shape: tuple[int, int]) -> bool:
    u0, v0, u1, v1 = bbox
    return u0 <= 0 or v0 <= 0 or u1 >= shape[1] or v1 >= shape[0]
