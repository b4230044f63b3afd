"""How well the belt is found from the frames alone: a found belt's errors against the truth,
judged by issue 15's bars, and the check over a family's bare captures.

    python -m tofcut.tools.evaluation.belt_check WORK/family-conveyor [--seconds S]

runs the finder on each line's bare capture as `tofcut calibrate` does (`find_belt`, at most
`--seconds` of frames) and compares what it found with the belt the line was drawn with.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path

from tofcut.driver.belt import KnownBelt
from tofcut.driver.capture import CaptureReader
from tofcut.driver.errors import TofcutError
from tofcut.sim.renderer import SceneSource
from tofcut.tools.pipeline.sources import scene_source
from tofcut.tracker.belt_finder import find_belt

BARS = {"normal_deg": 1.0, "plane_m": 0.01, "direction_deg": 2.0, "speed": 0.03, "width_m": 0.03}
"""The bars: plane normal (°), plane offset at the view's centre (m), direction of travel (°),
speed (share), width (m; issue 15 sets none: 3 cm here)."""


@dataclass(frozen=True)
class Errors:
    """How far a found belt is from the truth (nan: not found, or no truth to compare)."""

    normal_deg: float
    plane_m: float
    """Distance along the normal between the planes at the view's centre."""
    direction_deg: float = math.nan
    speed: float = math.nan
    """|found / true - 1|."""
    width_m: float = math.nan

    def within(self) -> dict[str, bool | None]:
        """Per bar: within it, beyond it, or None where there is nothing to judge."""
        out: dict[str, bool | None] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = None if math.isnan(value) else bool(value <= BARS[f.name])
        return out


def errors(found: KnownBelt, truth: KnownBelt) -> Errors:
    """The found belt's errors against the true one."""
    g, t = found.geometry, truth.geometry
    normal = math.degrees(math.acos(min(1.0, abs(float(g.normal @ t.normal)))))
    plane = abs(float(g.normal @ (t.origin - g.point)))
    if found.speed_mps is None or truth.speed_mps is None:
        return Errors(normal, plane)
    true_dir = t.direction * math.copysign(1.0, truth.speed_mps)
    direction = math.degrees(math.acos(min(1.0, float(g.direction @ true_dir))))
    speed = abs(found.speed_mps / abs(truth.speed_mps) - 1)
    width = math.nan if g.width_m is None or t.width_m is None else abs(g.width_m - t.width_m)
    return Errors(normal, plane, direction, speed, width)


@dataclass(frozen=True)
class LineCheck:
    """The finder on one line's capture: what it said of the travel, and its errors."""

    seed: int
    travel: str
    """The finder's `travel`: found, none, unsure, looking; or `no plane`."""
    errors: Errors | None


def check_line(family: str, seed: int, capture: Path, seconds: float) -> LineCheck:
    """Find the belt in a bare capture of the line `family:FAMILY:SEED` and compare it with
    the belt the line was drawn with."""
    source = scene_source(f"family:{family}:{seed}", seed)
    truth = source.belt if isinstance(source, SceneSource) else None
    if truth is None:
        raise TofcutError(f"family:{family}:{seed} has no belt to compare with")
    estimate = find_belt(CaptureReader(capture).frames(), seconds)
    if estimate.belt is None:
        return LineCheck(seed, "no plane", None)
    return LineCheck(seed, estimate.travel, errors(estimate.belt, truth))


COLUMNS = (("normal °", "normal_deg", 1.0, 2), ("plane mm", "plane_m", 1000.0, 1),
           ("direction °", "direction_deg", 1.0, 2), ("speed %", "speed", 100.0, 2),
           ("width mm", "width_m", 1000.0, 1))  # fmt: skip
"""The table's error columns: heading, `Errors` field, scale, decimals."""


def report(checks: Sequence[LineCheck]) -> str:
    """The per-line table and, per bar, how many lines are within it, as Markdown."""
    rows = ["| seed | travel | " + " | ".join(c[0] for c in COLUMNS) + " |",
            "| --- | --- |" + " --- |" * len(COLUMNS)]  # fmt: skip
    for c in checks:
        cells = [str(c.seed), c.travel]
        for _, name, scale, digits in COLUMNS:
            value = math.nan if c.errors is None else getattr(c.errors, name)
            cells.append("—" if math.isnan(value) else f"{value * scale:.{digits}f}")
        rows.append("| " + " | ".join(cells) + " |")
    summary = []
    for heading, name, scale, _ in COLUMNS:
        judged = [w for c in checks if c.errors and (w := c.errors.within()[name]) is not None]
        summary.append(
            f"- {heading.split()[0]} within {BARS[name] * scale:g} {heading.split()[1]}: "
            f"{sum(judged)} of {len(judged)} lines"
            + (
                f" ({len(checks) - len(judged)} with none to judge)"
                if len(judged) < len(checks)
                else ""
            )
        )
    travel = Counter(c.travel for c in checks)
    head = f"{len(checks)} lines; travel: " + ", ".join(f"{k} {v}" for k, v in travel.items())
    return "\n".join([head, "", *rows, "", *summary]) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tofcut.tools.evaluation.belt_check",
                                     description=__doc__.split("\n\n")[0])  # fmt: skip
    parser.add_argument("folder", type=Path, help="a family's folder: WORK/family-FAMILY")
    parser.add_argument("--seconds", type=float, default=20.0, help="look at most this long")
    args = parser.parse_args(argv)
    match = re.fullmatch(r"family-(\w+)", args.folder.name)
    if match is None or not args.folder.is_dir():
        print(f"belt_check: {args.folder} is not a family's folder (WORK/family-NAME)",
              file=sys.stderr)  # fmt: skip
        return 2
    if not (0 < args.seconds <= 600):
        print("belt_check: --seconds must be in (0, 600]", file=sys.stderr)
        return 2
    seeds = sorted(int(p.name[5:]) for p in args.folder.glob("seed-*") if p.name[5:].isdigit())
    checks = []
    for seed in seeds:
        capture = args.folder / f"seed-{seed}" / "capture.tofcap"
        if not capture.is_file():
            continue
        try:
            checks.append(check_line(match.group(1), seed, capture, args.seconds))
        except TofcutError as exc:
            print(f"belt_check: seed {seed}: {exc}", file=sys.stderr)
            return 1
    print(report(checks), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
