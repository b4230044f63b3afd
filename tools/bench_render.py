"""Bench stage: how fast the emulator renders each built-in scene (`sim.bench.render_rate`)
and the crowds of 1 to 20 boxes, at 176×144."""

from __future__ import annotations

from functools import partial
from typing import Any

from tofcut.sim.bench import render_rate
from tofcut.sim.catalog import scene_names
from tofcut.sim.crowd import crowd_source
from tofcut.sim.preview import scene_exposure
from tofcut.tools.bench_timing import median_seconds

CROWDS = (1, 5, 10, 20)


def run(quick: bool) -> dict[str, Any]:
    """{"scenes": [{scene, fps}], "crowds": [{objects, fps}]}."""
    frames = 5 if quick else 100
    scenes = [{"scene": name, "fps": render_rate(name, frames)} for name in scene_names()]
    crowds = []
    for n in CROWDS[:2] if quick else CROWDS:
        source = crowd_source(n)
        exposure = scene_exposure(source, 1.0)
        seconds = median_seconds(
            partial(source.render, exposure), warmup=1, repeats=3 if quick else 21
        )
        crowds.append({"objects": n, "fps": 1.0 / seconds})
    return {"scenes": scenes, "crowds": crowds}
