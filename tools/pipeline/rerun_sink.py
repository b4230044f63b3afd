"""Rerun output off the hot path: `log()` queues a frame, a worker thread does the logging.

The worker writes frames in batches, one rerun call per entity for the lot (rerun's cost per
call, and waking its threads, is most of what logging a frame costs next to a tracker on
the same core): a file's every `SYNC_FRAMES` frames, a live viewer's every
`LIVE_BATCH_FRAMES`, and sooner when the oldest queued frame has waited `FILE_DELAY_S` or
`LIVE_DELAY_S` (a stalled camera never holds frames back longer).

Live viewers (spawn, connect, serve, stdout) get a short queue: when the viewer falls
behind, rerun's own send queue pushes back on the worker, our queue fills, and the oldest
queued frame is dropped and counted, so the camera and tracker never wait. A file gets a
longer queue and loses nothing: if the worker ever falls that far behind, `log()` waits for
room (counted in `stats`); the worker in turn waits for rerun to write every `SYNC_FRAMES`
frames, so nothing piles up in rerun's own unbounded queues to the file. Events are never
dropped. `close()` drains the queue and closes the recording, so a file is complete (with
rerun's footer); it also runs at interpreter exit (Ctrl-C included).

A file is written in segments (`rerun_target` has the bounds): after a sync, a file past its
size or age is closed, footer and all, and the worker goes on in the next one. Each closed
file passes `rerun rrd verify`; the memory rerun holds for a footer is one segment's. A
process killed outright (SIGKILL, power loss) leaves its last file without a footer, perhaps
cut inside a message, which rerun's readers refuse; `rerun rrd optimize CUT.rrd -o OK.rrd`
recovers every whole message in it, and every earlier segment is intact.
"""

from __future__ import annotations

import argparse
import atexit
import sys
import tempfile
import threading
import time
import uuid
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy.typing as npt
import rerun as rr

from tofcut._closing import Closing
from tofcut.driver.calibration import Calibration
from tofcut.driver.errors import TofcutError
from tofcut.tools.pipeline.rerun_log import APP_ID, FrameLogger, FrameRow, default_blueprint
from tofcut.tools.pipeline.rerun_target import BlueprintSource, RerunTarget, target_from_args
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import TrackedFrame

LIVE_QUEUE_FRAMES = 8
"""About 0.15 s at 50 fps: a live view should lag little, so it drops early."""
FILE_QUEUE_FRAMES = 64
"""About 1.3 s at 50 fps of slack before a file makes `log()` wait."""
SYNC_FRAMES = 16
"""A file's worker waits for rerun to write what it was given every this many frames: rerun's
own queues to a file are unbounded, so a worker faster than rerun's encoder and the disk
would pile frames up in memory (about 190 KB each) instead of waiting in `log()`."""
LIVE_BATCH_FRAMES = 5
LIVE_DELAY_S = 0.1
"""A live viewer gets frames 5 at a time (0.1 s at 50 fps), at most 0.1 s after they were
queued (by default rerun's own batcher holds `rr.log` rows up to 0.2 s)."""
FILE_DELAY_S = 1.0
"""A file's frames are written at most this long after they were queued."""
LIVE_CLOSE_TIMEOUT_S = 5.0
"""How long `close()` gives a live viewer to take what is queued before abandoning it."""


class RerunOutputError(TofcutError):
    """The rerun output failed (a file that cannot be written), or was used after close."""


@dataclass(frozen=True)
class SinkStats:
    """What happened to the frames handed to a sink."""

    logged: int
    """Frames handed to `log()`."""
    written: int
    """Frames written to the recording."""
    dropped: int
    """Frames dropped because a live viewer was behind."""
    waits: int
    """`log()` calls that waited for room (file mode only)."""
    waited_s: float
    """Time those calls waited, in total."""
    writer_cpu_s: float
    """CPU time of the worker thread's Python side (it holds the GIL: it competes with the
    tracker, unlike rerun's native encoder threads)."""


@dataclass(frozen=True)
class CameraTree:
    """Where one camera's worker logs in a recording that several cameras share: under
    `root` (`cameras/SERIAL`), in the recording `recording_id`, whose layout has a tab for
    each of `roots`. The default is one camera's recording, at the top."""

    root: str = ""
    recording_id: str | None = None
    """None: a recording of its own."""
    roots: tuple[str, ...] = ("",)

    def __post_init__(self) -> None:
        if self.root not in self.roots:
            raise ValueError(f"the camera's tree {self.root!r} is not among {self.roots}")


@dataclass(frozen=True, eq=False)
class _Frame:
    row: FrameRow
    queued_s: float
    """`time.monotonic()` when queued."""


@dataclass(frozen=True)
class _Event:
    text: str
    level: str


class RerunSink(Closing):
    """A recording of a tracked run, written by a worker thread; see the module docstring.

    `lossless` overrides the target's drop policy (None: files lose nothing, viewers drop).
    """

    def __init__(
        self,
        calibration: Calibration,
        target: RerunTarget,
        belt_direction: npt.ArrayLike | None = None,
        *,
        name: str | None = None,
        queue_frames: int | None = None,
        lossless: bool | None = None,
        tree: CameraTree = CameraTree(),
    ) -> None:
        self.target = target
        self.lossless = target.lossless if lossless is None else lossless
        self.capacity = queue_frames or (FILE_QUEUE_FRAMES if self.lossless else LIVE_QUEUE_FRAMES)
        if self.capacity < 1:
            raise ValueError("the rerun queue must hold at least one frame")
        self.batch_frames = min(SYNC_FRAMES if self.lossless else LIVE_BATCH_FRAMES, self.capacity)
        self.delay_s = FILE_DELAY_S if self.lossless else LIVE_DELAY_S
        rec = rr.RecordingStream(APP_ID, recording_id=tree.recording_id or uuid.uuid4())
        try:
            self._blueprint = BlueprintSource(rec, default_blueprint(tree.roots))
            target.attach(rec, self._blueprint)
        except Exception as exc:
            raise RerunOutputError(f"cannot start rerun output ({target.kind}): {exc}") from exc
        self._name = name
        if name:
            rec.send_recording_name(name)
        self._writer = FrameLogger(rec, calibration, belt_direction, tree.root)
        self._files: list[Path] = [target.path] if target.path is not None else []
        self._segment_started = time.monotonic()
        self._segment_due = False
        self._cond = threading.Condition()
        self._items: deque[_Frame | _Event] = deque()
        self._queued_frames = 0
        self._logged = 0
        self._written = 0
        self._dropped = 0
        self._waits = 0
        self._waited_s = 0.0
        self._writer_cpu_s = 0.0
        self._closing = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="rerun-output", daemon=True)
        self._thread.start()
        atexit.register(self.close)

    @classmethod
    def from_args(
        cls,
        args: argparse.Namespace,
        calibration: Calibration,
        belt_direction: npt.ArrayLike | None = None,
        *,
        name: str | None = None,
        tree: CameraTree = CameraTree(),
    ) -> RerunSink | NullSink:
        """The sink `add_rerun_options` asked for; says where the recording goes.

        The message goes to stderr when the recording itself goes to stdout. `--headless`
        alone gives a `NullSink`: nothing is recorded, nothing written.
        """
        target = target_from_args(args)
        out = sys.stderr if target.kind == "stdout" else sys.stdout
        print(f"rerun: {target.describe()}", file=out, flush=True)
        if target.kind == "none":
            return NullSink()
        return cls(calibration, target, belt_direction, name=name, tree=tree)

    # --- the hot path -----------------------------------------------------------------------

    def log(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        """Queue one tracked frame and the pipeline's health; never waits on a live viewer."""
        with self._cond:
            self._check_usable()
            if self._queued_frames >= self.capacity:
                if self.lossless:
                    self._wait_for_room()
                else:
                    self._drop_oldest_frame()
            row = FrameRow(tracked, status, time.time_ns())
            self._items.append(_Frame(row, time.monotonic()))
            self._queued_frames += 1
            self._logged += 1
            # The worker needs waking for a first frame (to time its delay) or a full batch.
            if self._queued_frames == 1 or self._queued_frames >= self.batch_frames:
                self._cond.notify_all()

    def event(self, text: str, level: str = "INFO") -> None:
        """Queue a text line (device stall, disconnect, reconnect; rejects); never dropped."""
        with self._cond:
            self._check_usable()
            self._items.append(_Event(text, level))
            self._cond.notify_all()

    @property
    def dropped(self) -> int:
        """Frames dropped so far because a live viewer was behind (always 0 for a file)."""
        with self._cond:
            return self._dropped

    @property
    def stats(self) -> SinkStats:
        with self._cond:
            return SinkStats(
                self._logged,
                self._written,
                self._dropped,
                self._waits,
                self._waited_s,
                self._writer_cpu_s,
            )

    @property
    def files(self) -> list[Path]:
        """The files written so far, in order: the target's path alone, or its segments."""
        with self._cond:
            return list(self._files)

    def summary(self) -> str:
        """One line for the end of a run: what was written where, what was dropped."""
        s = self.stats
        files = self.files
        if len(files) > 1:
            assert self.target.path is not None
            path = self.target.path
            pattern = path.with_name(f"{path.stem}-*{path.suffix}")
            text = (
                f"rerun: {s.written} of {s.logged} frames written to {len(files)} files, "
                f"{files[0]} to {files[-1].name} (view them together with: rerun {pattern})"
            )
        elif self.target.kind == "save":
            text = f"rerun: {s.written} of {s.logged} frames written to {self.target.path}"
        else:
            text = f"rerun: {s.written} of {s.logged} frames sent ({self.target.kind})"
        if s.dropped:
            text += f", {s.dropped} dropped to keep up"
        if odd := self._writer.odd_device_times:
            text += f"; {odd} without a device time (their timestamps are out of range)"
        if s.waits:
            text += f"; the file writer held up the pipeline {s.waits} times ({s.waited_s:.2f} s)"
        return text

    def _check_usable(self) -> None:
        if self._error is not None:
            raise RerunOutputError(f"rerun output failed: {self._error}") from self._error
        if self._closing:
            raise RerunOutputError("rerun output is closed")

    def _wait_for_room(self) -> None:
        start = time.perf_counter()
        self._waits += 1
        while self._queued_frames >= self.capacity and self._error is None:
            self._cond.wait()
        self._waited_s += time.perf_counter() - start
        self._check_usable()

    def _drop_oldest_frame(self) -> None:
        for i, item in enumerate(self._items):
            if isinstance(item, _Frame):
                del self._items[i]
                self._queued_frames -= 1
                self._dropped += 1
                return

    # --- the worker -------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                batch = self._next_batch()
                if batch is None:
                    return
                dropped = self._dropped
                self._cond.notify_all()
            start = time.thread_time()
            try:
                if isinstance(batch, _Event):
                    self._writer.write_event(batch.text, batch.level)
                else:
                    self._write_frames(batch, dropped)
            except Exception as exc:
                with self._cond:
                    self._error = exc
                    self._cond.notify_all()
                return
            with self._cond:
                self._writer_cpu_s += time.thread_time() - start

    def _write_frames(self, batch: list[_Frame], dropped: int) -> None:
        """Write a batch, into the next file if the current one is due to close; a file's
        worker then waits for rerun each time `SYNC_FRAMES` more frames have been written.
        A file is closed only when a frame is there for the next, so none holds no frame."""
        if self._segment_due:
            self._next_segment()
        self._writer.write_frames([f.row for f in batch], dropped)
        with self._cond:
            before = self._written
            self._written += len(batch)
        if self.lossless and self._written // SYNC_FRAMES > before // SYNC_FRAMES:
            self._writer.sync()
            self._segment_due = self._due()
        elif not self.lossless and self.target.kind == "save":
            self._segment_due = self._due()

    def _due(self) -> bool:
        """Whether the current file is past its segment's size or age."""
        t = self.target
        if t.kind != "save":
            return False
        aged = t.segment_s > 0 and time.monotonic() - self._segment_started >= t.segment_s
        try:
            return aged or (
                t.segment_bytes > 0 and self._files[-1].stat().st_size >= t.segment_bytes
            )
        except OSError:  # gone: rerun will fail on the next write, and say so
            return aged

    def _next_segment(self) -> None:
        """Close the current file and start the next one."""
        t = self.target
        current = self._files[-1]
        number = len(self._files) + 1
        following = t.segment_path(number)
        # Closes the current file (rerun flushes it and writes its footer), then opens the next.
        t.start_segment(self._writer.rec, following, self._blueprint)
        if number == 2:  # the first file becomes RUN-0001.rrd now that there is a second
            first = t.segment_path(1)
            current.replace(first)
            current = first
        if self._name:
            self._writer.rec.send_recording_name(self._name)
        self._writer.restart()
        with self._cond:
            self._files[-1] = current
            self._files.append(following)
        self._segment_started = time.monotonic()

    def _next_batch(self) -> list[_Frame] | _Event | None:
        """Under the lock: the event at the head of the queue, or the frames before the next
        event once there are `batch_frames` of them, an event behind them, the first has
        waited `delay_s` or the sink is closing; None when closed and drained."""
        while True:
            head = self._items[0] if self._items else None
            if isinstance(head, _Event):
                self._items.popleft()
                return head
            frames: list[_Frame] = []
            for item in self._items:
                if not isinstance(item, _Frame):
                    break
                frames.append(item)
            if not frames and self._closing:
                return None
            wait: float | None = None
            if frames:
                wait = frames[0].queued_s + self.delay_s - time.monotonic()
                if (
                    len(frames) >= self.batch_frames
                    or len(frames) < len(self._items)
                    or wait <= 0
                    or self._closing
                ):
                    batch = frames[: self.batch_frames]
                    for _ in batch:
                        self._items.popleft()
                    self._queued_frames -= len(batch)
                    return batch
            self._cond.wait(wait)

    # --- the end ----------------------------------------------------------------------------

    def close(self) -> None:
        """Write what is queued and close the recording (a file is then complete); idempotent.

        A file waits for every frame. A live viewer gets `LIVE_CLOSE_TIMEOUT_S`; what it has
        not taken by then is counted as dropped. A served recording stays served while this
        object lives (see `rerun_target.wait_while_serving`).
        """
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._cond.notify_all()
        atexit.unregister(self.close)
        timeout = None if self.lossless else LIVE_CLOSE_TIMEOUT_S
        self._thread.join(timeout)
        if self._thread.is_alive():
            with self._cond:
                abandoned = sum(isinstance(i, _Frame) for i in self._items)
                self._items.clear()
                self._queued_frames = 0
                self._dropped += abandoned
            return
        if self._error is None:
            try:
                self._writer.close(timeout, keep_serving=self.target.kind == "serve")
            except Exception as exc:
                if self.lossless:  # a live viewer that is slow to take the last data is no error
                    self._error = exc
        if self._error is not None:
            raise RerunOutputError(f"rerun output failed: {self._error}") from self._error


class NullSink:
    """No recording (`--headless` without `--save`): takes frames and events, keeps none."""

    target = RerunTarget("none")
    dropped = 0

    def __init__(self) -> None:
        self._logged = 0

    def log(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        self._logged += 1

    def event(self, text: str, level: str = "INFO") -> None:
        pass

    @property
    def stats(self) -> SinkStats:
        return SinkStats(self._logged, 0, 0, 0, 0.0, 0.0)

    def summary(self) -> str:
        return "rerun: nothing recorded (--headless)"

    def close(self) -> None:
        pass


@dataclass(frozen=True)
class LoggingCost:
    """What logging a run to a file cost, next to what tracking it cost."""

    frames: int
    cpu_s: float
    """Process CPU time (every thread, rerun's own included) from the first `log()` until
    the file was complete."""
    writer_cpu_s: float
    """Of that, the worker thread's Python side, which shares the GIL with the tracker."""
    log_calls_s: float
    """Wall time the caller spent inside `log()`: what the hot path pays."""
    tracking_s: float
    file_bytes: int

    @property
    def ratio(self) -> float:
        """Logging CPU time over tracking time."""
        return self.cpu_s / self.tracking_s

    @property
    def cpu_ms_per_frame(self) -> float:
        return 1000.0 * self.cpu_s / self.frames


def measure_logging_cost(
    run: Sequence[tuple[TrackedFrame, PipelineStatus]],
    calibration: Calibration,
    tracking_s: float,
    belt_direction: npt.ArrayLike | None = None,
) -> LoggingCost:
    """Log `run` to a temporary .rrd file and compare the CPU it took with `tracking_s`.

    The queue holds the whole run (the frames are in memory already), so `log()` never
    waits for room and `log_calls_s` is the hot path's own cost.
    """
    if not run or tracking_s <= 0:
        raise ValueError("need at least one frame and a positive tracking time")
    with tempfile.TemporaryDirectory(prefix="tofcut-bench-") as tmp:
        path = Path(tmp) / "bench.rrd"
        sink = RerunSink(calibration, RerunTarget.save(path), belt_direction, queue_frames=len(run))
        in_log = 0.0
        cpu0 = time.process_time()
        for tracked, status in run:
            t0 = time.perf_counter()
            sink.log(tracked, status)
            in_log += time.perf_counter() - t0
        sink.close()
        cpu = time.process_time() - cpu0
        size = sum(f.stat().st_size for f in sink.files)
    return LoggingCost(len(run), cpu, sink.stats.writer_cpu_s, in_log, tracking_s, size)
