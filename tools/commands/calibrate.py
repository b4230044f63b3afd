"""`tofcut calibrate SOURCE [--seconds S] [-o map.toml]`: find the belt from the data.

SOURCE is named as for `tofcut track`. Whatever belt a capture's or a scene's metadata
carries is not read: the point is to find it (`tofcut.tracker.belt_finder`). With `-o`, the
belt found becomes the `[belt]` table of a conveyor map (a new one, or the given one with its
other tables and keys kept).
"""

from __future__ import annotations

import argparse
import os
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tofcut.driver.belt import BeltGeometry
from tofcut.driver.camera import Camera
from tofcut.driver.conveyor.config import parse_conveyor_config
from tofcut.driver.errors import ConfigError, TofcutError
from tofcut.driver.frames import Frame
from tofcut.driver.protocol import MOD_FREQ_MHZ, unambiguous_range_m
from tofcut.driver.toml_writer import dumps
from tofcut.tools.commands.options import add_camera_options, config_from_args
from tofcut.tools.pipeline.sources import SourceError, SourceSpec, configure, open_source
from tofcut.tracker.belt_finder import BeltEstimate, find_belt
from tofcut.tracker.noise import range_noise

DEFAULT_SECONDS = 20.0


class CalibrationError(TofcutError):
    """The belt could not be found, or its map not written."""


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 < value < 3600:
        raise argparse.ArgumentTypeError(f"--seconds must be in (0, 3600), not {text}")
    return value


def _source(text: str) -> SourceSpec:
    try:
        return SourceSpec.parse(text)
    except SourceError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "calibrate", help="find the belt (plane, travel, speed, width) and write it to a map"
    )
    p.add_argument(
        "source", type=_source, metavar="SOURCE",
        help="usb, usb:SERIAL, emulator[:SCENE] or FILE.tofcap (its metadata's belt unread)",
    )  # fmt: skip
    p.add_argument(
        "--seconds", type=_seconds, default=DEFAULT_SECONDS,
        help=f"look at most this long (default {DEFAULT_SECONDS:g} s; less once settled)",
    )  # fmt: skip
    p.add_argument(
        "-o", "--output", type=Path, metavar="MAP.toml",
        help="write the belt as a conveyor map's [belt] (an existing map keeps its other keys)",
    )  # fmt: skip
    add_camera_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Find the belt from the source and report it (and write the map when asked)."""
    existing = read_map(args.output) if args.output is not None else {}
    try:
        opened = open_source(
            args.source, realtime=not args.fast, seed=args.seed,
            amplitude_threshold=args.amplitude_threshold,
        )  # fmt: skip
    except OSError as exc:  # a capture that cannot be read
        raise CalibrationError(f"{args.source.arg}: {exc.strerror or exc}") from None
    device = opened.device
    try:
        if isinstance(device, Camera):
            configure(opened, config_from_args(args, device.config))
        last: list[Frame] = []

        def frames() -> Iterator[Frame]:
            for frame in device.frames():
                last[:] = [frame]
                yield frame

        estimate = find_belt(frames(), args.seconds)
    finally:
        opened.close()
    lines = report(estimate, str(args.source))
    if estimate.belt is not None and last:
        lines += wrapped_lines(estimate.belt.geometry, last[0])
    for line in lines:
        print(line)
    if estimate.belt is None:
        raise CalibrationError(f"no belt plane stands out in {estimate.frames} frames")
    if args.output is not None:
        write_map(args.output, estimate, existing)
        print(f"wrote {args.output}: [belt] {_what_was_written(estimate)}")
    return 0


def report(estimate: BeltEstimate, source: str) -> list[str]:
    """The found geometry with its fit quality, a few lines."""
    head = f"belt from {estimate.frames} frames ({estimate.seconds:.1f} s) of {source}"
    if estimate.belt is None:
        return [f"{head}: no plane found"]
    g = estimate.belt.geometry

    def vec(v: Any) -> str:
        return "(" + ", ".join(f"{float(x):+.4f}" for x in v) + ")"

    lines = [
        f"{head}:",
        f"  plane: normal {vec(g.normal)}, {float(g.origin[2]):.4f} m out along the optical "
        f"axis; rms {estimate.plane_rms_m * 1e3:.1f} mm, {estimate.inlier_share:.0%} of the "
        f"pixels on it ({estimate.layers} level surfaces seen)",
    ]
    speed = estimate.belt.speed_mps
    if estimate.travel == "found" and speed is not None:
        lines.append(
            f"  travel: direction {vec(g.direction)} at {speed:.4f} m/s ({estimate.tops} tops "
            f"followed; spread {estimate.direction_spread_deg:.2f}°, "
            f"{estimate.speed_spread_mps * 1e3:.1f} mm/s)"
        )
    elif estimate.travel == "none":
        lines.append("  travel: none found (nothing moved on the belt)")
    else:
        lines.append("  travel: unsure (things moved, but too little or not together to tell)")
    if g.width_m is not None:
        lines.append(f"  width: {g.width_m:.3f} m; centre line through {vec(g.point)}")
    else:
        lines.append("  width: not known (both edges must be in view, and the travel known)")
    lines.append(f"  {estimate.describe()}")
    return lines


WRAP_SIGMAS = 3.0
"""A pixel reads the belt, or the belt a whole unambiguous range too near, within this many
of its range noise sigmas..."""
WRAP_REACH_M = 0.5
"""...where that is at most this much (louder pixels could be read either way)."""
WRAP_MIN_SHARE = 0.01
"""Less of the belt than this read too near is not worth a line (a flying pixel or two)."""


def wrapped_share(belt: BeltGeometry, frame: Frame) -> float:
    """Of the pixels that read the belt (along their rays, within its width where known), the
    share that read it whole unambiguous ranges too near: it lies past the range the
    camera's modulation frequency can tell, and its phase wrapped round."""
    limit = unambiguous_range_m(frame.header.mod_code)
    rays = frame.rays
    has = (frame.range > 0) & np.isfinite(rays).all(axis=-1)
    along = belt.range_along(rays[has])
    reach = WRAP_SIGMAS * range_noise(frame, 0.001)[has]
    read = frame.range[has]
    usable = np.isfinite(along) & (reach <= WRAP_REACH_M)
    with np.errstate(invalid="ignore"):
        seen = usable & (np.abs(read - along) < reach)
        wrapped = usable & (along > limit) & (np.abs(read - np.mod(along, limit)) < reach)
    total = np.count_nonzero(seen | wrapped)
    return float(np.count_nonzero(wrapped) / total) if total else 0.0


def wrapped_lines(belt: BeltGeometry, frame: Frame) -> list[str]:
    """A line saying how much of the belt lies past the unambiguous range, if any does
    (`WRAP_MIN_SHARE`): there the camera reads the belt, and what rides on it, a whole range
    too near, which no tracking undoes."""
    code = frame.header.mod_code
    if code not in MOD_FREQ_MHZ:
        return []  # not a SwissRanger's frame: no modulation to judge
    share = wrapped_share(belt, frame)
    if share < WRAP_MIN_SHARE:
        return []
    limit = unambiguous_range_m(code)
    return [
        f"  range: {share:.0%} of the belt in view lies past the unambiguous range "
        f"({limit:.2f} m at {MOD_FREQ_MHZ[code]:g} MHz), read {limit:.2f} m (or a multiple) "
        "too near, and so is what rides there; a lower modulation frequency or a nearer "
        "camera sees it whole"
    ]


def map_document(estimate: BeltEstimate, existing: dict[str, Any]) -> dict[str, Any]:
    """A conveyor map's document with the found belt as its `[belt]`: the existing map's other
    tables and keys kept (its `diverter_m` too); a width it had is dropped unless found again
    (an old width around a new centre line would be wrong)."""
    if estimate.belt is None or estimate.travel != "found":
        raise CalibrationError(
            "no travel direction found, and a map's belt needs one: run it while the belt "
            "carries objects (or for longer)"
        )
    g = estimate.belt.geometry
    doc = {k: (dict(v) if isinstance(v, dict) else v) for k, v in existing.items()}
    belt = doc.get("belt", {})
    if not isinstance(belt, dict):
        raise CalibrationError("the map's [belt] is not a table")
    kept = {k: v for k, v in belt.items() if k not in ("direction", "normal", "point", "width_m")}
    found: dict[str, Any] = {
        "direction": [round(float(x), 6) for x in g.direction],
        "normal": [round(float(x), 6) for x in g.normal],
        "point": [round(float(x), 5) for x in g.point],
    }
    if g.width_m is not None:
        found["width_m"] = round(float(g.width_m), 4)
    doc["belt"] = found | kept
    try:
        parse_conveyor_config(doc)
    except ConfigError as exc:
        raise CalibrationError(f"the map would not be valid: {exc}") from None
    return doc


def read_map(path: Path) -> dict[str, Any]:
    """The map a found belt will extend ({} when there is none yet), read before any frame
    is looked at: a path that cannot be written, or a file that is no map, fails at once."""
    _check_writable(path)
    if not path.exists():
        return {}
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CalibrationError(f"{path}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path} is not a TOML map: {exc}") from None


def write_map(path: Path, estimate: BeltEstimate, existing: dict[str, Any]) -> None:
    """Write the conveyor map at `path`: `existing` (the map read from there, or {}) with the
    found belt as its `[belt]`; the speed goes in as a comment (the map takes no speed: the
    conveyor's encoder is the truth). Comments of the existing map are not kept."""
    doc = map_document(estimate, existing)
    assert estimate.belt is not None
    note = [f"found by tofcut calibrate from {estimate.frames} frames"]
    if estimate.belt.speed_mps is not None:
        note.append(
            f"speed found: {estimate.belt.speed_mps:.4f} m/s (for information: the conveyor's "
            "encoder is the truth)"
        )
    text = dumps(doc, {"belt": note})
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise CalibrationError(f"cannot write {path}: {exc.strerror or exc}") from None


def _check_writable(path: Path) -> None:
    """Fail before looking at any frame when the map cannot be written there."""
    folder = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise CalibrationError(f"{path} is a folder, not a map file")
    if not folder.is_dir():
        raise CalibrationError(f"cannot write {path}: no folder {folder}")
    if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise CalibrationError(f"cannot write {path}: permission denied")


def _what_was_written(estimate: BeltEstimate) -> str:
    assert estimate.belt is not None
    keys = "direction, normal, point" + (
        ", width_m" if estimate.belt.geometry.width_m is not None else ""
    )
    return keys + ("; the speed as a comment" if estimate.belt.speed_mps is not None else "")
