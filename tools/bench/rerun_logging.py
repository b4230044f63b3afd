"""Bench stage: what logging to a rerun file costs next to tracking the same frames
(`tools.pipeline.rerun_sink.measure_logging_cost`), on the conveyor at 176×144."""

from __future__ import annotations

from typing import Any

from tofcut.sim.catalog import open_scene
from tofcut.tools.bench.frames import raw_run
from tofcut.tools.bench.timing import CLOCK
from tofcut.tools.bench.tracker import WARM_FRAMES, BeltTracker
from tofcut.tools.pipeline.rerun_sink import measure_logging_cost
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import TrackedFrame

SCENE = "conveyor"


def run(quick: bool) -> dict[str, Any]:
    """{frames, tracking_ms_per_frame, logging_cpu_ms_per_frame, ratio, ...}."""
    source = open_scene(SCENE, 0)
    timed = 10 if quick else 200
    raws, _ = raw_run(source, WARM_FRAMES + timed)
    bench = BeltTracker(source)
    for raw in raws[:WARM_FRAMES]:
        bench.step(raw)
    tracked_run: list[tuple[TrackedFrame, PipelineStatus]] = []
    tracking_s = 0.0
    for i, raw in enumerate(raws[WARM_FRAMES:]):
        start = CLOCK()
        tracked = bench.step(raw)
        took = CLOCK() - start
        tracking_s += took
        status = PipelineStatus(50.0, took, i + 1, 0, len(tracked.tracks), bench.speed_mps)
        tracked_run.append((tracked, status))
    cost = measure_logging_cost(tracked_run, source.calibration, tracking_s, bench.direction)
    return {
        "scene": SCENE,
        "frames": cost.frames,
        "tracking_ms_per_frame": 1e3 * tracking_s / cost.frames,
        "logging_cpu_ms_per_frame": cost.cpu_ms_per_frame,
        "writer_python_ms_per_frame": 1e3 * cost.writer_cpu_s / cost.frames,
        "log_call_us_per_frame": 1e6 * cost.log_calls_s / cost.frames,
        "ratio": cost.ratio,
        "file_kib_per_frame": cost.file_bytes / 1024 / cost.frames,
    }
