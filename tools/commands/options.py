"""Command-line options shared by the commands that open a camera."""

from __future__ import annotations

import argparse

from tofcut.driver.config import CameraConfig, TriggerMode
from tofcut.tools.commands.arguments import source


def add_source_argument(parser: argparse.ArgumentParser, *, captures: bool = True) -> None:
    """The SOURCE argument; without `captures`, only cameras (`record`)."""
    help_text = "usb, usb:SERIAL, emulator[:SCENE]" + (" or FILE.tofcap" if captures else "")
    parser.add_argument("source", type=source(captures=captures), metavar="SOURCE", help=help_text)


def add_camera_options(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("camera settings (unset: as the camera or scene has them)")
    g.add_argument("--mod-freq", type=float, metavar="MHZ", help="modulation frequency in MHz")
    g.add_argument("--integration", type=float, metavar="MS", help="integration time per tap, ms")
    g.add_argument("--fps", type=float, help="frame rate (0: as fast as the integration allows)")
    g.add_argument(
        "--trigger",
        choices=[m.name.lower().replace("_", "-") for m in TriggerMode],
        help="trigger mode",
    )
    g.add_argument(
        "--amplitude-threshold",
        type=float,
        default=0.0,
        metavar="COUNTS",
        help="pixels with a lower amplitude are invalid (default 0)",
    )
    g.add_argument("--seed", type=int, default=0, help="emulator: noise seed (default 0)")
    g.add_argument(
        "--fast",
        action="store_true",
        help="emulator: deliver frames as fast as they are read, not in real time",
    )


def add_loop_option(parser: argparse.ArgumentParser) -> None:
    """`--loop`, for the commands that stream a replayed capture (`live`, `track`, `record`)."""
    parser.add_argument(
        "--loop",
        action="store_true",
        help="emulator:FILE.tofcap: replay the capture over and over (default: the stream "
        "ends with it)",
    )


def config_from_args(args: argparse.Namespace, current: CameraConfig) -> CameraConfig | None:
    """The configuration the options ask for, or None when none was given."""
    if args.mod_freq is None and args.integration is None and args.fps is None and not args.trigger:
        return None
    asked = CameraConfig.make(
        mod_freq_mhz=args.mod_freq,
        integration_ms=args.integration,
        frame_rate=args.fps,
        trigger_mode=args.trigger or TriggerMode.FREE_RUN,
    )
    return CameraConfig(
        asked.mod_freq_code if args.mod_freq is not None else current.mod_freq_code,
        asked.integration if args.integration is not None else current.integration,
        asked.frame_period if args.fps is not None else current.frame_period,
        asked.trigger_mode if args.trigger else current.trigger_mode,
    )
