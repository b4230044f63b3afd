"""The cameras of one box as a TOML file (`tofcut live --cameras FILE`): one `[[camera]]`
table per camera, each value checked, a mistake said in one line with the camera's number::

    [[camera]]
    source = "emulator:conveyor"   # usb:SERIAL or emulator[:SCENE] (required)
    seed = 1                       # emulator: noise seed (default: --seed)
    fps = 50                       # frame rate (default: --fps, or as the camera has it)
    tracks_out = "line1.jsonl"     # this camera's outputs (default: --tracks-out etc. with
    mot_out = "line1.mot.txt"      #   the camera's serial number added to the name)
    mots_out = "line1.mots.txt"
    masks_out = "line1.npz"
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tofcut.driver.config_file import as_float, load_toml, show, unknown_keys
from tofcut.tools.commands.arguments import UsageError, output_file, source
from tofcut.tools.pipeline.sources import SourceSpec

MAX_FILE_BYTES = 1 << 20
"""A camera list larger than this is refused unread."""
MAX_CAMERAS = 64
OUTPUTS = ("tracks_out", "mot_out", "mots_out", "masks_out")
KEYS = ("source", "seed", "fps", *OUTPUTS)


class CameraListError(UsageError):
    """A camera list that cannot be used (exit status 2, as a command-line mistake)."""


@dataclass(frozen=True)
class CameraEntry:
    """One camera of the box: its source, and the settings and outputs that are its own
    (None: the command line's)."""

    source: SourceSpec
    seed: int | None = None
    fps: float | None = None
    outputs: dict[str, Path] = field(default_factory=dict)
    """`tracks_out`, ... → this camera's file."""


def load_camera_list(path: Path) -> list[CameraEntry]:
    """The `[[camera]]` tables of `path`; `CameraListError` (one line, naming the file) for
    anything wrong."""
    return load_toml(path, MAX_FILE_BYTES, _entries, CameraListError)


def _entries(doc: dict[str, Any]) -> list[CameraEntry]:
    if problem := unknown_keys(doc, ["camera"], {"camera": "[[camera]]"}):
        raise CameraListError(problem)
    tables = doc.get("camera")
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict) for t in tables):
        raise CameraListError("no [[camera]] tables (one for each camera)")
    if len(tables) > MAX_CAMERAS:
        raise CameraListError(f"{len(tables)} cameras; at most {MAX_CAMERAS}")
    return [_entry(t, f"camera {i}") for i, t in enumerate(tables, 1)]


def _entry(table: dict[str, Any], where: str) -> CameraEntry:
    if problem := unknown_keys(table, KEYS):
        raise CameraListError(f"{where}: {problem}")
    if "source" not in table:
        raise CameraListError(f"{where}: no source (usb:SERIAL or emulator[:SCENE])")
    spec = _checked(table, "source", where, source(captures=False))
    seed = table.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise CameraListError(f"{where}: seed must be a whole number, not {show(seed)}")
    fps = None
    if "fps" in table:
        fps = as_float(table["fps"])
        if fps is None or not math.isfinite(fps) or fps < 0:
            raise CameraListError(
                f"{where}: fps must be a number, 0 or more, not {show(table['fps'])}"
            )
    outputs = {key: _checked(table, key, where, output_file) for key in OUTPUTS if key in table}
    return CameraEntry(spec, seed, fps, outputs)


def _checked(table: dict[str, Any], key: str, where: str, parse: Callable[[str], Any]) -> Any:
    """The string `table[key]` through an argument type, its complaint as this file's."""
    value = table[key]
    if not isinstance(value, str):
        raise CameraListError(f"{where}: {key} must be a string, not {show(value)}")
    try:
        return parse(value)
    except argparse.ArgumentTypeError as exc:
        raise CameraListError(f"{where}: {key}: {exc}") from None
