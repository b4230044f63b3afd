"""`tofcut live [CAMERA ...]`: live tracking, by default of the emulated conveyor; several
cameras (or a camera list) run one worker process each (`tools.commands.cameras`)."""

from __future__ import annotations

import argparse

from tofcut.tools.commands.arguments import source
from tofcut.tools.commands.camera_list import CameraEntry, load_camera_list
from tofcut.tools.commands.cameras import add_camera_list_options, run_cameras
from tofcut.tools.commands.options import add_camera_options, add_loop_option
from tofcut.tools.commands.tracking import add_tracking_options, track
from tofcut.tools.pipeline.conveyor_line import add_conveyor_options
from tofcut.tools.pipeline.sources import SourceSpec

DEFAULT_SECONDS = 10.0
DEFAULT_CAMERA = "emulator"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "live",
        help="track live from a camera (default: the emulated conveyor)",
        description="Track live from usb, usb:SERIAL or emulator[:SCENE] (emulator:FILE.tofcap: "
        "the emulated camera replays a capture). Without --frames or --seconds it runs "
        f"{DEFAULT_SECONDS:g} s (a replay: at most to the capture's end); --seconds 0 runs "
        "until Ctrl-C. Several cameras (or --cameras FILE) run in a worker process each, "
        "with their outputs named after each camera's serial number.",
    )
    p.add_argument(
        "cameras", type=source(captures=False), nargs="*", metavar="CAMERA",
        help=f"usb, usb:SERIAL, emulator[:SCENE] (default: {DEFAULT_CAMERA})",
    )  # fmt: skip
    add_tracking_options(
        p, seconds_help=f"stop after this long (default {DEFAULT_SECONDS:g}; 0: until Ctrl-C)"
    )
    add_camera_options(p)
    add_loop_option(p)
    add_conveyor_options(p)
    add_camera_list_options(p)
    p.set_defaults(func=run, default_seconds=DEFAULT_SECONDS)


def run(args: argparse.Namespace) -> int:
    if args.seconds == 0:
        args.seconds = None
        args.default_seconds = None
    entries = [CameraEntry(spec) for spec in args.cameras]
    if args.cameras_file is not None:
        entries += load_camera_list(args.cameras_file)
    if len(entries) > 1 or args.cameras_file is not None or args.summary_json is not None:
        return run_cameras(args, entries)
    args.source = entries[0].source if entries else SourceSpec.parse(DEFAULT_CAMERA)
    return track(args, live=True)
