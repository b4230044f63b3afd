"""Reading MOTChallenge rows: the ground truth and tracks `tofcut evaluate` takes.

`frame,id,bb_left,bb_top,bb_width,bb_height,conf,x,y,z`, one row per object per frame
(commas, or spaces or tabs, between the fields), frames from 1: the layout `--mot-out`
writes and MOT15's 3D benchmark uses, where x, y, z are a 3D position (here the centroid,
camera coordinates, metres) and -1 where unknown. In ground truth, a row whose `conf` is 0
is not to be scored (MOTChallenge's convention): tofcut ignores tracks near it.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from tofcut.tools.pipeline.sources import SourceError

T = TypeVar("T")

UNKNOWN = -1.0
"""MOTChallenge's value of a coordinate it does not give."""
_SPLIT = re.compile(r"[,\s]+")


@dataclass(frozen=True)
class MotRow:
    """One MOTChallenge row."""

    frame: int
    """As the file has it: from 1."""
    id: int
    box: tuple[float, float, float, float]
    """bb_left, bb_top, bb_width, bb_height (1-based pixels)."""
    conf: float
    xyz: tuple[float, float, float] | None
    """The 3D position; None where the row gives none (fewer fields, or -1, -1, -1)."""


def parse_row(text: str) -> MotRow | None:
    """One row (None for a blank one); ValueError says what is wrong with it."""
    fields = [f for f in _SPLIT.split(text.strip()) if f]
    if not fields:
        return None
    if len(fields) < 7:
        raise ValueError(
            f"{len(fields)} fields, not 7 to 10 (frame,id,bb_left,bb_top,bb_width,bb_height,"
            "conf,x,y,z)"
        )
    try:
        values = [float(f) for f in fields[:10]]
    except ValueError:
        raise ValueError("a field is not a number") from None
    frame, ident = values[0], values[1]
    if frame != int(frame) or ident != int(ident) or frame < 1:
        raise ValueError("frame and id must be whole numbers, frame from 1")
    xyz: tuple[float, float, float] | None = None
    if len(values) >= 10 and values[7:10] != [UNKNOWN] * 3:
        xyz = (values[7], values[8], values[9])
    box = (values[2], values[3], values[4], values[5])
    return MotRow(int(frame), int(ident), box, values[6], xyz)


def read_lines(path: Path, parse: Callable[[str], T | None], what: str) -> list[T]:
    """What `parse` makes of every line of a text file, in file order (None: a line it
    passes over); an unreadable file or a line `parse` refuses is a one-line SourceError
    naming `what` the lines should be."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"cannot read {path} as {what}s: {exc}") from None
    out = []
    for n, line in enumerate(text.splitlines(), start=1):
        try:
            item = parse(line)
        except ValueError as exc:
            raise SourceError(f"{path}, line {n}: not a {what}: {exc}") from None
        if item is not None:
            out.append(item)
    return out


def read_mot(path: Path) -> list[MotRow]:
    """Every row of a MOTChallenge file, in file order; a bad row is a one-line SourceError."""
    return read_lines(path, parse_row, "MOTChallenge row")
