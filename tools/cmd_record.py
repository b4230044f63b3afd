"""`tofcut record CAMERA -o FILE.tofcap`: write the raw stream to a capture file.

`--bare` records as a real camera would: the capture's metadata holds only the camera's own
keys (`tofcut.driver.capture.CAMERA_KEYS`), so what is tracked or evaluated from it cannot
lean on the emulator's knowledge of the scene; the ground truth still goes beside it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tofcut.driver.camera import Camera
from tofcut.driver.capture import CaptureWriter, bare_metadata, capture_metadata
from tofcut.driver.events import DeviceEvent
from tofcut.driver.protocol import WRITABLE_REGISTERS
from tofcut.driver.stream import StreamStats
from tofcut.sim.truth import FrameTruth, save_truth, truth_path
from tofcut.tools.losses import describe_losses
from tofcut.tools.options import add_camera_options, add_source_argument, config_from_args
from tofcut.tools.progress import Progress
from tofcut.tools.sources import SourceError, open_source


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="record a camera's raw frames to a .tofcap capture")
    add_source_argument(p)
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE.tofcap")
    limit = p.add_mutually_exclusive_group()
    limit.add_argument("--frames", type=int, help="stop after this many frames")
    limit.add_argument("--seconds", type=float, help="stop after this long (default 5 s)")
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
    p.set_defaults(func=run)


def stats_summary(stats: StreamStats) -> str:
    text = f"{stats.frames} frames, {stats.lost} lost, {stats.damaged} damaged"
    if stats.gaps:
        ranges = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in list(stats.gaps)[-5:])
        text += f" (lost sequence numbers: {ranges})"
    return text


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
    )  # fmt: skip
    cam = opened.device
    assert isinstance(cam, Camera)
    with cam:
        asked = config_from_args(args, cam.config)
        if asked is not None:
            cam.configure(asked)
        registers = {r.name: cam.read_register(r) for r in sorted(WRITABLE_REGISTERS)}
        meta = capture_metadata(cam.info, registers, source=str(args.source), **opened.metadata)
        if args.bare:
            meta = bare_metadata(meta)
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
        elapsed = time.monotonic() - start
    print(f"wrote {args.output}: {stats_summary(cam.stats)} in {elapsed:.1f} s")
    if args.reconnect:
        for text in describe_losses(cam.stats):
            print(text)
    if truths:
        path = truth_path(args.output)
        save_truth(path, truths)
        print(f"wrote {path}: ground truth of {len(truths)} frames")
    return 0
