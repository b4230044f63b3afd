"""`tofcut record CAMERA -o FILE.tofcap`: write the raw stream to a capture file.

The capture's metadata keeps the belt the run knows at its start (the map's, else the
scene's: `belt` and `belt_source`); with a conveyor linked (`--conveyor PORT`,
`--conveyor-emulator`), its encoder readings go to a conveyor log beside the capture
(`run.conveyor.jsonl`, `tofcut.driver.conveyor.belt_log`), so that `tofcut track run.tofcap` replays
the belt prior the live run had.

`--bare` records as a real camera would: the capture's metadata holds only the camera's own
keys (`tofcut.driver.capture.CAMERA_KEYS`), so what is tracked or evaluated from it cannot
lean on the emulator's knowledge of the scene; the ground truth still goes beside it.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from typing import Any

from tofcut.driver.camera import Camera
from tofcut.driver.capture import CaptureWriter, bare_metadata, capture_metadata
from tofcut.driver.conveyor.belt_log import BeltLogWriter, belt_log_path
from tofcut.driver.events import DeviceEvent
from tofcut.driver.protocol import WRITABLE_REGISTERS
from tofcut.driver.stream import StreamStats
from tofcut.sim.truth import FrameTruth, save_truth, truth_path
from tofcut.tools.commands.arguments import output_file, positive_float, positive_int
from tofcut.tools.commands.options import (
    add_camera_options,
    add_loop_option,
    add_source_argument,
    config_from_args,
)
from tofcut.tools.commands.progress import Progress
from tofcut.tools.pipeline.belt_source import BeltResolution, resolve_run_belt, warn
from tofcut.tools.pipeline.conveyor_line import ConveyorLine, add_conveyor_options, open_conveyor
from tofcut.tools.pipeline.losses import describe_losses, stats_summary
from tofcut.tools.pipeline.sources import Opened, SourceError, configure, open_source


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="record a camera's raw frames to a .tofcap capture")
    add_source_argument(p, captures=False)
    p.add_argument("-o", "--output", type=output_file, required=True, metavar="FILE.tofcap")
    limit = p.add_mutually_exclusive_group()
    limit.add_argument("--frames", type=positive_int, help="stop after this many frames")
    limit.add_argument("--seconds", type=positive_float, help="stop after this long (default 5 s)")
    p.add_argument(
        "--reconnect", action="store_true",
        help="record through unplugs, stalls and hangs (default: stop at the first, with an "
        "error); the closing lines say what was lost",
    )  # fmt: skip
    p.add_argument(
        "--bare", action="store_true",
        help="keep only what the camera itself tells (serial, firmware, registers, ...), as a "
        "real camera's capture has it: no scene, belt or target; the emulator's ground truth "
        "is still written beside the capture",
    )  # fmt: skip
    add_camera_options(p)
    add_loop_option(p)
    add_conveyor_options(p, rejects=False)
    p.set_defaults(func=run)


def _print_event(event: DeviceEvent) -> None:
    """A device event on the console (the reader's own thread: recording waits anyway)."""
    print(f"device: {event}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    if args.source.kind == "capture":
        raise SourceError("record reads from a camera: usb, usb:SERIAL or emulator[:SCENE]")
    frames_wanted = args.frames
    seconds = args.seconds if args.seconds is not None or frames_wanted else 5.0
    opened = open_source(
        args.source, realtime=not args.fast, seed=args.seed,
        amplitude_threshold=args.amplitude_threshold, reconnect=args.reconnect,
        on_event=_print_event if args.reconnect else None,
        virtual_host_clock=not (args.conveyor or args.conveyor_emulator), loop=args.loop,
    )  # fmt: skip
    cam = opened.device
    assert isinstance(cam, Camera)
    with contextlib.closing(opened):  # the camera, and the emulator's process if any
        configure(opened, config_from_args(args, cam.config))
        resolution = resolve_run_belt(args, opened)
        for text in resolution.warnings:
            warn(text)
        registers = {r.name: cam.read_register(r) for r in sorted(WRITABLE_REGISTERS)}
        meta = capture_metadata(
            cam.info, registers, source=str(args.source), **belt_metadata(opened, resolution)
        )
        if args.bare:
            meta = bare_metadata(meta)
        log, line = _open_line(args, opened, resolution)
        try:
            cam_stats, elapsed, truths = _record(args, opened, cam, meta, frames_wanted, seconds)
        finally:
            if line is not None:
                line.close()
            if log is not None:
                log.close()
    print(f"wrote {args.output}: {stats_summary(cam_stats)} in {elapsed:.1f} s")
    if args.reconnect:
        for text in describe_losses(cam_stats):
            print(text)
    if truths:
        path = truth_path(args.output)
        save_truth(path, truths)
        print(f"wrote {path}: ground truth of {len(truths)} frames")
    if args.bare:
        kept = "not kept: --bare records the camera's stream alone"
    else:
        kept = "kept in the capture's metadata" if resolution.belt else "nothing kept"
    print(f"{resolution.describe()} ({kept})")
    if log is not None:
        print(
            f"wrote {log.path}: {log.readings} encoder readings"
            + ("" if log.error is None else f"; the log stopped: {log.error}")
        )
    if line is not None:
        print(line.summary())
    return 0


def belt_metadata(opened: Opened, resolution: BeltResolution) -> dict[str, Any]:
    """The source's metadata for the capture, with the belt the run knows at its start (and
    where it came from) in place of the scene's own."""
    kept_here = ("belt", "belt_source", "source")  # (a replayed capture's own are replaced)
    meta = {k: v for k, v in opened.metadata.items() if k not in kept_here}
    if resolution.belt is not None:
        meta["belt"] = resolution.belt.to_dict()
        meta["belt_source"] = resolution.belt.source
    return meta


def _open_line(
    args: argparse.Namespace, opened: Opened, resolution: BeltResolution
) -> tuple[BeltLogWriter | None, ConveyorLine | None]:
    """With a conveyor linked, the link and the conveyor log beside the capture, which gets
    every reading from the first on."""
    if not args.conveyor and not args.conveyor_emulator:
        return None, None
    log = BeltLogWriter(belt_log_path(args.output))
    try:
        line = open_conveyor(args, opened, resolution=resolution, on_reading=log.reading)
    except BaseException:
        log.close()
        log.path.unlink(missing_ok=True)
        raise
    assert line is not None
    log.begin(
        port=line.client.link.port,
        exposure_offset_ns=line.exposures.offset_ns,
        max_extrapolation_s=line.client.max_extrapolation_s,
    )
    return log, line


def _record(
    args: argparse.Namespace,
    opened: Opened,
    cam: Camera,
    meta: dict[str, Any],
    frames_wanted: int | None,
    seconds: float | None,
) -> tuple[StreamStats, float, list[FrameTruth]]:
    """Write frames until the limit: the camera's statistics, the time taken, the truth."""
    progress = Progress(frames_wanted, f"recording {args.output}")
    start = time.monotonic()
    truths: list[FrameTruth] = []
    with CaptureWriter(args.output, meta, cam.calibration_block) as writer:
        try:
            for raw in cam.raw_frames():
                writer.write(raw)
                truth = opened.emulator.truth(raw.sequence) if opened.emulator else None
                if isinstance(truth, FrameTruth):
                    truths.append(truth)
                progress.update(writer.frames, f"lost {cam.stats.lost}")
                if frames_wanted is not None and writer.frames >= frames_wanted:
                    break
                if seconds is not None and time.monotonic() - start >= seconds:
                    break
        except KeyboardInterrupt:
            print("stopped by Ctrl-C; the capture is complete up to the last frame")
        finally:
            progress.close()
    return cam.stats, time.monotonic() - start, truths
