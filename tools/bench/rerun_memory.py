"""Does a long run written to a rerun file hold resident memory flat? Measure it.

`python -m tofcut.tools.bench.rerun_memory --frames 10000` tracks a short emulated conveyor run,
then hands it to a `RerunSink` writing a temporary .rrd file round and round, each round
renumbered (sequence numbers and device time go on) and with new track ids (on a conveyor
ids grow without end), while `soak.MemorySampler` samples RSS. It prints RSS as the frames
go and the growth over the second half (the least-squares trend, as `tofcut soak` has it).
The file is written in segments as `tofcut` writes it (`--segment-mb`, default 256; 0 writes one
file, whose footer's manifest rerun keeps in memory until the end).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from tofcut.driver.calibration import Calibration
from tofcut.sim.catalog import open_scene
from tofcut.tools.bench.frames import raw_run
from tofcut.tools.bench.tracker import WARM_FRAMES, BeltTracker
from tofcut.tools.experiments.soak import MemoryGrowth, MemorySampler, rss_bytes
from tofcut.tools.pipeline.rerun_sink import RerunSink
from tofcut.tools.pipeline.rerun_target import MB, SEGMENT_MB, RerunTarget
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import Track, TrackedFrame

MIB = 1024 * 1024
Run = Sequence[tuple[TrackedFrame, PipelineStatus]]


def shifted(
    tracked: TrackedFrame, sequence: int, device_time_us: int, id_offset: int
) -> TrackedFrame:
    """`tracked` as frame `sequence` at `device_time_us`, its track ids raised by `id_offset`."""
    f = tracked.frame
    header = dataclasses.replace(f.header, sequence=sequence, device_time_us=device_time_us)
    labels = np.where(tracked.labels > 0, tracked.labels + id_offset, 0).astype(np.uint16)

    def track(t: Track) -> Track:
        return dataclasses.replace(t, id=t.id + id_offset)

    return TrackedFrame(
        frame=dataclasses.replace(f, header=header),
        labels=labels,
        tracks=tuple(track(t) for t in tracked.tracks),
        born=tuple(i + id_offset for i in tracked.born),
        ended=tuple(i + id_offset for i in tracked.ended),
    )


def endless(run: Run, frames: int) -> Iterator[tuple[TrackedFrame, PipelineStatus]]:
    """`frames` frames of `run` round and round: time goes on, every round has new ids."""
    first, last = run[0][0].frame, run[-1][0].frame
    period_us = (last.device_time_us - first.device_time_us) // max(len(run) - 1, 1)
    span = 1 + max((t.id for tracked, _ in run for t in tracked.tracks), default=0)
    for i in range(frames):
        rounds, k = divmod(i, len(run))
        if span * (rounds + 1) > np.iinfo(np.uint16).max:
            raise ValueError("too many frames: track ids would overflow the 16-bit masks")
        tracked, status = run[k]
        yield (
            shifted(tracked, i, first.device_time_us + i * period_us, span * rounds),
            dataclasses.replace(status, frames=i + 1),
        )


def tracked_conveyor(
    frames: int,
) -> tuple[Calibration, npt.NDArray[np.float64], list[tuple[TrackedFrame, PipelineStatus]]]:
    """The emulated conveyor tracked as `tofcut track` tracks it: `frames` frames after warm-up."""
    source = open_scene("conveyor", 0)
    raws, _ = raw_run(source, WARM_FRAMES + frames)
    bench = BeltTracker(source)
    run = []
    for i, raw in enumerate(raws):
        start = time.perf_counter()
        tracked = bench.step(raw)
        took = time.perf_counter() - start
        if i >= WARM_FRAMES:
            status = PipelineStatus(10.0, took, i + 1, 0, len(tracked.tracks), bench.speed_mps)
            run.append((tracked, status))
    return source.calibration, bench.direction, run


def measure(
    run: Run,
    calibration: Calibration,
    frames: int,
    belt_direction: npt.ArrayLike | None = None,
    report_every: int = 0,
    segment_mb: float = SEGMENT_MB,
) -> MemoryGrowth:
    """RSS while `frames` frames of `run` (see `endless`) are written to a temporary file,
    in segments of `segment_mb` MB (0: one file)."""
    with tempfile.TemporaryDirectory(prefix="tofcut-rerun-memory-") as tmp:
        target = RerunTarget.save(Path(tmp) / "run.rrd", segment_bytes=round(segment_mb * MB))
        sink = RerunSink(calibration, target, belt_direction)
        sampler = MemorySampler(interval_s=0.1).start()
        try:
            for i, (tracked, status) in enumerate(endless(run, frames), 1):
                sink.log(tracked, status)
                if report_every and i % report_every == 0:
                    print(
                        f"frame {i}: RSS {rss_bytes() / MIB:.1f} MiB, file {len(sink.files)}",
                        flush=True,
                    )
        finally:
            sink.close()
        return sampler.stop()


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=10000, help="frames to write (default 10000)")
    p.add_argument("--base", type=int, default=60, help="emulated frames tracked (default 60)")
    p.add_argument(
        "--segment-mb",
        type=float,
        default=SEGMENT_MB,
        help=f"a new file at this size (default {SEGMENT_MB:g}; 0: one file)",
    )
    args = p.parse_args(argv)
    calibration, direction, run = tracked_conveyor(args.base)
    start = time.monotonic()
    grown = measure(
        run, calibration, args.frames, direction, args.frames // 10, segment_mb=args.segment_mb
    )
    per_frame = grown.second_half_growth_b / (args.frames / 2)
    print(
        f"{args.frames} frames in {time.monotonic() - start:.0f} s; RSS {grown.start_b / MIB:.1f} "
        f"MiB at the start, {grown.half_b / MIB:.1f} at half time, {grown.end_b / MIB:.1f} at "
        f"the end (peak {grown.peak_b / MIB:.1f}); growth over the second half "
        f"{grown.second_half_growth_b / MIB:.1f} MiB ({per_frame / 1024:.2f} KiB a frame)"
    )


if __name__ == "__main__":
    main()
