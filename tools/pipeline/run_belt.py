"""The belt of a running pipeline: the one holder of what the run knows of its belt, which
hands it to the tracker, the rejects, the velocity prior and the conveyor log alike, at the
start and whenever a belt becomes known during the run.

    run_belt = RunBelt(resolution, tracker, line=line)          # live, or replay=ReplayedLink
    run(..., prior=run_belt.at_frame)                           # the pipeline, every frame
    run_belt.find(BeltFinder())                                 # where nothing gave a belt
    run_belt.offer(found)                                       # or from anywhere, any thread
    print(run_belt.describe())                                  # "belt: from the map (...)"

The velocity prior: the conveyor's encoder when linked (the live link, or the capture's
conveyor log replayed), else the belt's known speed, else none.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Protocol

from tofcut.driver.belt import BeltReading, KnownBelt
from tofcut.driver.conveyor.belt_log import BeltLogWriter, ReplayedLink
from tofcut.driver.frames import Frame
from tofcut.tools.pipeline.belt_source import (
    BeltResolution,
    conflict_warning,
    describe_belt,
    rank,
    warn,
)
from tofcut.tools.pipeline.conveyor_line import ConveyorLine
from tofcut.tracker.belt_finder import BeltFinder
from tofcut.tracker.belt_prior import VelocityPrior, belt_velocity_prior, known_speed_prior
from tofcut.tracker.tracker import Tracker


class Readings(Protocol):
    """Where the encoder's readings come from: the live link, or a conveyor log replayed."""

    def frame_time_ns(self, frame: Frame) -> int: ...

    def reading_at(self, time_ns: int) -> BeltReading | None: ...


class RunBelt:
    """What the run knows of its belt now, and where it came from.

    `offer(belt)` hands over a belt that became known during the run (the belt finder's, or
    one a conveyor log recorded), from any thread; it is applied on the pipeline's thread at
    the next frame (`at_frame`), so one frame is tracked with one belt throughout. By the
    precedence of `tools.pipeline.belt_source`, a found belt replaces only a found one (or none): a
    belt the run was given stays, and a found one that disagrees with it is one warning line.
    Applying a belt sets the tracker's `belt`, the rejects' (`RejectScheduler.set_belt`),
    the direction of the link's prior, and appends it to the conveyor log when recording.
    """

    def __init__(
        self,
        resolution: BeltResolution,
        tracker: Tracker | None = None,
        *,
        line: ConveyorLine | None = None,
        replay: ReplayedLink | None = None,
        log: BeltLogWriter | None = None,
        say: Callable[[str], object] = warn,
    ) -> None:
        """`tracker` is expected to hold `resolution.belt` already (`Tracker(belt=...)`);
        `line` is the live conveyor link, `replay` a capture's conveyor log in its place;
        `say` gets each warning line (printed on stderr by default)."""
        self.resolution = resolution
        self.tracker = tracker
        self.line = line
        self.replay = replay
        self.log = log
        self._found_by: BeltFinder | None = None
        self.finder: Callable[[Frame], KnownBelt | None] | None = None
        """Called with every frame before it is tracked; a belt it returns is offered."""
        self._say = say
        self._belt = resolution.belt
        self._detail = resolution.detail
        self._speed_from = resolution.speed_from
        self._lock = threading.Lock()
        self._pending: KnownBelt | None = None
        self._warned: set[str] = set()
        self._since: int | None = None
        """The sequence number of the frame from which the current belt's source was used,
        when it became known during the run."""
        self._refined = 0
        """Belts of that source applied after the first."""
        self.changes = 0
        """Belts applied during the run."""
        for text in resolution.warnings:
            say(text)

    @property
    def belt(self) -> KnownBelt | None:
        """The belt the run uses now."""
        return self._belt

    @property
    def readings(self) -> Readings | None:
        return self.line if self.line is not None else self.replay

    def offer(self, belt: KnownBelt) -> bool:
        """A belt that became known during the run (any thread); True if it will be used
        from the next frame on, False if a belt the run was given takes precedence."""
        with self._lock:
            current = self._pending or self._belt
            if current is not None and rank(belt) > rank(current):
                warning = conflict_warning(current, belt)
                if warning is not None and belt.source not in self._warned:
                    self._warned.add(belt.source)
                    self._say(warning)
                return False
            self._pending = belt
            return True

    def at_frame(self, frame: Frame) -> VelocityPrior | None:
        """Called by the pipeline with each frame before it is tracked: applies a belt
        offered since the last frame (first those the conveyor log recorded up to this
        frame, then the finder's), and returns the frame's velocity prior."""
        if self.replay is not None:
            for logged in self.replay.belts_until(frame.host_time_ns):
                self.offer(logged.belt)
        if self.finder is not None:
            found = self.finder(frame)
            if found is not None:
                self.offer(found)
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is not None:
            self._apply(pending, frame)
        return self.prior(frame)

    def prior(self, frame: Frame) -> VelocityPrior | None:
        """The frame's velocity prior: the encoder's, else the known speed's, else None
        (and None while the belt's direction is unknown)."""
        belt = self._belt
        if belt is None:
            return None
        readings = self.readings
        if readings is None:
            return known_speed_prior(belt)
        time_ns = readings.frame_time_ns(frame)
        return belt_velocity_prior(
            readings.reading_at(time_ns), belt.geometry.direction, time_ns=time_ns
        )

    def _apply(self, belt: KnownBelt, frame: Frame) -> None:
        if self._belt is None or self._belt.source != belt.source:
            self._since, self._refined = frame.sequence, 0
        else:
            self._refined += 1
        self._belt, self._detail, self._speed_from = belt, "", None
        self.changes += 1
        geometry = belt.geometry
        if self.tracker is not None:
            self.tracker.belt = geometry
        if self.line is not None:
            self.line.direction = geometry.direction
            if self.line.rejects is not None:
                self.line.rejects.set_belt(geometry)
        if self.log is not None:
            self.log.belt(belt, frame.host_time_ns)

    def find(self, finder: BeltFinder) -> None:
        """Look for the belt in the run's own frames (where nothing gave one): the finder's
        plane is offered as soon as it has one, again once it knows the travel, again when it
        moves the plane to the layer things are seen to move over, and once more when it is
        done; `describe_found` says how well it fits."""
        self._found_by = finder
        offered: list[tuple[bool, bool, int]] = []

        def found(frame: Frame) -> KnownBelt | None:
            belt = finder.update(frame).belt
            if belt is None:
                return None
            state = (belt.speed_mps is not None, finder.done, finder.moves)
            if offered and offered[-1] == state:
                return None
            offered.append(state)
            return belt

        self.finder = found

    def describe_found(self) -> str | None:
        """What the belt finder found and how well it fits, if the run looked for the belt."""
        finder = self._found_by
        if finder is None:
            return None
        return "found " + finder.finish().describe()

    def describe(self) -> str:
        """The closing line: where the belt came from, and where the prior did."""
        detail = self._detail
        if self._since is not None:
            detail = f"from frame {self._since}" + (
                f", refined {self._refined} times" if self._refined else ""
            )
        text = describe_belt(self._belt, detail, self._speed_from)
        if self._belt is None:
            return text
        if self.line is not None:
            return text + "; velocity prior from the conveyor link's encoder"
        if self.replay is not None:
            return text + "; velocity prior from the encoder readings in the capture's conveyor log"
        if self._belt.speed_mps is not None:
            return text + "; velocity prior from its speed"
        return text + "; no velocity prior (no speed known)"
