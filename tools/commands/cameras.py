"""Many cameras on one box: `tofcut live CAMERA CAMERA ...` (or `--cameras FILE`) runs one
worker process per camera (`camera_worker`), each the single-camera live run with its own
reader thread, tracker and outputs, under this supervisor.

The supervisor starts the workers, lets them start their runs together once every one is
ready, shows one status line for all, restarts a worker that dies (at most `--restarts`
times, each said in one line; not one that ended with an error of its own, such as a camera
that is not there: that is said in one line at the end), stops them all on Ctrl-C or
SIGTERM, and sums up each camera at the end. Workers sit in process groups of their own, so
Ctrl-C at a terminal reaches the supervisor alone, which passes it on; a worker whose
supervisor is gone stops by itself.

Each camera is named by its serial number: a USB camera's own (`usb:SERIAL`), an emulated
camera's given here, `EMULATOR_SERIAL` for the first and one more for each next one. Its
files are the command line's with `-SERIAL` before the suffix (`tracks.jsonl` →
`tracks-4000002F.jsonl`); a restarted worker's go to `-SERIAL-restartN` files. In rerun the
cameras share one recording, each under `cameras/SERIAL` (`--rerun-per-camera tree`), or
each has a recording of its own (`file`), laid out as a single camera's.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from types import FrameType
from typing import Any

from tofcut.sim.device import EMULATOR_SERIAL
from tofcut.tools.commands.arguments import UsageError, non_negative_int, output_file
from tofcut.tools.commands.camera_list import OUTPUTS, CameraEntry
from tofcut.tools.commands.camera_worker import CameraJob, Health
from tofcut.tools.commands.progress import Progress
from tofcut.tools.pipeline.rerun_sink import CameraTree
from tofcut.tools.pipeline.rerun_target import default_recording_path, target_from_args

TREE = "tree"
FILE = "file"
RESTARTS = 3
"""A camera's worker that dies is started again at most this many times."""
STOP_GRACE_S = 30.0
"""After a stop, how long a worker may take to close its outputs before it is killed."""
REDRAW_S = 0.2
READY_WAIT_S = 120.0
"""How long the cameras that are ready wait for the others before they start."""
MIN_LEFT_S = 0.5
"""A worker that dies with less than this left of the run is not started again."""


def add_camera_list_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("several cameras (one worker process each)")
    g.add_argument(
        "--cameras", dest="cameras_file", type=Path, metavar="FILE.toml",
        help="the cameras to run, a [[camera]] table each (source, seed, fps, tracks_out, "
        "mot_out, mots_out, masks_out), after those named on the command line",
    )  # fmt: skip
    g.add_argument(
        "--rerun-per-camera", choices=[TREE, FILE], default=TREE,
        help="tree: one recording, each camera under cameras/SERIAL (saved, one file per "
        "camera, which rerun opens as one recording: rerun RUN-*.rrd); file: a recording "
        "of its own per camera, as a single camera's (default tree)",
    )  # fmt: skip
    g.add_argument(
        "--restarts", type=non_negative_int, default=RESTARTS, metavar="N",
        help=f"restart a camera's worker that dies at most N times (default {RESTARTS})",
    )  # fmt: skip
    g.add_argument(
        "--summary-json", type=output_file, metavar="FILE",
        help="write each camera's frames, losses, restarts and CPU time to FILE as JSON (a "
        "single camera then runs in a worker too)",
    )  # fmt: skip


def serial_text(serial: int) -> str:
    return f"{serial:08X}"


def _with_serial(path: Path, serial: str) -> Path:
    return path.with_name(f"{path.stem}-{serial}{path.suffix}")


def _serials(entries: list[CameraEntry]) -> list[tuple[str, int]]:
    """Each camera's serial number as text, and the number it is given if it is emulated."""
    named: list[tuple[str, int]] = []
    emulated = 0
    for entry in entries:
        spec = entry.source
        if spec.kind == "emulator":
            number = EMULATOR_SERIAL + emulated
            emulated += 1
            text = serial_text(number)
        elif spec.arg is None:
            raise UsageError("with several cameras, name each USB camera as usb:SERIAL")
        else:
            number, text = EMULATOR_SERIAL, spec.arg
        if text in (t for t, _ in named):
            raise UsageError(f"camera {text} is named twice")
        named.append((text, number))
    return named


def plan_jobs(args: argparse.Namespace, entries: list[CameraEntry]) -> list[CameraJob]:
    """A job for each camera, its arguments its own; `UsageError` (one line) when the
    cameras cannot run together."""
    if args.conveyor or args.conveyor_emulator:
        raise UsageError("the conveyor options take one camera, not several")
    target = target_from_args(args)
    if target.kind in ("spawn", "serve", "stdout"):
        raise UsageError(
            f"several cameras cannot share --{target.kind}: save them to files (the default), "
            "or start a viewer ('rerun') and --connect to it"
        )
    named = _serials(entries)
    recording = str(uuid.uuid4())
    roots = tuple(f"cameras/{text}" for text, _ in named)
    rrd = target.path or default_recording_path()
    jobs = []
    files: set[Path] = set()
    for entry, (text, number), root in zip(entries, named, roots, strict=True):
        one = copy.copy(args)
        one.source = entry.source
        one.seed = args.seed if entry.seed is None else entry.seed
        one.fps = args.fps if entry.fps is None else entry.fps
        for name in OUTPUTS:
            path = entry.outputs.get(name)
            if path is None and getattr(args, name) is not None:
                path = _with_serial(getattr(args, name), text)
            if path is not None and path.resolve() in files:
                raise UsageError(f"{path} is the output of two cameras")
            if path is not None:
                files.add(path.resolve())
            setattr(one, name, path)
        if target.kind == "save":
            one.save = str(_with_serial(rrd, text))
        tree = CameraTree(root, recording, roots) if args.rerun_per_camera == TREE else CameraTree()
        jobs.append(CameraJob(one, number, tree, verbose=args.verbose, quiet=args.quiet))
    return jobs


def restarted(job: CameraJob, restart: int, seconds: float | None, frames: int | None) -> CameraJob:
    """The first job of a camera, for its worker's `restart`-th start: new files, and the
    run's time or frames left."""
    one = copy.copy(job.args)
    for name in (*OUTPUTS, "save"):
        path = getattr(one, name, None)
        if path is not None:
            path = Path(path)
            setattr(one, name, path.with_name(f"{path.stem}-restart{restart}{path.suffix}"))
    if one.save is not None:
        one.save = str(one.save)
    one.seconds, one.frames, one.default_seconds = seconds, frames, None
    return dataclasses.replace(job, args=one)


def _serial_of(job: CameraJob) -> str:
    spec = job.args.source
    return serial_text(job.serial) if spec.kind == "emulator" else str(spec.arg)


@dataclass
class CameraRun:
    """What the supervisor knows of one camera."""

    first: CameraJob
    """The camera's job as planned (a restart's is made from it)."""
    serial: str
    restarts: int = 0
    frames_before: int = 0
    """Frames tracked by the camera's earlier workers (those that died)."""
    lost_before: int = 0
    health: Health | None = None
    cpu_s: float = 0.0
    """CPU time of its workers' runs, those that ended and said so."""
    cpu_frames: int = 0
    """The frames those workers tracked."""
    code: int | None = None
    error: str | None = None
    lines: list[str] = field(default_factory=list)
    """What the worker printed once its run had begun, shown at the end."""
    # the worker now running
    proc: subprocess.Popen[bytes] | None = None
    conn: Connection | None = None
    ready: bool = False
    started: bool = False
    finished: bool = False
    """The worker said it was done (else, if it ended, it died)."""

    @property
    def frames(self) -> int:
        return self.frames_before + (self.health.frames if self.health else 0)

    @property
    def lost(self) -> int:
        return self.lost_before + (self.health.lost if self.health else 0)

    @property
    def cpu_ms_per_frame(self) -> float | None:
        return 1e3 * self.cpu_s / self.cpu_frames if self.cpu_frames else None

    def to_json(self) -> dict[str, Any]:
        return {
            "serial": self.serial, "source": str(self.first.args.source), "frames": self.frames,
            "lost": self.lost, "restarts": self.restarts, "cpu_s": self.cpu_s,
            "cpu_ms_per_frame": self.cpu_ms_per_frame,
            "exit_status": self.code, "error": self.error,
        }  # fmt: skip


class Supervisor:
    """Runs the jobs' workers to their end; see the module docstring."""

    def __init__(
        self,
        jobs: list[CameraJob],
        *,
        restarts: int = RESTARTS,
        seconds: float | None = None,
        frames: int | None = None,
        on_health: Callable[[CameraRun, Supervisor], None] | None = None,
    ) -> None:
        if restarts < 0:
            raise ValueError("restarts cannot be negative")
        self.cameras = [CameraRun(job, _serial_of(job)) for job in jobs]
        self.restarts = restarts
        self.seconds = seconds
        self.frames = frames
        self._on_health = on_health
        self._go_at: float | None = None
        self._first_ready_at: float | None = None
        self.stopping = False
        self._stop_at = 0.0
        self._status = Progress(None, "live")

    # --- workers ------------------------------------------------------------------------

    def _start(self, camera: CameraRun, job: CameraJob) -> None:
        ours, theirs = socket.socketpair()
        code = (
            "import signal; signal.signal(signal.SIGINT, signal.SIG_IGN); "
            f"import sys; sys.path[:] = {sys.path!r}; "
            f"from tofcut.tools.commands.camera_worker import serve; serve({theirs.fileno()})"
        )
        try:
            camera.proc = subprocess.Popen(
                [sys.executable, "-c", code], pass_fds=[theirs.fileno()],
                stdin=subprocess.DEVNULL, process_group=0,
            )  # fmt: skip
        finally:
            theirs.close()
        camera.conn = Connection(ours.detach())
        camera.conn.send(job)
        camera.ready = camera.started = camera.finished = False
        camera.health = None

    def kill(self, camera: CameraRun, sig: int = signal.SIGKILL) -> None:
        """Send a signal to a camera's worker (the tests' way to kill one)."""
        if camera.proc is not None and camera.proc.poll() is None:
            camera.proc.send_signal(sig)

    def _ended(self, camera: CameraRun) -> None:
        """A worker's socket closed: it is done, or it died."""
        assert camera.proc is not None
        assert camera.conn is not None
        camera.conn.close()
        camera.conn = None
        status = camera.proc.wait()
        camera.proc = None
        if camera.finished:
            return
        if self.stopping and status in (130, -signal.SIGINT):
            camera.code = 130
            return
        how = (
            f"killed by {signal.Signals(-status).name}" if status < 0
            else f"ended with exit status {status}"
        )  # fmt: skip
        left = self._left(camera)
        again = camera.error is None and not self.stopping and camera.restarts < self.restarts
        if left and again:
            camera.restarts += 1
            camera.frames_before, camera.lost_before = camera.frames, camera.lost
            self._say(
                f"camera {camera.serial}: its worker {how}; restarting it "
                f"({camera.restarts} of at most {self.restarts})"
            )
            self._start(camera, restarted(camera.first, camera.restarts, *left))
            return
        camera.code = status if status > 0 else 1
        camera.error = camera.error or f"its worker {how}"
        if camera.restarts:
            camera.error += f" (after {camera.restarts} restarts)"

    def _left(self, camera: CameraRun) -> tuple[float | None, int | None] | None:
        """What a camera's restarted worker has left to do: (seconds, frames), None where
        the run has no such bound; None when nothing is left."""
        seconds = self.seconds
        if seconds is not None and self._go_at is not None:
            seconds -= time.monotonic() - self._go_at
            if seconds <= MIN_LEFT_S:
                return None
        frames = None if self.frames is None else self.frames - camera.frames
        if frames is not None and frames <= 0:
            return None
        return seconds, frames

    # --- messages -----------------------------------------------------------------------

    def _handle(self, camera: CameraRun, message: tuple[Any, ...]) -> None:
        kind = message[0]
        if kind == "line":
            _, stream, text = message
            if stream == "out" and camera.started:
                camera.lines.append(text)
            else:
                self._say(f"{camera.serial}: {text}", stream == "err")
        elif kind == "ready":
            camera.ready = True
        elif kind == "health":
            camera.health = message[1]
            if self._on_health is not None:
                self._on_health(camera, self)
        elif kind == "error":
            camera.error = message[1]
        elif kind == "done":
            _, code, cpu, health = message
            camera.finished = True
            camera.code = code
            camera.health = health or camera.health
            if cpu is not None and camera.health is not None:
                camera.cpu_s += cpu
                camera.cpu_frames += camera.health.frames

    def _go(self) -> None:
        """Every camera starts its run together, once all are ready (or `READY_WAIT_S` after
        the first was: a camera slow to open does not hold up the others for ever); a
        restarted one at once."""
        waiting = [c for c in self.cameras if c.conn is not None and not c.started]
        if not waiting:
            return
        now = time.monotonic()
        if self._first_ready_at is None and any(c.ready for c in waiting):
            self._first_ready_at = now
        everyone = all(c.ready or c.conn is None for c in self.cameras)
        waited = self._first_ready_at is not None and now - self._first_ready_at > READY_WAIT_S
        if self._go_at is None and not (everyone or waited or self.stopping):
            return
        for camera in waiting:
            if camera.ready and camera.conn is not None:
                camera.conn.send("stop" if self.stopping else "go")
                camera.started = True
        if self._go_at is None:
            self._go_at = time.monotonic()

    # --- the run ------------------------------------------------------------------------

    def _signal(self, signum: int, frame: FrameType | None) -> None:
        self.stop()

    def stop(self) -> None:
        """Stop every worker, as Ctrl-C stops a run (a second stop, as a second Ctrl-C)."""
        if not self.stopping:
            self.stopping = True
            self._stop_at = time.monotonic()
        for camera in self.cameras:
            self.kill(camera, signal.SIGINT)

    def run(self) -> list[CameraRun]:
        previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        for s in previous:
            signal.signal(s, self._signal)
        try:
            for camera in self.cameras:
                self._start(camera, camera.first)
            self._loop()
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
            for camera in self.cameras:  # only after an error of the supervisor's own
                self.kill(camera)
                if camera.proc is not None:
                    camera.proc.wait()
            self._status.close()
        return self.cameras

    def _loop(self) -> None:
        redrawn = 0.0
        while running := [c for c in self.cameras if c.conn is not None]:
            ready = wait([c.conn for c in running if c.conn is not None], REDRAW_S)
            for camera in running:
                conn = camera.conn
                if conn is None or conn not in ready:
                    continue
                try:
                    while conn.poll():
                        self._handle(camera, conn.recv())
                except (EOFError, OSError):
                    self._ended(camera)
            self._go()
            now = time.monotonic()
            if self.stopping and now - self._stop_at > STOP_GRACE_S:
                for camera in self.cameras:
                    if camera.proc is not None and camera.proc.poll() is None:
                        self._say(
                            f"camera {camera.serial}: its worker did not stop within "
                            f"{STOP_GRACE_S:g} s: killed"
                        )
                        self.kill(camera)
                self._stop_at = float("inf")  # once
            if now - redrawn >= REDRAW_S:
                redrawn = now
                self._status.update(sum(c.frames for c in self.cameras), self._status_text())

    def _status_text(self) -> str:
        """One status line for all: totals, and the slowest camera."""
        known = [(c, c.health) for c in self.cameras if c.health is not None]
        if not known:
            return "cameras starting"
        slowest, worst = min(known, key=lambda k: k[1].fps)
        learning = "learning the scenes  " if any(h.learning for _, h in known) else ""
        return (
            f"{len(known)} cameras  {learning}{sum(h.fps for _, h in known):.0f} fps  "
            f"{sum(h.tracks for _, h in known)} tracks  "
            f"{sum(c.lost for c in self.cameras)} lost  "
            f"(slowest {slowest.serial}: {worst.fps:.1f} fps)"
        )

    def _say(self, text: str, err: bool = True) -> None:
        """A line over the status line."""
        stream = sys.stderr if err else sys.stdout
        if self._status.enabled:
            text = f"\r{text:<120}"
        print(text, file=stream, flush=True)


def summary_lines(cameras: list[CameraRun]) -> list[str]:
    """Each camera's closing lines, then one line each that sums it up."""
    out = []
    for c in cameras:
        if c.lines:
            out.append(f"camera {c.serial} ({c.first.args.source}):")
            out += [f"  {line}" for line in c.lines]
    for c in cameras:
        ms = c.cpu_ms_per_frame
        cpu = "" if ms is None else f", {ms:.1f} ms CPU a frame"
        restarts = f", {c.restarts} restarts" if c.restarts else ""
        end = f": error: {c.error}" if c.error else ""
        out.append(f"{c.serial}: {c.frames} frames tracked, {c.lost} lost{restarts}{cpu}{end}")
    return out


def exit_status(cameras: list[CameraRun], interrupted: bool) -> int:
    """130 when stopped by Ctrl-C or SIGTERM; else 1 when a camera failed, 0 when none did."""
    if interrupted:
        return 130
    return max((1 if c.error or (c.code or 0) != 0 else 0) for c in cameras)


def run_cameras(args: argparse.Namespace, entries: list[CameraEntry]) -> int:
    """`tofcut live` with several cameras (or a camera list): plan, supervise, sum up."""
    jobs = plan_jobs(args, entries)
    seconds = args.seconds if args.seconds is not None else args.default_seconds
    supervisor = Supervisor(jobs, restarts=args.restarts, seconds=seconds, frames=args.frames)
    for job in jobs:
        job.args.seconds, job.args.default_seconds = seconds, None
    cameras = supervisor.run()
    for line in summary_lines(cameras):
        print(line)
    for c in cameras:
        if c.error:
            print(f"tofcut: error: camera {c.serial}: {c.error}", file=sys.stderr)
    if args.summary_json:
        doc = {"cameras": [c.to_json() for c in cameras], "interrupted": supervisor.stopping}
        args.summary_json.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {args.summary_json}")
    return exit_status(cameras, supervisor.stopping)
