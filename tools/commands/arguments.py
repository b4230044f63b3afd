"""Argument types that check what a user gives before any work starts.

Each is an `argparse` type: a bad value is a usage error (one line, exit status 2, see
`tools.cli`) said in words, never "invalid _pixel value".
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path

from tofcut.driver.errors import TofcutError
from tofcut.tools.pipeline.sources import SourceError, SourceSpec

CAPTURE_SUFFIX = ".tofcap"


class UsageError(TofcutError):
    """A value the command line gave that is wrong, found once the source is open (exit
    status 2, as argparse's own usage errors)."""

    exit_code = 2


def _number(text: str, kind: Callable[[str], float]) -> float:
    try:
        value = kind(text)
    except ValueError:
        what = "a whole number" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def positive_int(text: str) -> int:
    """A count of at least 1 (`--frames`)."""
    value = int(_number(text, int))
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {text}")
    return value


def non_negative_int(text: str) -> int:
    """A count of 0 or more (`--restarts`)."""
    value = int(_number(text, int))
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, not {text}")
    return value


def positive_float(text: str) -> float:
    """A duration above 0 (`--seconds`)."""
    value = _number(text, float)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be more than 0, not {text}")
    return value


def non_negative_float(text: str) -> float:
    """A duration of 0 or more (`live --seconds`, where 0 means until Ctrl-C)."""
    value = _number(text, float)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, not {text}")
    return value


def pixel(text: str) -> tuple[int, int]:
    """`U,V`: a pixel's column and row (whether it is in the image is checked once the
    camera or capture is open)."""
    parts = text.split(",")
    try:
        u, v = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not U,V (a pixel's column and row, two whole numbers: e.g. 88,72)"
        ) from None
    if u < 0 or v < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a pixel: U and V start at 0")
    return (u, v)


def point(text: str) -> tuple[float, float, float]:
    """`X,Y,Z`: a point in camera coordinates, metres."""
    try:
        x, y, z = (float(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not X,Y,Z (three numbers, metres: e.g. 0,0,1.2)"
        ) from None
    if not all(math.isfinite(c) for c in (x, y, z)):
        raise argparse.ArgumentTypeError(f"{text!r} is not a point: not finite")
    return (x, y, z)


def existing_file(text: str, what: str = "file") -> Path:
    """A file to read: it must be there and be a file."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder, not a {what}")
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{what} {text} does not exist")
    if not os.access(path, os.R_OK):
        raise argparse.ArgumentTypeError(f"{what} {text} cannot be read (permission denied)")
    return path


def existing_folder(text: str) -> Path:
    """A folder to read from (`evaluate --runs`)."""
    path = Path(text)
    if not path.is_dir():
        there = "is a file, not a folder" if path.exists() else "does not exist"
        raise argparse.ArgumentTypeError(f"{text} {there}")
    return path


def capture_file(text: str) -> Path:
    """A capture to read (`convert`, `evaluate`)."""
    return existing_file(text, "capture")


def output_file(text: str) -> Path:
    """A file to write: its folder must exist and take files, and it must not be a folder.
    Checked before the run, so that a run's outputs are not lost at its end."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder; give a file name in it")
    folder = path.parent
    if not folder.is_dir():
        if folder.exists():
            raise argparse.ArgumentTypeError(f"cannot write {text}: {folder} is not a folder")
        raise argparse.ArgumentTypeError(f"cannot write {text}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise argparse.ArgumentTypeError(f"cannot write {text}: permission denied")
    return path


def output_file_or_folder(text: str) -> Path:
    """A file to write, or a folder to write files into (`convert -o`): the folder it is in
    must exist and take files; the path may be a folder already there, or be made as one."""
    path = Path(text)
    if path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise argparse.ArgumentTypeError(f"cannot write into {text}: permission denied")
        return path
    return output_file(text)


def source(*, captures: bool) -> Callable[[str], SourceSpec]:
    """A SOURCE argument: `usb[:SERIAL]`, `emulator[:SCENE]`, and with `captures` an
    existing capture file (a folder or a missing file is said so)."""

    def parse(text: str) -> SourceSpec:
        kind = text.partition(":")[0]
        path = Path(text)
        if kind not in ("usb", "emulator") and (path.suffix == CAPTURE_SUFFIX or path.exists()):
            if not captures:
                raise argparse.ArgumentTypeError(
                    f"{text}: this command reads from a camera (usb, usb:SERIAL or "
                    "emulator[:SCENE]); 'tofcut track FILE.tofcap' tracks a capture, "
                    f"emulator:{text} replays it through the emulated camera"
                )
            existing_file(text, "capture")
        try:
            return SourceSpec.parse(text)
        except SourceError as exc:
            if not captures:
                raise argparse.ArgumentTypeError(
                    f"{text!r} is not a source: use usb, usb:SERIAL or emulator[:SCENE]"
                ) from None
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = "source"
    return parse
