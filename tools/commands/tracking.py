"""What `tofcut track SOURCE` and `tofcut live [CAMERA]` share: the tracking options and the
run they ask for (track objects, export tracks and masks); the two commands only register.

SOURCE is a capture file, `usb[:SERIAL]` or `emulator[:SCENE]`. Offline sources show a
progress bar; live ones a one-line status (fps, tracks, losses).
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from tofcut.driver.camera import Camera
from tofcut.driver.capture import CaptureReader
from tofcut.driver.conveyor.belt_log import ReplayedLink, belt_log_path
from tofcut.driver.demod import demodulate
from tofcut.driver.events import DeviceEvent
from tofcut.driver.frames import Frame
from tofcut.tools.commands.arguments import (
    UsageError,
    non_negative_float,
    output_file,
    pixel,
    point,
    positive_float,
    positive_int,
)
from tofcut.tools.commands.ctrl_c import CtrlC
from tofcut.tools.commands.options import config_from_args
from tofcut.tools.commands.progress import Progress
from tofcut.tools.commands.startup import current as startup
from tofcut.tools.pipeline.belt_source import resolve_run_belt, run_metadata
from tofcut.tools.pipeline.conveyor_line import ConveyorLine, open_conveyor
from tofcut.tools.pipeline.keeping_up import PaceWatch
from tofcut.tools.pipeline.losses import describe_losses, describe_untracked, event_level
from tofcut.tools.pipeline.mots import DEFORMABLE_CLASS, RIGID_CLASS, MotsWriter
from tofcut.tools.pipeline.outputs import ConveyorOutput, RerunOutput
from tofcut.tools.pipeline.rerun_sink import CameraTree, NullSink, RerunSink
from tofcut.tools.pipeline.rerun_target import (
    add_rerun_options,
    check_viewer,
    wait_while_serving,
)
from tofcut.tools.pipeline.run import (
    EventRelay,
    LiveFeed,
    MasksWriter,
    MotWriter,
    Output,
    RunSummary,
    TracksWriter,
    offline,
    run,
)
from tofcut.tools.pipeline.run_belt import RunBelt
from tofcut.tools.pipeline.settings import applied, one_setting
from tofcut.tools.pipeline.sources import (
    Opened,
    SourceError,
    configure,
    open_source,
    scene_target,
)
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.belt_finder import BeltFinder
from tofcut.tracker.belt_prior import VelocityPrior
from tofcut.tracker.tracker import Tracker, TrackerParams
from tofcut.tracker.tracks import TrackedFrame


def add_tracking_options(p: argparse.ArgumentParser, *, seconds_help: str | None = None) -> None:
    """The tracking options; `seconds_help` (live) lets `--seconds 0` mean until Ctrl-C."""
    g = p.add_argument_group("tracking")
    g.add_argument(
        "--tracks-out", type=output_file, metavar="FILE.jsonl", help="tracks, one line a frame"
    )
    g.add_argument(
        "--mot-out", type=output_file, metavar="FILE.txt",
        help="tracks as MOTChallenge rows: frame,id,bb_left,bb_top,bb_width,bb_height,conf,"
        "x,y,z (frame counts from 1 over the run; x,y,z the 3D centroid, metres)",
    )  # fmt: skip
    g.add_argument(
        "--mots-out", type=output_file, metavar="FILE.txt",
        help="track masks as MOTS lines: time_frame id class_id img_height img_width rle "
        "(time_frame counts from 0 over the run; rle: COCO's, as pycocotools writes it)",
    )  # fmt: skip
    g.add_argument(
        "--masks-out", type=output_file, metavar="FILE.npz", help="label images of every frame"
    )
    g.add_argument("--frames", type=positive_int, help="stop after this many frames")
    g.add_argument(
        "--seconds", type=positive_float if seconds_help is None else non_negative_float,
        help=seconds_help or "stop after this long",
    )  # fmt: skip
    g.add_argument(
        "--keep-going", action="store_true",
        help="exit 0 even when damaged frames were skipped or no frame was tracked (the "
        "closing lines still say what was skipped)",
    )  # fmt: skip
    g.add_argument(
        "--target-pixel", type=pixel, action="append", default=[], metavar="U,V",
        help="follow a known target from this seed pixel (repeatable)",
    )  # fmt: skip
    g.add_argument(
        "--target-point", type=point, action="append", default=[], metavar="X,Y,Z",
        help="follow a known target from this 3D point, camera coordinates (repeatable)",
    )  # fmt: skip
    g.add_argument(
        "--deformable", action="store_true",
        help="the targets may bend (a person): every view is measured and what stands out "
        "beside a target is part of it (default: rigid objects, as on a conveyor)",
    )  # fmt: skip
    g.add_argument(
        "--set", type=one_setting, action="append", default=[], metavar="tracker.PARAM=VALUE",
        help="a tracker parameter (tofcut.tracker.params.TrackerParams; repeatable), e.g. "
        "tracker.beta=3 or tracker.background.rate=0.05",
    )  # fmt: skip
    g.add_argument(
        "--scene-target", action="store_true",
        help="emulator or emulator capture: follow the scene's marked target from its seed",
    )  # fmt: skip
    add_rerun_options(p)


class StatusLine:
    """The live one-line status on stderr: fps, tracks, losses, latency; and while the
    tracker learns the empty scene, that it does."""

    def __init__(self, progress: Progress, tracker: Tracker | None = None) -> None:
        self._progress = progress
        self._tracker = tracker

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        background = None if self._tracker is None else self._tracker.background
        learning = "learning the scene  " if background is not None and not background.ready else ""
        self._progress.update(
            status.frames,
            f"{learning}{status.fps:5.1f} fps  {status.tracks} tracks  {status.dropped} lost  "
            f"latency {status.latency_s * 1e3:.1f} ms",
        )

    def close(self) -> None:
        self._progress.close()


class Supervised(Protocol):
    """What a run is told when it is one camera's worker under a supervisor (`tofcut live
    CAMERA CAMERA ...`, `tools.commands.cameras`)."""

    serial: int
    """An emulated camera's serial number (each camera of the box has its own)."""
    tree: CameraTree
    """Where the camera logs in the recording."""

    def ready(self) -> None:
        """The camera, tracker and outputs are ready: returns when the run is to start."""

    def status(self, tracker: Tracker) -> Output:
        """The output that reports the run's health (instead of the status line)."""


def track(args: argparse.Namespace, *, live: bool, supervised: Supervised | None = None) -> int:
    """Run the tracker on the source the arguments name."""
    check_viewer(args)  # before anything slow: a viewer asked for must be there
    params = applied(
        TrackerParams(rigid=not args.deformable), {s.name: s.values[0] for s in args.set}
    )
    events = EventRelay()
    what = {"emulator": "starting the emulated camera", "capture": "opening the capture"}
    startup().step(what.get(args.source.kind, "opening the camera"))
    try:
        opened = open_source(
            args.source, realtime=not args.fast, seed=args.seed,
            amplitude_threshold=args.amplitude_threshold, reconnect=live, on_event=events.post,
            loop=args.loop,
            serial=None if supervised is None else supervised.serial,
        )  # fmt: skip
    finally:
        startup().done()
    try:
        return _track(args, live, opened, events, params, supervised)
    finally:
        opened.close()


def _track(
    args: argparse.Namespace,
    live: bool,
    opened: Opened,
    events: EventRelay,
    params: TrackerParams,
    supervised: Supervised | None,
) -> int:
    device = opened.device
    meta, _ = run_metadata(opened)
    if not live and (args.conveyor or args.conveyor_emulator):
        raise SourceError("the conveyor options need a live camera, not a capture")
    resolution = resolve_run_belt(args, opened)
    belt = resolution.belt
    startup().step(
        "loading the tracker",
        slow="compiling the tracker (a first run only: it is cached after)",
    )
    try:
        tracker = Tracker(params, belt=belt.geometry if belt else None)
    finally:
        startup().done()
    targets = list(args.target_pixel)
    if args.scene_target:
        seed = scene_target(meta)
        if seed is None:
            raise SourceError("--scene-target needs an emulated scene that marks a target")
        targets.append(seed)
    width, height = device.info.width, device.info.height
    for u, v in targets:
        if not (0 <= u < width and 0 <= v < height):
            raise UsageError(
                f"--target-pixel {u},{v} is outside the frame: the image is {width}x{height}, "
                f"so U is 0-{width - 1} and V is 0-{height - 1}"
            )
        tracker.add_target(pixel=(u, v))
    for xyz in args.target_point:
        tracker.add_target(point=np.array(xyz))
    replay = _replay(device)
    try:
        line = open_conveyor(
            args, opened, lambda e: sink.event(e.describe(), "INFO"), resolution=resolution
        )
    except BaseException:
        if replay is not None:
            replay.close()
        raise
    try:
        run_belt = RunBelt(resolution, tracker, line=line, replay=replay)
        if belt is None and not args.deformable:
            # nothing gave a belt: it is found from the frames (a person is not on one)
            run_belt.find(BeltFinder())
        direction = belt.geometry.direction if belt else None
        sink = RerunSink.from_args(
            args, device.calibration, direction, name=f"tofcut {args.source}",
            tree=CameraTree() if supervised is None else supervised.tree,
        )  # fmt: skip
        events.start([lambda e: sink.event(str(e), event_level(e)), _print_event])
        with CtrlC() as ctrl_c:
            summary = _run(
                args, live, opened, tracker, sink, events, line, run_belt.at_frame,
                lambda: ctrl_c.requested, supervised,
            )  # fmt: skip
        summary.interrupted |= ctrl_c.requested
        if replay is not None and not summary.interrupted:
            replay.finish()
    except KeyboardInterrupt:  # before the run started
        print("stopped by Ctrl-C before the run began", file=sys.stderr)
        return 130
    finally:
        if line is not None:
            line.close()
        if replay is not None:
            replay.close()
    fps = summary.frames / summary.elapsed_s if summary.elapsed_s > 0 else 0.0
    # with the recording on stdout (`--stdout`), what is said to the user goes to stderr
    say = functools.partial(print, file=sys.stderr if args.stdout else sys.stdout)
    say(
        f"tracked {summary.frames} frames in {summary.elapsed_s:.1f} s ({fps:.1f} fps): "
        f"{summary.tracks_started} tracks; latency p50 {summary.percentile_ms(50):.1f} ms, "
        f"p95 {summary.percentile_ms(95):.1f} ms, p99 {summary.percentile_ms(99):.1f} ms"
    )
    for text in describe_losses(device.stats):
        say(text)
    say(f"dropped by the tracker queue (the tracker fell behind): {summary.dropped}")
    untracked = describe_untracked(device.stats.frames, summary.frames, summary.dropped)
    if untracked is not None:
        say(untracked)
    say(sink.summary())
    say(run_belt.describe())
    found = run_belt.describe_found()
    if found is not None:
        say(found)
    if replay is not None:
        say(replay.summary())
    if opened.replay is not None:
        say(opened.replay.describe())
    if line is not None:
        say(line.summary())
    wait_while_serving(args)
    for name in ("tracks_out", "mot_out", "mots_out", "masks_out"):
        path = getattr(args, name)
        if path:
            say(f"wrote {path}")
    if summary.interrupted:
        say(f"stopped by Ctrl-C after {summary.frames} frames; the outputs hold every one")
        return 130
    return _damage_verdict(args, opened, summary, say)


def _damage_verdict(
    args: argparse.Namespace, opened: Opened, summary: RunSummary, say: Callable[..., None]
) -> int:
    """The closing line on what a damaged capture (read, or replayed by the emulated
    camera) made the run skip, and the exit status: 1 when frames were skipped or none was
    tracked, unless `--keep-going`."""
    device = opened.device
    damaged = truncated = 0
    if isinstance(device, CaptureReader):
        damaged, truncated = device.stats.damaged, device.truncated_bytes
    elif opened.replay is not None:
        damaged, truncated = opened.replay.damaged, opened.replay.truncated_bytes
    skipped = []
    if damaged:
        skipped.append(f"{damaged} damaged frames")
    if truncated:
        skipped.append(f"{truncated} bytes cut short at the end of the file")
    if not skipped and summary.frames > 0:
        return 0
    what = f"skipped {' and '.join(skipped)}" if skipped else "nothing skipped"
    say(f"{args.source.arg or args.source}: {what}; {summary.frames} frames tracked")
    problem = "no frame was tracked" if summary.frames == 0 else "the input is damaged"
    if args.keep_going:
        print(f"tofcut: warning: {problem} (--keep-going: exit status 0)", file=sys.stderr)
        return 0
    print(
        f"tofcut: error: {problem}: {what} (--keep-going accepts what could be read)",
        file=sys.stderr,
    )
    return 1


def _replay(device: Camera | CaptureReader) -> ReplayedLink | None:
    """A capture's conveyor log, replayed in place of the link; None without one."""
    if not isinstance(device, CaptureReader):
        return None
    path = belt_log_path(device.path)
    return ReplayedLink(path) if path.exists() else None


def _print_event(event: DeviceEvent) -> None:
    """A device event on the console (over the live status line on a terminal)."""
    text = f"device: {event}"
    if sys.stderr.isatty():
        text = f"\r{text:<120}"
    print(text, file=sys.stderr, flush=True)


def _run(
    args: argparse.Namespace,
    live: bool,
    opened: Opened,
    tracker: Tracker,
    sink: RerunSink | NullSink,
    events: EventRelay,
    line: ConveyorLine | None,
    prior: Callable[[Frame], VelocityPrior | None],
    stop_asked: Callable[[], bool] = lambda: False,
    supervised: Supervised | None = None,
) -> RunSummary:
    """The pipeline on a capture (progress bar) or a camera (reader thread, status line)."""
    device = opened.device
    outputs: list[Output] = [] if line is None else [ConveyorOutput(line)]
    if args.tracks_out:
        outputs.append(TracksWriter(args.tracks_out))
    if args.mot_out:
        outputs.append(MotWriter(args.mot_out))
    if args.mots_out:
        kind = DEFORMABLE_CLASS if args.deformable else RIGID_CLASS
        outputs.append(MotsWriter(args.mots_out, kind))
    if args.masks_out:
        outputs.append(MasksWriter(args.masks_out))
    outputs.append(RerunOutput(sink))
    limit_s = args.seconds
    if live and limit_s is None and args.frames is None:
        limit_s = getattr(args, "default_seconds", None)
    started = time.perf_counter()

    def should_stop(s: RunSummary) -> bool:
        if stop_asked():
            return True
        if args.frames is not None and s.frames >= args.frames:
            return True
        return limit_s is not None and time.perf_counter() - started >= limit_s

    if isinstance(device, CaptureReader):
        total = len(device) if args.frames is None else min(args.frames, len(device))
        outputs.append(StatusLine(Progress(total, f"tracking {args.source}")))
        return run(
            offline(device.raw_frames()),
            lambda raw: demodulate(raw, device.optics, device.amplitude_threshold),
            tracker, outputs, stats=lambda: device.stats, dropped=lambda: 0, prior=prior,
            should_stop=should_stop, events=events,
        )  # fmt: skip
    configure(opened, config_from_args(args, device.config))
    print(
        f"camera {device.serial} ({args.source}): {device.config.describe()}",
        file=sys.stderr if args.stdout else sys.stdout,
    )
    if supervised is None:
        outputs.append(StatusLine(Progress(None, "live"), tracker))
    else:
        outputs.append(supervised.status(tracker))
        try:
            supervised.ready()
        except KeyboardInterrupt:  # stopped before the run began: the files are left whole
            for out in outputs:
                out.close()
            raise
        started = time.perf_counter()
    fast = args.fast and args.source.kind == "emulator"  # a virtual clock: no frame to lose
    feed = LiveFeed(device, wait_for_room=fast).start()
    rate = device.config.frame_rate
    outputs.append(
        PaceWatch(
            lambda: device.stats, lambda: feed.dropped, time.monotonic, rate,
            emulated=args.source.kind == "emulator",
        )
    )  # fmt: skip
    try:
        return run(
            feed, device.demodulate, tracker, outputs, stats=lambda: device.stats,
            dropped=lambda: feed.dropped, prior=prior,
            should_stop=should_stop, events=events,
        )  # fmt: skip
    finally:
        feed.stop()
