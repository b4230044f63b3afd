"""How fast a scene renders: the number `tofcut bench` reports (one core, no USB, no driver)."""

from __future__ import annotations

import time

from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import scene_exposure


def render_rate(name: str, frames: int = 100, seed: int = 0) -> float:
    """Frames per second of `render` for a scene at its own settings, after one warm-up frame."""
    source = open_scene(name, seed)
    period = source.settings.frame_period * 1e-4 or 0.02
    source.render(scene_exposure(source, 0.0, 0))
    start = time.perf_counter()
    for i in range(1, frames + 1):
        source.render(scene_exposure(source, i * period, i))
    return frames / (time.perf_counter() - start)
