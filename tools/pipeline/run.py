"""The tracking pipeline: raw frames → demodulation → tracker → outputs, live or offline.

Live, USB reads run on their own thread into a bounded queue, so the camera never waits
for the tracker: when the tracker falls behind, the oldest frames are dropped and counted.
Offline (a capture), frames are read as fast as they are tracked and nothing is dropped.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Protocol

import numpy as np

from tofcut.driver.camera import Camera
from tofcut.driver.errors import TofcutError
from tofcut.driver.events import DeviceEvent
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.stream import StreamStats
from tofcut.tools.pipeline.frame_stamp import FrameStamp, frame_index
from tofcut.tools.pipeline.latency import LatencyHistogram
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.belt_prior import VelocityPrior
from tofcut.tracker.tracker import Tracker
from tofcut.tracker.tracks import TrackedFrame

QUEUE_FRAMES = 8
"""Frames the live queue holds; older ones are dropped when the tracker falls behind."""


class LiveFeed:
    """Reads a camera on its own thread into a bounded queue; iterating yields raw frames."""

    def __init__(
        self,
        camera: Camera,
        size: int = QUEUE_FRAMES,
        on_frame: Callable[[RawFrame], None] | None = None,
        *,
        wait_for_room: bool = False,
    ) -> None:
        """`on_frame` sees every frame received, on the reader thread, before it is queued
        (the soak's accounting); it must be quick. With `wait_for_room` the reader waits for
        the tracker instead of dropping frames: for a camera with no clock to keep up with
        (an emulated one on its virtual clock, `--fast`)."""
        if size < 1:
            raise ValueError(f"queue size must be at least 1, got {size}")
        self._camera = camera
        self._on_frame = on_frame
        self._wait_for_room = wait_for_room
        self._queue: deque[tuple[RawFrame, float]] = deque()
        self._size = size
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self.dropped = 0
        """Frames received but dropped because the tracker was behind."""
        self._thread = threading.Thread(target=self._read, name="tofcut-usb", daemon=True)

    def start(self) -> LiveFeed:
        self._thread.start()
        return self

    def _read(self) -> None:
        try:
            for raw in self._camera.raw_frames():
                if self._on_frame is not None:
                    self._on_frame(raw)
                with self._cond:
                    while self._wait_for_room and len(self._queue) >= self._size:
                        if self._stop.is_set():
                            return
                        self._cond.wait()
                    if len(self._queue) >= self._size:
                        self._queue.popleft()
                        self.dropped += 1
                    self._queue.append((raw, time.perf_counter()))
                    self._cond.notify()
                if self._stop.is_set():
                    break
        except BaseException as exc:  # handed to the consumer, which raises it
            self._error = exc
        finally:
            with self._cond:
                self._stop.set()
                self._cond.notify_all()

    def __iter__(self) -> Iterator[tuple[RawFrame, float]]:
        """(raw frame, perf_counter time it arrived) until the feed stops."""
        while True:
            with self._cond:
                while not self._queue and not self._stop.is_set():
                    self._cond.wait()
                if self._queue:
                    item = self._queue.popleft()
                    self._cond.notify_all()  # a reader waiting for room
                elif self._error is not None:
                    raise self._error
                else:
                    return
            yield item

    def stop(self) -> None:
        with self._cond:
            self._stop.set()
            self._cond.notify_all()
        self._thread.join(timeout=5.0)


def offline(frames: Iterable[RawFrame]) -> Iterator[tuple[RawFrame, float]]:
    """A capture or any other iterable of raw frames, stamped as they are taken."""
    for raw in frames:
        yield raw, time.perf_counter()


class Output(Protocol):
    """Something that takes every tracked frame: a file, the viewer, a status line."""

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None: ...

    def close(self) -> None: ...


EVENTS_QUEUED = 1024
"""Device events waiting for the relay's thread; more are dropped and counted."""


class EventRelay:
    """Device events from the camera's reader thread to the console and rerun, off that thread.

    `post` is the camera's `on_event`: it runs on the reader thread, sometimes under the
    camera's lock, so it only puts the event on a queue. A thread of the relay's own hands
    each event, in order, to every handler, as it happens (an outage shows while it lasts).
    """

    def __init__(self) -> None:
        self._queue: queue.Queue[DeviceEvent | None] = queue.Queue(EVENTS_QUEUED)
        self._handlers: list[Callable[[DeviceEvent], object]] = []
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        """What a handler raised, if one did (the relay then stops handing on events)."""
        self.dropped = 0
        """Events not handed on: `EVENTS_QUEUED` were waiting (a handler stuck, or failed);
        every event is still in the camera's `stats.events` and counts."""

    def post(self, event: DeviceEvent) -> None:
        """Queue one event; never waits (it runs on the camera's reader thread)."""
        try:
            self._queue.put_nowait(event)
        except queue.Full:
            self.dropped += 1

    def start(self, handlers: list[Callable[[DeviceEvent], object]]) -> EventRelay:
        """Hand events (those posted before too) to `handlers` from now on."""
        self._handlers = handlers
        self._thread = threading.Thread(target=self._run, name="tofcut-events", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        failed = False
        while (event := self._queue.get()) is not None:
            if failed:
                continue  # drain, so that post() never fills the queue for nothing
            try:
                for handle in self._handlers:
                    handle(event)
            except Exception as exc:  # raised to the pipeline by close()
                self.error = exc
                failed = True

    def close(self) -> None:
        """Hand on every event posted so far, then stop; raises what a handler raised."""
        if self._thread is not None:
            self._queue.put(None)  # waits for room: the relay's thread drains the queue
            self._thread.join()
            self._thread = None
        if self.error is not None:
            raise self.error


@dataclass
class RunSummary:
    """What a run did, for the closing line; its size does not grow with the run."""

    frames: int = 0
    dropped: int = 0
    latencies: LatencyHistogram = field(default_factory=LatencyHistogram)
    elapsed_s: float = 0.0
    tracks_started: int = 0
    interrupted: bool = False
    """Ctrl-C stopped the run (the outputs hold every frame tracked until then)."""

    def percentile_ms(self, q: float) -> float:
        return self.latencies.percentile(q) * 1e3


class TracksWriter:
    """`--tracks-out FILE.jsonl`: one JSON object per frame (format in the README)."""

    def __init__(self, path: Path) -> None:
        self._file: IO[str] = path.open("w", encoding="utf-8")

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        row = {**FrameStamp.of(tracked, status).to_json(), **tracked.to_json()}
        self._file.write(json.dumps(row, separators=(",", ":")) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class MotWriter:
    """`--mot-out FILE.txt`: MOTChallenge rows (what py-motmetrics and TrackEval read).

    `frame,id,bb_left,bb_top,bb_width,bb_height,conf,x,y,z`, one row per track seen in a
    frame (the tracks `--tracks-out` lists, in its order). `frame` is the run-wide index
    (`tofcut.tools.pipeline.frame_stamp`) + 1, so it never goes back even when the camera restarts
    its sequence (the camera's sequence and times are on `--tracks-out`'s line: a row of
    more columns is one py-motmetrics refuses); the box is the track's `bbox` in
    MOTChallenge's 1-based pixel convention (bb_left = u0 + 1); conf is 1; x, y, z are the
    3D centroid, camera coordinates in metres.
    """

    def __init__(self, path: Path) -> None:
        self._file: IO[str] = path.open("w", encoding="utf-8")

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        frame = frame_index(status) + 1
        for track in tracked.tracks:
            if not track.visible:
                continue
            u0, v0, u1, v1 = track.bbox
            x, y, z = (round(float(c), 6) for c in track.centroid)  # as --tracks-out has it
            self._file.write(
                f"{frame},{track.id},{u0 + 1},{v0 + 1},{u1 - u0},{v1 - v0},1,{x},{y},{z}\n"
            )
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class MasksWriter:
    """`--masks-out FILE.npz`: `labels` (frames × H × W, uint16, 0 background), `seq` and
    `frame` (the run-wide index, `tofcut.tools.pipeline.frame_stamp`).

    Every frame's labels stay in memory until `close()` writes the file (about 50 KB a
    176×144 frame): meant for runs of bounded length, not for unattended live runs. The
    file is written beside its name and renamed into place, so a failed write leaves no
    half file (and an older file of that name stays whole until the new one is).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._labels: list[np.ndarray] = []
        self._seq: list[int] = []
        self._frame: list[int] = []

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        self._labels.append(tracked.labels)
        self._seq.append(tracked.sequence)
        self._frame.append(frame_index(status))

    def close(self) -> None:
        if not self._labels:
            return
        labels, seq = np.stack(self._labels).astype(np.uint16), np.array(self._seq, np.int64)
        frame = np.array(self._frame, np.int64)
        self._labels, self._seq, self._frame = [], [], []
        partial = self.path.with_name(f".{self.path.name}.partial")
        try:
            with partial.open("wb") as f:
                np.savez_compressed(f, labels=labels, seq=seq, frame=frame)
            os.replace(partial, self.path)
        finally:
            partial.unlink(missing_ok=True)


def run(
    source: Iterable[tuple[RawFrame, float]],
    demodulate: Callable[[RawFrame], Frame],
    tracker: Tracker,
    outputs: list[Output],
    *,
    stats: Callable[[], StreamStats],
    dropped: Callable[[], int],
    prior: Callable[[Frame], VelocityPrior | None] = lambda frame: None,
    should_stop: Callable[[RunSummary], bool] = lambda s: False,
    events: EventRelay | None = None,
) -> RunSummary:
    """Track every frame of `source` and hand each result to every output.

    `prior` gives the belt's velocity at a frame (the conveyor's, or a fixed one). At the
    end, `events` is drained into the outputs, which are then closed in order.
    """
    summary = RunSummary()
    start = time.perf_counter()
    recent: deque[float] = deque(maxlen=50)
    try:
        for raw, arrived in source:
            frame = demodulate(raw)
            belt = prior(frame)
            tracked = tracker.update(frame, belt)
            done = time.perf_counter()
            recent.append(done)
            summary.frames += 1
            summary.latencies.add(done - arrived)
            summary.tracks_started += len(tracked.born)
            st = stats()
            span = recent[-1] - recent[0]
            status = PipelineStatus(
                fps=(len(recent) - 1) / span if span > 0 else 0.0,
                latency_s=done - arrived,
                frames=summary.frames,
                dropped=st.lost + dropped(),
                tracks=len(tracked.tracks),
                belt_speed_mps=float(np.linalg.norm(belt.mean)) if belt and belt.informed else None,
            )
            for out in outputs:
                out.write(tracked, status)
            if should_stop(summary):
                break
    except KeyboardInterrupt:  # the outputs are closed below: they keep every frame tracked
        summary.interrupted = True
    finally:
        summary.elapsed_s = time.perf_counter() - start
        summary.dropped = dropped()
        errors: list[BaseException] = []
        if events is not None:
            try:
                events.close()
            except (OSError, TofcutError) as exc:
                errors.append(exc)
        for out in outputs:
            try:
                out.close()
            except (OSError, TofcutError) as exc:
                errors.append(exc)
        if errors:
            raise errors[0]
    return summary
