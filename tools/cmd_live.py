"""`tofcut live`: stream from a camera (the emulated one by default) and report what came."""

from __future__ import annotations

import argparse
import time

import numpy as np

from tofcut.driver.camera import Camera
from tofcut.tools.cmd_record import stats_summary
from tofcut.tools.options import add_camera_options, add_source_argument, config_from_args
from tofcut.tools.sources import SourceError, open_source


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("live", help="stream live from a camera (default: the emulator)")
    add_source_argument(p, default="emulator")
    p.add_argument("--seconds", type=float, default=3.0, help="how long to run (default 3 s)")
    add_camera_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.source.kind == "capture":
        raise SourceError("live reads from a camera; use 'tofcut track FILE.tofcap' for captures")
    opened = open_source(
        args.source, realtime=not args.fast, seed=args.seed,
        amplitude_threshold=args.amplitude_threshold,
    )  # fmt: skip
    cam = opened.device
    assert isinstance(cam, Camera)
    with cam:
        asked = config_from_args(args, cam.config)
        if asked is not None:
            cam.configure(asked)
        print(f"camera {cam.serial} ({args.source}): {cam.config.describe()}")
        start = time.monotonic()
        ranges: list[float] = []
        valid: list[float] = []
        try:
            for frame in cam.frames():
                ranges.append(float(np.median(frame.range[frame.valid])))
                valid.append(float(frame.valid.mean()))
                if time.monotonic() - start >= args.seconds:
                    break
        except KeyboardInterrupt:
            pass
        elapsed = time.monotonic() - start
    n = len(ranges)
    print(f"captured {stats_summary(cam.stats)} in {elapsed:.1f} s ({n / elapsed:.1f} fps)")
    if n:
        print(f"median range {np.median(ranges):.3f} m, valid pixels {100 * np.mean(valid):.1f} %")
    return 0
