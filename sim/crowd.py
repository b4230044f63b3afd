"""Scenes made for measuring: the conveyor with N boxes in view, and any scene at another
sensor size. `tofcut bench` uses them to see how costs grow with objects and pixels."""

from __future__ import annotations

import dataclasses
import tomllib
from typing import Any

import numpy as np

from tofcut.sim.catalog import scene_path
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene import Scene
from tofcut.sim.scene_file import SceneError, parse_scene

GRID = (5, 4)
"""Places for boxes: columns along the belt, rows across it."""
PITCH_M = (0.16, 0.125)
"""Distance between neighbouring places (along, across)."""
CRAWL_MPS = 0.02
"""Belt speed of a crowd: slow enough that every box stays in view for a few seconds."""
MAX_BOXES = GRID[0] * GRID[1]


def crowd_scene(boxes: int, seed: int = 0) -> Scene:
    """The conveyor scene with `boxes` (1 to 20) boxes in view at t = 0, spread over a 5 × 4
    grid under the camera, crawling along the belt; sizes and turns are drawn from `seed`."""
    doc = crowd_doc(boxes, seed)
    return parse_scene(doc, doc["name"])


def crowd_doc(boxes: int, seed: int = 0) -> dict[str, Any]:
    """`crowd_scene`'s scene file, as a TOML document (`driver.toml_writer.dumps` writes it)."""
    if not 1 <= boxes <= MAX_BOXES:
        raise SceneError(f"a crowd has 1 to {MAX_BOXES} boxes, not {boxes}")
    doc = tomllib.loads(scene_path("conveyor").read_text(encoding="utf-8"))
    doc["name"] = f"crowd-{boxes}"
    doc["description"] = f"{boxes} boxes in view on a crawling belt"
    doc["belt"]["speed"] = CRAWL_MPS
    rng = np.random.default_rng([seed, boxes])
    cells = np.unique(np.linspace(0, MAX_BOXES - 1, boxes).round().astype(int))
    objects = []
    for k, cell in enumerate(cells):
        col, row = divmod(int(cell), GRID[1])
        x = (col - (GRID[0] - 1) / 2) * PITCH_M[0]
        y = (row - (GRID[1] - 1) / 2) * PITCH_M[1]
        height = float(rng.uniform(0.05, 0.14))
        objects.append(
            {
                "name": f"box-{k + 1}",
                "shape": "box",
                "size": [float(rng.uniform(0.08, 0.11)), float(rng.uniform(0.07, 0.09)), height],
                "position": [x, y, height / 2],
                "rotation_deg": [0.0, 0.0, float(rng.uniform(-15, 15))],
                "albedo": float(rng.uniform(0.43, 0.47)),
                "motion": "belt",
            }
        )
    doc["object"] = objects
    return doc


def resized(scene: Scene, width: int, height: int) -> Scene:
    """The same scene seen by a sensor of another size: the same horizontal field of view,
    square pixels kept square (a 4:3 sensor sees a little more above and below)."""
    lens = scene.lens
    if width < 8 or height < 8:
        raise SceneError(f"a sensor must be at least 8x8 pixels, not {width}x{height}")
    k = width / lens.width
    scaled = dataclasses.replace(
        lens, width=width, height=height, fx=lens.fx * k, fy=lens.fy * k,
        cx=(lens.cx + 0.5) * k - 0.5, cy=(lens.cy + 0.5) * height / lens.height - 0.5,
    )  # fmt: skip
    return dataclasses.replace(scene, lens=scaled)


def crowd_source(boxes: int, width: int = 176, height: int = 144, seed: int = 0) -> SceneSource:
    """A renderable crowd at a sensor size."""
    scene = crowd_scene(boxes, seed)
    if (width, height) != (scene.lens.width, scene.lens.height):
        scene = resized(scene, width, height)
    return SceneSource(scene, seed)
