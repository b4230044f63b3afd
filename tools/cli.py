"""The `tofcut` command line: one subcommand per module in `tofcut.tools`."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from tofcut import __version__
from tofcut.driver.errors import TofcutError

# Recordings are written without rerun's footer (`tools.rerun_target` says why), and rerun
# warns of that for every file it opens: quiet that one warning before rerun is imported
# (the user's own RUST_LOG wins).
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error")

COMMANDS = [
    "tofcut.tools.cmd_devices",
    "tofcut.tools.cmd_info",
    "tofcut.tools.cmd_record",
    "tofcut.tools.cmd_convert",
    "tofcut.tools.cmd_live",
    "tofcut.tools.cmd_track",
    "tofcut.tools.cmd_calibrate",
    "tofcut.tools.cmd_evaluate",
    "tofcut.tools.cmd_scenes",
    "tofcut.tools.cmd_reproduce",
    "tofcut.tools.cmd_ports",
    "tofcut.tools.cmd_soak",
    "tofcut.tools.cmd_bench",
]
"""Each module has `register(subparsers)`, which adds its parser with `func` set."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tofcut",
        description="Time-of-flight camera driver, emulator and graph-cut tracker.",
    )
    parser.add_argument("--version", action="version", version=f"tofcut {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except TofcutError as exc:
        print(f"tofcut: error: {exc}", file=sys.stderr)
        return int(getattr(exc, "exit_code", 1))  # 2: something needed was not given
    except KeyboardInterrupt:
        print("tofcut: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
