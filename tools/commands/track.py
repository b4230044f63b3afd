"""`tofcut track SOURCE`: track objects in a capture or from a camera (the run is
`tracking.track`, which `tofcut live` shares)."""

from __future__ import annotations

import argparse

from tofcut.tools.commands.options import (
    add_camera_options,
    add_loop_option,
    add_source_argument,
)
from tofcut.tools.commands.tracking import add_tracking_options, track
from tofcut.tools.pipeline.conveyor_line import add_conveyor_options


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("track", help="track objects in a capture or from a camera")
    add_source_argument(p)
    add_tracking_options(p)
    add_camera_options(p)
    add_loop_option(p)
    add_conveyor_options(p)
    p.set_defaults(func=lambda a: track(a, live=a.source.kind != "capture"))
