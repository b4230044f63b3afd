"""`tofcut scenes`: list the built-in scenes; draw each (intensity, range, truth labels); or
draw a line of a scene family from a seed (`--family conveyor --seed N`)."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path
from typing import Any

from tofcut.sim.family import FAMILIES
from tofcut.sim.scene_file import SceneError


def register(subparsers: Any) -> None:
    """Add the `scenes` subcommand."""
    parser = subparsers.add_parser(
        "scenes",
        help="list the emulator's scenes and draw them, or draw a family's line from a seed",
        description="List the built-in emulator scenes; with --out, write NAME.png for each: "
        "decoded intensity, decoded range and ground-truth labels side by side. With --family, "
        "draw the family's line from --seed instead: print what was drawn, write its scene file "
        "with --toml-out, and its picture with --out. The emulator opens the same line as "
        "emulator:family:FAMILY:SEED (docs/family.md).",
    )
    parser.add_argument("names", nargs="*", help="scenes or scene files (default: all built-in)")
    parser.add_argument("--out", type=Path, help="folder for the pictures, e.g. docs/scenes")
    parser.add_argument("--time", type=float, default=0.0, help="scene time in seconds (0)")
    parser.add_argument(
        "--seed", type=int, default=0,
        help="noise and calibration seed (0); with --family, the seed the line is drawn from "
        "(its picture then uses noise seed 0, as emulator:family:FAMILY:SEED does)",
    )  # fmt: skip
    parser.add_argument("--scale", type=int, default=3, help="pixels per sensor pixel (3)")
    parser.add_argument(
        "--family", choices=FAMILIES, help="draw a line of this scene family from --seed"
    )
    parser.add_argument(
        "--toml-out", type=Path, metavar="FILE.toml",
        help="with --family: write the drawn line as a scene file (edit it, then record it "
        "with `tofcut record emulator:FILE.toml`)",
    )  # fmt: skip
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """List the scenes, and draw them when asked to; or draw a family's line."""
    if args.family is not None:
        return _run_family(args)
    if args.toml_out is not None:
        raise SceneError("--toml-out writes a family's line: give --family too")
    from tofcut.sim.catalog import open_scene, scene_names
    from tofcut.sim.preview import scene_picture

    names = args.names or scene_names()
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    for name in names:
        source = open_scene(name, args.seed)
        line = f"{source.name:12s} {source.scene.description}"
        if args.out is not None:
            path = args.out / f"{source.name}.png"
            scene_picture(source, args.time, args.scale).save(path)
            line += f"  -> {path}"
        print(line)
    return 0


def _run_family(args: argparse.Namespace) -> int:
    """Draw one line of a family: its summary, and its scene file and picture when asked."""
    from tofcut.sim.family import draw_line
    from tofcut.sim.preview import scene_picture
    from tofcut.sim.renderer import SceneSource

    if args.names:
        raise SceneError("give scene names or --family, not both")
    if args.seed < 0:
        raise SceneError(f"a family's seed is a whole number ≥ 0, not {args.seed}")
    line = draw_line(args.family, args.seed)
    print(textwrap.fill(line.summary(), 100, break_on_hyphens=False))
    if args.toml_out is not None:
        args.toml_out.parent.mkdir(parents=True, exist_ok=True)
        args.toml_out.write_text(line.toml(), encoding="utf-8")
        print(f"scene file: {args.toml_out}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        path = args.out / f"{line.name}.png"
        scene_picture(SceneSource(line.scene(), 0), args.time, args.scale).save(path)
        print(f"picture: {path}")
    return 0
