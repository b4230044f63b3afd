"""Where a run's belt comes from: everything the run was told of it, resolved in one place.

Precedence, for the belt's geometry (the first source that gives one wins):

1. given: through the Python API (`KnownBelt(..., source="given")`);
2. map: `--conveyor-map`'s `[belt]` table;
3. capture or scene: the capture's metadata, or the emulated scene's (a run has one of them);
4. found: the belt finder's, used only where nothing above gave a belt.

What the user gave wins over what a recording or a scene says; a found belt never overrides
a given one. The speed comes with the winning geometry; where it has none (a map never has
one), it is taken from the next source that has one and runs the same way. Two sources that
disagree by more than `ANGLE_TOLERANCE_DEG` or `OFFSET_TOLERANCE_M` are reported, one
warning line for each, never silently resolved. The velocity prior is chosen later
(`tools.pipeline.run_belt`): the conveyor's encoder when linked, else the known speed, else none.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tofcut.driver.belt import KnownBelt
from tofcut.driver.capture import CaptureReader
from tofcut.driver.conveyor.belt_log import SOURCES
from tofcut.driver.conveyor.config import load_conveyor_config
from tofcut.driver.errors import ConfigError
from tofcut.tools.pipeline.sources import Opened, SourceError, belt_of

ANGLE_TOLERANCE_DEG = 3.0
"""Directions or normals further apart than this are two different belts."""
OFFSET_TOLERANCE_M = 0.03
"""Planes, centre lines or widths further apart than this are two different belts."""
SPEED_TOLERANCE_MPS = 0.01

RANK = {"given": 0, "map": 1, "capture": 2, "scene": 2, "found": 3}
"""Precedence by `KnownBelt.source`: lower wins (an unknown source counts as given)."""
LABEL = {
    "given": "given through the Python API",
    "map": "from the map",
    "scene": "from the scene's metadata",
    "capture": "from the capture's metadata",
    "found": "found during the run",
}
WHOSE = {
    "given": "the given belt",
    "map": "the map's belt",
    "scene": "the scene's belt",
    "capture": "the capture's belt",
    "found": "the found belt",
}
RECORDED = {
    "given": "recorded as given",
    "map": "recorded from the map",
    "scene": "recorded from the scene",
    "capture": "recorded from a capture",
    "found": "found by the recording run",
}


class NoBelt(ConfigError):
    """Something needs the belt's geometry and no source gave it (exit status 2)."""

    exit_code = 2


@dataclass(frozen=True, eq=False)
class BeltCandidate:
    """One source's belt, with a word for the closing line (a map's path, a scene's name)."""

    belt: KnownBelt
    detail: str = ""


@dataclass(frozen=True, eq=False)
class BeltResolution:
    """What a run knows of its belt at the start, and from where."""

    belt: KnownBelt | None
    """The winner's geometry, with the speed as resolved; `belt.source` is the geometry's."""
    detail: str = ""
    speed_from: str | None = None
    """The source of the speed where it is not the geometry's own."""
    warnings: tuple[str, ...] = ()
    """One line per source that disagrees with the winner."""

    def describe(self) -> str:
        """The closing line's start: `belt: from the map (line.toml); speed 0.250 m/s ...`."""
        return describe_belt(self.belt, self.detail, self.speed_from)


def describe_belt(belt: KnownBelt | None, detail: str = "", speed_from: str | None = None) -> str:
    if belt is None:
        return "belt: none given"
    text = f"belt: {LABEL.get(belt.source, belt.source)}"
    if detail:
        text += f" ({detail})"
    if belt.speed_mps is not None:
        text += f"; speed {belt.speed_mps:.3f} m/s"
        if speed_from is not None:
            text += f" ({LABEL.get(speed_from, speed_from)})"
    return text


def warn(text: str) -> None:
    """A warning line on stderr (a disagreement between sources)."""
    print(f"tofcut: warning: {text}", file=sys.stderr, flush=True)


def rank(belt: KnownBelt) -> int:
    return RANK.get(belt.source, 0)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = float(a @ b) / float(np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def disagreement(a: KnownBelt, b: KnownBelt) -> str | None:
    """How two belts differ beyond the tolerances ("directions 12.0° apart, ..."), or None."""
    ga, gb = a.geometry, b.geometry
    parts = []
    directions = _angle_deg(ga.direction, gb.direction)
    if directions > ANGLE_TOLERANCE_DEG:
        parts.append(f"directions {directions:.1f}° apart")
    normals = _angle_deg(ga.normal, gb.normal)
    if normals > ANGLE_TOLERANCE_DEG:
        parts.append(f"normals {normals:.1f}° apart")
    planes = max(abs(float(ga.height(gb.origin))), abs(float(gb.height(ga.origin))))
    if planes > OFFSET_TOLERANCE_M:
        parts.append(f"planes {planes * 100:.1f} cm apart")
    if ga.width_m is not None and gb.width_m is not None:
        if abs(ga.width_m - gb.width_m) > OFFSET_TOLERANCE_M:
            parts.append(f"widths {ga.width_m:.3f} and {gb.width_m:.3f} m")
        centres = abs(float(ga.across(gb.point) - ga.across(ga.point)))
        if centres > OFFSET_TOLERANCE_M:
            parts.append(f"centre lines {centres * 100:.1f} cm apart")
    if (
        a.speed_mps is not None
        and b.speed_mps is not None
        and directions <= ANGLE_TOLERANCE_DEG
        and abs(a.speed_mps - b.speed_mps) > SPEED_TOLERANCE_MPS
    ):
        parts.append(f"speeds {a.speed_mps:.3f} and {b.speed_mps:.3f} m/s")
    return ", ".join(parts) or None


def conflict_warning(winner: KnownBelt, other: KnownBelt) -> str | None:
    """The one warning line for two sources that disagree, or None."""
    why = disagreement(winner, other)
    if why is None:
        return None
    mine = WHOSE.get(winner.source, winner.source)
    theirs = WHOSE.get(other.source, other.source)
    return f"{mine} and {theirs} disagree ({why}); using {mine}"


def resolve_belt(candidates: Iterable[BeltCandidate | None]) -> BeltResolution:
    """The run's belt from every source that gave one (None: that source gave none), by the
    precedence in this module's docstring; disagreements as warning lines."""
    given = sorted((c for c in candidates if c is not None), key=lambda c: rank(c.belt))
    if not given:
        return BeltResolution(None)
    winner, others = given[0], given[1:]
    belt, speed_from = winner.belt, None
    warnings = []
    for other in others:
        warning = conflict_warning(winner.belt, other.belt)
        if warning is not None:
            warnings.append(warning)
        same_way = (
            _angle_deg(winner.belt.geometry.direction, other.belt.geometry.direction)
            <= ANGLE_TOLERANCE_DEG
        )
        if belt.speed_mps is None and other.belt.speed_mps is not None and same_way:
            belt = KnownBelt(belt.geometry, other.belt.speed_mps, belt.source)
            speed_from = other.belt.source
    return BeltResolution(belt, winner.detail, speed_from, tuple(warnings))


# --- the command line's sources -------------------------------------------------------------


def map_candidate(path: Path | None) -> BeltCandidate | None:
    """`--conveyor-map`'s `[belt]`, or None (no map, or a map without one)."""
    if path is None:
        return None
    config = load_conveyor_config(path)
    if config.belt is None:
        return None
    return BeltCandidate(KnownBelt(config.belt, None, "map"), str(path))


def metadata_candidate(meta: dict[str, Any], source: str) -> BeltCandidate | None:
    """The belt in a capture's (`source="capture"`) or an emulated scene's metadata, checked:
    a value that is off is a `SourceError`, one line."""
    belt = belt_of(meta, source)
    if belt is None:
        return None
    whose = "capture's" if source == "capture" else "scene's"
    recorded = meta.get("belt_source")
    if recorded is not None and recorded not in SOURCES:
        raise SourceError(
            f"the {whose} metadata says its belt came from {str(recorded)[:20]!r}, "
            f"not one of {', '.join(SOURCES)}"
        )
    detail = ""
    if source == "capture" and recorded is not None:
        detail = RECORDED[recorded]
    elif source == "scene" and isinstance(meta.get("scene"), str):
        detail = meta["scene"]
    return BeltCandidate(belt, detail)


def run_metadata(opened: Opened) -> tuple[dict[str, Any], str]:
    """A source's metadata and what it is: a capture's ("capture", also one the emulated
    camera replays), else the scene's."""
    device = opened.device
    if isinstance(device, CaptureReader):
        return device.capture.metadata, "capture"
    return opened.metadata, "scene" if opened.replay is None else "capture"


def resolve_run_belt(
    args: argparse.Namespace, opened: Opened, given: KnownBelt | None = None
) -> BeltResolution:
    """What a command's run knows of its belt: `given` (the Python API), the map's, the
    capture's or scene's metadata."""
    meta, source = run_metadata(opened)
    return resolve_belt(
        [
            None if given is None else BeltCandidate(given),
            map_candidate(getattr(args, "conveyor_map", None)),
            metadata_candidate(meta, source),
        ]
    )
