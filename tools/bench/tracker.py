"""Bench stage: the tracker, raw bytes to tracks (the driver's frame parser, demodulation and
`Tracker.update`), with
1, 5, 10 and 20 boxes in view (`sim.crowd`), and with 10 boxes at three sensor sizes.

Each case renders its frames first, then runs a fresh tracker over them several times: the
first frames (learning the empty scene, confirming the boxes) untimed, the rest timed one
by one (fewer frames at the larger sensors, at least 10). Frames per second is one over the
median frame time; latency percentiles are over every timed frame of every repetition.
Times are CPU time of the thread (see `bench_timing`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.frames import RawFrame
from tofcut.driver.stream import FrameParser
from tofcut.sim.crowd import crowd_source
from tofcut.sim.renderer import SceneSource
from tofcut.tools.bench.frames import device_info, wire_run
from tofcut.tools.bench.timing import CLOCK, percentiles_ms
from tofcut.tools.pipeline.sources import belt_of, scene_metadata
from tofcut.tracker.belt_prior import known_speed_prior
from tofcut.tracker.tracker import Tracker
from tofcut.tracker.tracks import TrackedFrame

OBJECTS = (1, 5, 10, 20)
SIZES = ((176, 144), (352, 288), (640, 480))
SIZE_OBJECTS = 10
WARM_FRAMES = 20
"""Untimed: the background model learns from 10, a box is confirmed after 3 more."""


class BeltTracker:
    """A tracker set up as `tofcut track` sets it up for an emulated scene with a belt."""

    def __init__(self, source: SceneSource) -> None:
        belt = belt_of(scene_metadata(source))
        assert belt is not None
        assert belt.speed_mps is not None
        self.tracker = Tracker(belt=belt.geometry)
        self.direction = belt.geometry.direction
        self.speed_mps = belt.speed_mps
        self.prior = known_speed_prior(belt)
        self.optics = Optics.from_calibration(source.calibration)
        self.parser = FrameParser(device_info(source))

    def step(self, raw: RawFrame) -> TrackedFrame:
        """Raw frame to tracks."""
        return self.tracker.update(demodulate(raw, self.optics), self.prior)

    def step_bytes(self, wire: bytes) -> TrackedFrame:
        """One frame's bytes, as they came over USB, to tracks."""
        (raw,) = self.parser.feed(wire, 0)
        return self.step(raw)


def time_tracking(source: SceneSource, timed: int, repeats: int) -> dict[str, Any]:
    """Frame times of raw bytes → tracks over `timed` frames after the warm-up, `repeats` times."""
    wires, _ = wire_run(source, WARM_FRAMES + timed)
    per_frame: list[float] = []
    in_view: list[int] = []
    for _ in range(repeats):
        bench = BeltTracker(source)
        for wire in wires[:WARM_FRAMES]:
            bench.step_bytes(wire)
        for wire in wires[WARM_FRAMES:]:
            start = CLOCK()
            tracked = bench.step_bytes(wire)
            per_frame.append(CLOCK() - start)
            in_view.append(sum(t.visible for t in tracked.tracks))
    median = float(np.median(per_frame))
    return {
        "frame_s": median,
        "fps": 1.0 / median,
        "latency_ms": percentiles_ms(per_frame),
        "tracks_in_view": float(np.median(in_view)),
        "frames_timed": len(per_frame),
    }


def run(quick: bool) -> dict[str, Any]:
    """{"objects": [{objects, ...timing}], "sizes": [{width, height, pixels, ...timing}]};
    the 176×144 row of "sizes" is the 10-object row of "objects" (the same measurement)."""
    timed, repeats = (5, 1) if quick else (60, 3)
    by_objects = []
    for n in (1, SIZE_OBJECTS) if quick else OBJECTS:
        by_objects.append({"objects": n, **time_tracking(crowd_source(n), timed, repeats)})
    ten = next(r for r in by_objects if r["objects"] == SIZE_OBJECTS)
    width, height = SIZES[0]
    by_size = [{"width": width, "height": height, "pixels": width * height, **ten}]
    for width, height in () if quick else SIZES[1:]:
        source = crowd_source(SIZE_OBJECTS, width, height)
        row = {"width": width, "height": height, "pixels": width * height}
        fewer = max(10, timed * SIZES[0][0] * SIZES[0][1] // (width * height))
        by_size.append({**row, **time_tracking(source, fewer, repeats)})
    return {"objects": by_objects, "sizes": by_size, "size_objects": SIZE_OBJECTS}
