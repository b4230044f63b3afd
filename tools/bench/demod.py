"""Bench stage: demodulation (raw taps → range, amplitude, intensity, xyz) at three sensor
sizes, the fast path against spec §7 as written (`demodulate_reference`), and the renderer's
rate at the same sizes (the conveyor scene with the same field of view)."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

from tofcut.driver.demod import Optics, demodulate, demodulate_reference
from tofcut.driver.frames import Frame, RawFrame
from tofcut.sim.catalog import scene_path
from tofcut.sim.crowd import resized
from tofcut.sim.preview import scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import load_scene
from tofcut.tools.bench.frames import raw_run
from tofcut.tools.bench.timing import median_seconds

SIZES = ((176, 144), (352, 288), (640, 480))
FRAMES = 8
"""Distinct frames demodulated round and round."""


def _each(demod: Callable[[RawFrame, Optics], Frame], raws: list[RawFrame], optics: Optics) -> None:
    for raw in raws:
        demod(raw, optics)


def run(quick: bool) -> dict[str, Any]:
    """{"rows": [{width, height, pixels, fast_fps, reference_fps, ratio, render_fps}]}."""
    rows = []
    for width, height in SIZES[:2] if quick else SIZES:
        source = SceneSource(resized(load_scene(scene_path("conveyor")), width, height), 0)
        raws, _ = raw_run(source, 2 if quick else FRAMES)
        optics = Optics.from_calibration(source.calibration)
        pixels = width * height
        number = max(1, (3 if quick else 25) * 176 * 144 // pixels)
        repeats = 3 if quick else 9

        fast, ref = (
            median_seconds(partial(_each, fn, raws, optics), warmup=2, repeats=repeats,
                           number=number) / len(raws)
            for fn in (demodulate, demodulate_reference)
        )  # fmt: skip
        exposure = scene_exposure(source, 0.5)
        render = median_seconds(
            partial(source.render, exposure), warmup=1, repeats=3 if quick else 7
        )
        rows.append(
            {
                "width": width,
                "height": height,
                "pixels": pixels,
                "fast_s": fast,
                "reference_s": ref,
                "fast_fps": 1.0 / fast,
                "reference_fps": 1.0 / ref,
                "ratio": ref / fast,
                "render_s": render,
                "render_fps": 1.0 / render,
            }
        )
    return {"rows": rows}
