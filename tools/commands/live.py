"""`tofcut live [CAMERA]`: live tracking, by default of the emulated conveyor."""

from __future__ import annotations

import argparse

from tofcut.tools.commands.options import (
    add_camera_options,
    add_loop_option,
    add_source_argument,
)
from tofcut.tools.commands.tracking import add_tracking_options, track
from tofcut.tools.pipeline.conveyor_line import add_conveyor_options
from tofcut.tools.pipeline.sources import SourceError

DEFAULT_SECONDS = 10.0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "live",
        help="track live from a camera (default: the emulated conveyor)",
        description="Track live from usb, usb:SERIAL or emulator[:SCENE] (emulator:FILE.tofcap: "
        "the emulated camera replays a capture). Without --frames or --seconds it runs "
        f"{DEFAULT_SECONDS:g} s (a replay: at most to the capture's end); --seconds 0 runs "
        "until Ctrl-C.",
    )
    add_source_argument(p, default="emulator", captures=False)
    add_tracking_options(
        p, seconds_help=f"stop after this long (default {DEFAULT_SECONDS:g}; 0: until Ctrl-C)"
    )
    add_camera_options(p)
    add_loop_option(p)
    add_conveyor_options(p)
    p.set_defaults(func=run, default_seconds=DEFAULT_SECONDS)


def run(args: argparse.Namespace) -> int:
    if args.source.kind == "capture":
        raise SourceError(
            "live reads from a camera; use 'tofcut track FILE.tofcap' for captures, or "
            "'tofcut live emulator:FILE.tofcap' to replay one through the emulated camera"
        )
    if args.seconds == 0:
        args.seconds = None
        args.default_seconds = None
    return track(args, live=True)
