"""Bench stage: how fast the emulator renders each built-in scene and the crowds of 1 to 20
boxes, at 176×144: the median CPU time of a frame over consecutive frames at the scene's
frame rate, on the bench's clock."""

from __future__ import annotations

from typing import Any

import numpy as np

from tofcut.sim.catalog import open_scene, scene_names
from tofcut.sim.crowd import crowd_source
from tofcut.sim.preview import scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.tools.bench.timing import CLOCK

CROWDS = (1, 5, 10, 20)


def frame_seconds(source: SceneSource, frames: int) -> float:
    """Median CPU time of rendering one of `frames` consecutive frames, after one warm-up."""
    period = source.settings.frame_period * 1e-4 or 0.02
    source.render(scene_exposure(source, 0.0, 0))
    times = []
    for i in range(1, frames + 1):
        exposure = scene_exposure(source, i * period, i)
        start = CLOCK()
        source.render(exposure)
        times.append(CLOCK() - start)
    return float(np.median(times))


def run(quick: bool) -> dict[str, Any]:
    """{"scenes": [{scene, fps}], "crowds": [{objects, fps}]}."""
    frames = 5 if quick else 50
    scenes = [
        {"scene": name, "fps": 1.0 / frame_seconds(open_scene(name, 0), frames)}
        for name in scene_names()
    ]
    crowds = [
        {"objects": n, "fps": 1.0 / frame_seconds(crowd_source(n), frames)}
        for n in (CROWDS[:2] if quick else CROWDS)
    ]
    return {"scenes": scenes, "crowds": crowds}
