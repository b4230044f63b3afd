"""The `tofcut` command line: one subcommand per module in `tofcut.tools.commands`.

Only the command asked for is imported (its module brings the tracker, rerun, pandas, ...
when it needs them), so `tofcut --help`, `--version`, `devices` and `ports` start at once;
the others are listed from `COMMANDS` without being imported.

Ordinary mistakes end with one line, `tofcut: error: ...`, and exit status 2 (the command
line asks for something it cannot have: usage) or 1 (the run failed); `--debug` shows the
traceback instead. `-v` / `-q` set how much tofcut and its libraries log (`setup_logging`).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from tofcut import __version__
from tofcut.driver.errors import TofcutError
from tofcut.tools.commands import startup

COMMANDS: dict[str, tuple[str, str]] = {
    "devices": ("tofcut.tools.commands.devices", "list cameras (serial, firmware, resolution)"),
    "info": ("tofcut.tools.commands.info", "show a camera's info, registers and calibration"),
    "record": ("tofcut.tools.commands.record", "record a camera's raw frames to a .tofcap capture"),
    "convert": (
        "tofcut.tools.commands.convert",
        "capture → npz arrays, PLY/PCD point clouds or 16-bit depth PNGs",
    ),
    "live": (
        "tofcut.tools.commands.live",
        "track live from a camera (default: the emulated conveyor)",
    ),
    "track": ("tofcut.tools.commands.track", "track objects in a capture or from a camera"),
    "calibrate": (
        "tofcut.tools.commands.calibrate",
        "find the belt (plane, travel, speed, width) and write it to a map",
    ),
    "evaluate": (
        "tofcut.tools.commands.evaluate",
        "score tracks and masks against emulator ground truth (or a family)",
    ),
    "sweep": (
        "tofcut.tools.commands.sweep",
        "score the tracker on a family of lines under every setting of a grid",
    ),
    "scenes": (
        "tofcut.tools.commands.scenes",
        "list the emulator's scenes and draw them, or draw a family's line from a seed",
    ),
    "reproduce": (
        "tofcut.tools.commands.reproduce",
        "run the paper's segmentation experiments on the emulator and write a report",
    ),
    "ports": ("tofcut.tools.commands.ports", "list serial ports (for --conveyor PORT)"),
    "soak": (
        "tofcut.tools.commands.soak",
        "run the emulated line under random faults; account for every lost frame",
    ),
    "bench": (
        "tofcut.tools.commands.bench",
        "measure every stage on one core, against its naive form and its peers",
    ),
}
"""Command name → (module, one-line help). Each module has `register(subparsers)`, which
adds its parser (with the same help) and sets `func`."""

LIBRARY_LOGGERS = (
    "pymodbus", "serial", "rerun", "numba", "PIL", "matplotlib", "ray", "py.warnings",
)  # fmt: skip
"""Third-party loggers (and Python's warnings, routed to logging): silent by default (tofcut
says what matters in its own words), warnings with `-v`, everything with `-vv`."""

RUST_LOG_DEFAULT = "error"
"""Rerun's native log (it bypasses Python's logging): errors only by default."""


class ArgumentParser(argparse.ArgumentParser):
    """Usage errors in one line, `tofcut: error: COMMAND: ...`, exit status 2."""

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix("tofcut").strip()
        where = f"{command}: " if command else ""
        hint = f" (see 'tofcut {command} --help')" if command else " (see 'tofcut --help')"
        self.exit(2, f"tofcut: error: {where}{message}{hint}\n")


def command_in(argv: Sequence[str]) -> str | None:
    """The command named on a command line: the first word not an option (the global
    options take no value), when it is one of `COMMANDS`."""
    for word in argv:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser; with `argv`, only the command it names is registered in full (the rest
    are listed by name and help), so that parsing it imports nothing else."""
    parser = ArgumentParser(
        prog="tofcut",
        description="Time-of-flight camera driver, emulator and graph-cut tracker.",
    )
    parser.add_argument("--version", action="version", version=f"tofcut {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="count", default=0,
        help="say more: tofcut's progress notes (-v), libraries' warnings (-v) and debug "
        "logs (-vv)",
    )  # fmt: skip
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="only errors (no warnings, no library logs)"
    )
    parser.add_argument(
        "--debug", action="store_true", help="show the Python traceback of an error"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    chosen = None if argv is None else command_in(argv)
    for name, (module, help_text) in COMMANDS.items():
        if argv is None or name == chosen:
            importlib.import_module(module).register(sub)
        else:
            sub.add_parser(name, help=help_text, add_help=False)
    return parser


class _Formatter(logging.Formatter):
    """`tofcut: warning: text` for tofcut's loggers, `tofcut: pymodbus: warning: text` for a
    library's."""

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if record.exc_info and record.levelno >= logging.ERROR:
            text += "\n" + self.formatException(record.exc_info)
        root = record.name.split(".")[0]
        where = {"tofcut": "", "py": "python: "}.get(root, f"{root}: ")
        return f"tofcut: {where}{record.levelname.lower()}: {text}"


_HANDLER_NAME = "tofcut-cli"


def setup_logging(verbose: int = 0, quiet: bool = False) -> None:
    """Route tofcut's and its libraries' logs to stderr, one line each, at the levels the
    options ask for; and set rerun's native log level (`RUST_LOG`, unless the user set it)
    without colour codes (`NO_COLOR`, same)."""
    if quiet:
        ours, theirs, rust = logging.ERROR, logging.CRITICAL + 1, "off"
    elif verbose <= 0:
        ours, theirs, rust = logging.WARNING, logging.CRITICAL + 1, RUST_LOG_DEFAULT
    elif verbose == 1:
        ours, theirs, rust = logging.INFO, logging.WARNING, "warn"
    else:
        ours, theirs, rust = logging.DEBUG, logging.DEBUG, "debug"
    root = logging.getLogger()
    for old in [h for h in root.handlers if h.get_name() == _HANDLER_NAME]:
        root.removeHandler(old)
    handler = logging.StreamHandler()  # sys.stderr as it is when a record is written
    handler.set_name(_HANDLER_NAME)
    handler.setFormatter(_Formatter())
    root.addHandler(handler)
    root.setLevel(logging.DEBUG)
    logging.getLogger("tofcut").setLevel(ours)
    for name in LIBRARY_LOGGERS:
        logging.getLogger(name).setLevel(theirs)
    logging.captureWarnings(True)
    os.environ.setdefault("RUST_LOG", rust)
    os.environ.setdefault("NO_COLOR", "1")


def global_options(argv: Sequence[str]) -> tuple[int, bool]:
    """`-v` count and `-q` among the options before the command (logging is set up before
    the command's module, and rerun with it, is imported)."""
    verbose, quiet = 0, False
    for word in argv:
        if not word.startswith("-") or word == "--":
            break
        if word in ("-q", "--quiet"):
            quiet = True
        elif word == "--verbose":
            verbose += 1
        elif word.startswith("-v") and set(word[1:]) == {"v"}:
            verbose += len(word) - 1
    return verbose, quiet


def describe_error(exc: BaseException) -> tuple[str, int]:
    """An error's one line and exit status: 2 for what the command line asked wrongly."""
    if isinstance(exc, TofcutError):
        return str(exc), int(getattr(exc, "exit_code", 1))
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}", 1
    if isinstance(exc, OSError):
        return str(exc), 1
    return f"{type(exc).__name__}: {exc} (unexpected: run again with --debug for details)", 1


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    verbose, quiet = global_options(argv)
    setup_logging(verbose, quiet)
    startup.begin(command_in(argv), quiet=quiet)  # importing a command can take seconds
    try:
        parser = build_parser(argv)
    finally:
        startup.current().done()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        if args.debug:
            raise
        print("tofcut: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        text, code = describe_error(exc)
        print(f"tofcut: error: {text}", file=sys.stderr)
        return code


if __name__ == "__main__":
    sys.exit(main())
