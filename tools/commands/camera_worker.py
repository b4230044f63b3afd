"""One camera's worker under `tofcut live CAMERA CAMERA ...`: a process of its own that runs
the single-camera live run (`tracking.track`), with its own reader thread, tracker and
outputs, and talks to the supervisor (`tools.commands.cameras`) over one socket.

To the supervisor go the lines it would print (stdout and stderr, Python's), that it is
ready, its health a few times a second, and at the end its exit status, CPU time and last
health. From the supervisor come the job, then "go" (every camera starts together; "stop"
when the supervisor stopped first), and SIGINT to stop, as Ctrl-C stops a single run. When
the supervisor goes away (its socket reaches end of file) the worker stops as if it had
been sent SIGINT: no orphan runs on.
"""

from __future__ import annotations

import io
import os
import resource
import signal
import sys
import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from tofcut.tools.pipeline.rerun_sink import CameraTree
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracker import Tracker
from tofcut.tracker.tracks import TrackedFrame

STATUS_EVERY_S = 0.25
"""How often a worker tells the supervisor its health."""


@dataclass(frozen=True)
class CameraJob:
    """What one worker is to do: the run's arguments for its camera alone, and its place."""

    args: Any
    """The `argparse.Namespace` of a single-camera `tofcut live`."""
    serial: int
    """The serial number the camera is given if it is emulated (a USB camera has its own)."""
    tree: CameraTree
    verbose: int = 0
    quiet: bool = False


@dataclass(frozen=True)
class Health:
    """A camera's health as its status line would show it."""

    frames: int
    fps: float
    tracks: int
    lost: int
    """Frames lost so far: the device's, damaged ones and those the queue dropped."""
    learning: bool = False


def cpu_s() -> float:
    """User and system CPU time of this process, every thread."""
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


class _Lines(io.TextIOBase):
    """A text stream that sends each whole line to the supervisor."""

    def __init__(self, link: Link, stream: str) -> None:
        self._link = link
        self._stream = stream
        self._partial = ""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self._partial += text
        *lines, self._partial = self._partial.split("\n")
        for line in lines:
            if not self._link.send("line", self._stream, line.rpartition("\r")[2]):
                original = sys.__stdout__ if self._stream == "out" else sys.__stderr__
                if original is not None:  # the supervisor is gone: straight to the terminal
                    print(line, file=original, flush=True)
        return len(text)


class _HealthOutput:
    """The pipeline output that sends the camera's health to the supervisor."""

    def __init__(self, link: Link, tracker: Tracker) -> None:
        self._link = link
        self._tracker = tracker
        self._last = 0.0

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        background = self._tracker.background
        self._link.health = Health(
            status.frames, status.fps, status.tracks, status.dropped,
            background is not None and not background.ready,
        )  # fmt: skip
        now = time.monotonic()
        if now - self._last >= STATUS_EVERY_S:
            self._last = now
            self._link.send("health", self._link.health)

    def close(self) -> None:
        pass


class Link:
    """The worker's side of the socket: `tracking.Supervised` for the run."""

    def __init__(self, conn: Connection, job: CameraJob) -> None:
        self._conn = conn
        self._lock = threading.Lock()
        self.serial = job.serial
        self.tree = job.tree
        self.health: Health | None = None
        self.cpu_at_go: float | None = None
        self._gone = False

    def send(self, *message: object) -> bool:
        """Send a message; False when the supervisor is gone (and stop, as Ctrl-C would)."""
        with self._lock:
            if self._gone:
                return False
            try:
                self._conn.send(message)
            except OSError:
                self._lost()
                return False
        return True

    def _lost(self) -> None:
        """Under the lock: the supervisor is gone; stop the run, once."""
        if not self._gone:
            self._gone = True
            os.kill(os.getpid(), signal.SIGINT)

    def status(self, tracker: Tracker) -> _HealthOutput:
        return _HealthOutput(self, tracker)

    def ready(self) -> None:
        self.send("ready")
        if self._conn.recv() != "go":  # "stop": the supervisor stopped before the run began
            raise KeyboardInterrupt
        self.cpu_at_go = cpu_s()
        threading.Thread(target=self._watch, name="tofcut-supervisor", daemon=True).start()

    def _watch(self) -> None:
        """Stop the run, as Ctrl-C would, when the supervisor goes away."""
        try:
            while True:
                self._conn.recv()
        except (EOFError, OSError):
            with self._lock:
                self._lost()


def serve(fd: int) -> None:
    """The worker process's main: take a job from the socket `fd`, run it, report. SIGINT
    is ignored until here (the process starts with it so), then stops the run."""
    conn = Connection(fd)
    job: CameraJob = conn.recv()
    link = Link(conn, job)
    sys.stdout = _Lines(link, "out")
    sys.stderr = _Lines(link, "err")
    code = 130
    try:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        from tofcut.tools.cli import describe_error, setup_logging
        from tofcut.tools.commands.tracking import track

        setup_logging(job.verbose, job.quiet)
        code = track(job.args, live=True, supervised=link)
    except KeyboardInterrupt:
        pass
    except Exception as exc:
        text, code = describe_error(exc)
        link.send("error", text)
    cpu = None if link.cpu_at_go is None else cpu_s() - link.cpu_at_go
    link.send("done", code, cpu, link.health)
    sys.exit(code)
