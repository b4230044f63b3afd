"""`tofcut scenes`: list the built-in scenes; draw each (intensity, range, truth labels)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add the `scenes` subcommand."""
    parser = subparsers.add_parser(
        "scenes",
        help="list the emulator's scenes and draw them",
        description="List the built-in emulator scenes; with --out, write NAME.png for each: "
        "decoded intensity, decoded range and ground-truth labels side by side.",
    )
    parser.add_argument("names", nargs="*", help="scenes or scene files (default: all built-in)")
    parser.add_argument("--out", type=Path, help="folder for the pictures, e.g. docs/scenes")
    parser.add_argument("--time", type=float, default=0.0, help="scene time in seconds (0)")
    parser.add_argument("--seed", type=int, default=0, help="noise and calibration seed (0)")
    parser.add_argument("--scale", type=int, default=3, help="pixels per sensor pixel (3)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """List the scenes, and draw them when asked to."""
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
