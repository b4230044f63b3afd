"""Where the tracker's time goes: the bench's tracker stage (raw bytes → tracks, 10 boxes)
under cProfile, its top functions by own time and by cumulative time.

    python -m tofcut.tools.bench.profile [--frames N] [--objects N] [--top N]

What to speed up first, before and after a change (docs/benchmarks.md); cProfile's own
overhead inflates the times of functions called often, so the ranking matters, not the ms.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats

from tofcut.sim.crowd import crowd_source
from tofcut.tools.bench.frames import wire_run
from tofcut.tools.bench.tracker import WARM_FRAMES, BeltTracker


def profile(objects: int, frames: int, top: int) -> str:
    """The report: `frames` frames of `objects` boxes, after the bench's warm-up."""
    source = crowd_source(objects)
    wires, _ = wire_run(source, WARM_FRAMES + frames)
    bench = BeltTracker(source)
    for wire in wires[:WARM_FRAMES]:
        bench.step_bytes(wire)
    profiler = cProfile.Profile()
    profiler.enable()
    for wire in wires[WARM_FRAMES:]:
        bench.step_bytes(wire)
    profiler.disable()
    out = io.StringIO()
    for order in ("tottime", "cumulative"):
        pstats.Stats(profiler, stream=out).sort_stats(order).print_stats(top)
    return out.getvalue()


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m tofcut.tools.bench.profile")
    parser.add_argument("--objects", type=int, default=10, choices=range(1, 41), metavar="N")
    parser.add_argument("--frames", type=int, default=200, choices=range(1, 10001), metavar="N")
    parser.add_argument("--top", type=int, default=10, choices=range(1, 101), metavar="N")
    args = parser.parse_args()
    print(profile(args.objects, args.frames, args.top))


if __name__ == "__main__":
    main()
