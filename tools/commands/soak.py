"""`tofcut soak --minutes N [--seed S]`: the emulated line under random faults, for a long time.

The emulated camera (through pyusb, reconnecting), the tracker, the rerun file output and,
with `--conveyor-emulator`, the emulated conveyor run as `tofcut live` runs them, while
faults from the emulator's list (`tofcut.sim.drill.FAULTS`, and the conveyor link's) are
injected one at a time at random, seeded. The report says where every lost frame went.
"""

from __future__ import annotations

import argparse
import collections
import functools
import math
import random
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from tofcut.driver.camera import Camera
from tofcut.driver.events import DeviceEvent
from tofcut.sim.drill import FAULTS
from tofcut.sim.modbus_server import Fault
from tofcut.tools.commands.options import add_camera_options, config_from_args
from tofcut.tools.experiments.soak import (
    HOST_OVERFLOW,
    UNEXPLAINED,
    FaultInjector,
    Inject,
    LossAudit,
    MemoryGrowth,
    MemorySampler,
)
from tofcut.tools.pipeline.belt_source import BeltResolution, resolve_run_belt
from tofcut.tools.pipeline.conveyor_line import ConveyorLine, add_conveyor_options, open_conveyor
from tofcut.tools.pipeline.losses import describe_losses, event_level
from tofcut.tools.pipeline.outputs import ConveyorOutput, RerunOutput
from tofcut.tools.pipeline.rerun_sink import RerunSink
from tofcut.tools.pipeline.rerun_target import MB, RerunTarget
from tofcut.tools.pipeline.run import EventRelay, LiveFeed, Output, RunSummary, run
from tofcut.tools.pipeline.run_belt import RunBelt
from tofcut.tools.pipeline.sources import (
    Opened,
    SourceError,
    SourceSpec,
    configure,
    open_source,
)
from tofcut.tracker.tracker import Tracker

MAX_GROWTH_MIB = 10.0
"""Default bound on resident memory growth over the run's second half (MiB): CI's soak command
grew -9.2 to 4.1 MiB in eleven runs in 16 MB files, 5-11 MiB in one file (docs/faults.md)."""
SOAK_FPS = 10.0
"""The soak's default frame rate: one the emulator, tracker and rerun keep up with on two
cores, so that the camera's FIFO never overflows on its own."""
SOAK_SEGMENT_MB = 16.0
"""The soak's rerun file is written in segments this size (MB), about 8 s at 10 fps: rerun keeps
a file's footer manifest in memory until the file closes (up to ~20 KiB a frame in real time,
bounded by the segment), so in one 256 MB segment a one-minute soak would see that bounded
growth and not what it is looking for; rolling files over under faults is exercised too."""
SETTLE_FRAMES = 20
MIB = 1 << 20


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "soak",
        help="run the emulated line under random faults; account for every lost frame",
        description=(
            "Run the emulated line (camera through pyusb, tracker, rerun file output, "
            "optionally the emulated conveyor) while faults from the emulator's list are "
            "injected at random (seeded), one at a time. Reports frames processed, frames lost "
            "per cause (sequence ranges; estimated vs counted), reconnects, latency "
            "percentiles and memory growth. Exits 1 on any unexplained loss (lost or damaged "
            "frames no injected fault accounts for and the camera did not flag as its FIFO "
            "overflowing), on a fault the stream did not recover from, or when resident memory "
            f"grew by more than --max-growth-mib (default {MAX_GROWTH_MIB:g} MiB) over the "
            "second half of the run (the first half is warm-up). The camera runs at "
            f"{SOAK_FPS:g} fps unless --fps says otherwise."
        ),
    )
    p.add_argument("--minutes", type=float, default=1.0, help="how long to run (default 1)")
    p.add_argument(
        "--scene", default="conveyor",
        help="the emulated scene (default conveyor), or a capture FILE.tofcap the emulated "
        "camera replays over and over",
    )  # fmt: skip
    p.add_argument(
        "--fault-every", type=float, default=3.0, metavar="S",
        help="mean quiet time between one fault settling and the next, s (default 3)",
    )  # fmt: skip
    p.add_argument(
        "--max-growth-mib", type=float, default=MAX_GROWTH_MIB, metavar="MIB",
        help=f"fail above this RSS growth over the second half (default {MAX_GROWTH_MIB:g})",
    )  # fmt: skip
    p.add_argument(
        "--save", type=Path, metavar="FILE.rrd",
        help="keep the rerun recording here, as FILE-0001.rrd, FILE-0002.rrd, ... once it "
        "outgrows --segment-mb (default: a temporary file, deleted at the end; it grows by "
        "about 190 KB a frame)",
    )  # fmt: skip
    p.add_argument(
        "--no-rerun", action="store_true",
        help="leave the rerun output out (to tell its memory growth from the pipeline's)",
    )  # fmt: skip
    p.add_argument(
        "--segment-mb", type=float, default=SOAK_SEGMENT_MB, metavar="MB",
        help=f"write the rerun recording in files of this size (default {SOAK_SEGMENT_MB:g}, "
        "so that the memory rerun holds for a file's footer is freed within the run; 0: one file)",
    )  # fmt: skip
    add_camera_options(p)
    add_conveyor_options(p)
    p.set_defaults(func=soak, fps=SOAK_FPS)


def camera_faults(opened: Opened) -> dict[str, Inject]:
    """The drill's camera faults, bound to the opened emulator and its bus."""
    bus, emu = opened.bus, opened.emulator
    assert bus is not None
    assert emu is not None
    return {name: functools.partial(inject, bus, emu) for name, inject in FAULTS.items()}


def conveyor_faults(line: ConveyorLine) -> dict[str, Inject]:
    """Faults of the emulated controller's link: three replies spoiled in each way."""
    server = line.server
    if server is None:
        return {}
    return {
        f"conveyor: 3 requests answered with {how}": functools.partial(server.inject, fault, 3)
        for fault, how in [
            (Fault.GARBAGE, "garbage"),
            (Fault.CRC, "bad CRCs"),
            (Fault.EXCEPTION, "busy exceptions"),
            (Fault.LOST, "silence"),
        ]
    }


def soak(args: argparse.Namespace) -> int:
    if args.minutes <= 0:
        raise SourceError("--minutes must be positive")
    if not (math.isfinite(args.segment_mb) and args.segment_mb >= 0):
        raise SourceError("--segment-mb must be a size in MB (0: one file)")
    rng = random.Random(args.seed)
    relay = EventRelay()
    opened = open_source(
        SourceSpec("emulator", args.scene), realtime=not args.fast, seed=args.seed,
        amplitude_threshold=args.amplitude_threshold, reconnect=True, on_event=relay.post,
        loop=True,  # a capture replays for as long as the soak runs
    )  # fmt: skip
    camera = opened.device
    assert isinstance(camera, Camera)
    try:
        configure(opened, config_from_args(args, camera.config))
        resolution = resolve_run_belt(args, opened)
        line = open_conveyor(args, opened, resolution=resolution)
        try:
            return _soak(args, rng, opened, camera, relay, line, resolution)
        finally:
            if line is not None:
                line.close()
    finally:
        opened.close()


def _soak(
    args: argparse.Namespace,
    rng: random.Random,
    opened: Opened,
    camera: Camera,
    relay: EventRelay,
    line: ConveyorLine | None,
    resolution: BeltResolution,
) -> int:
    belt = resolution.belt
    tracker = Tracker(belt=belt.geometry if belt else None)
    run_belt = RunBelt(resolution, tracker, line=line)
    faults = camera_faults(opened) | (conveyor_faults(line) if line else {})
    seconds = args.minutes * 60.0
    mode = "fast (virtual clock)" if args.fast else "real time"
    print(
        f"soak: {args.minutes:g} min, seed {args.seed}: emulator:{args.scene} at "
        f"{camera.config.describe()}, {mode}"
        + (", emulated conveyor" if line and line.server else "")
        + f"; {len(faults)} kinds of fault, ~{args.fault_every:g} s apart",
        flush=True,
    )
    with tempfile.TemporaryDirectory(prefix="tofcut-soak-") as tmp:
        path = args.save or Path(tmp) / "soak.rrd"
        direction = belt.geometry.direction if belt else None
        device_events: collections.Counter[str] = collections.Counter()
        handlers: list[Callable[[DeviceEvent], object]] = [lambda e: _count(device_events, e)]
        outputs: list[Output] = [] if line is None else [ConveyorOutput(line)]
        sink = None
        if not args.no_rerun:
            target = RerunTarget.save(path, round(args.segment_mb * MB))
            sink = RerunSink(camera.calibration, target, direction, name="soak")
            handlers.append(functools.partial(_log_event, sink))
            outputs.append(RerunOutput(sink))
        relay.start(handlers)
        audit = LossAudit(camera.stats, SETTLE_FRAMES)
        injector = FaultInjector(
            faults, audit, rng, quiet_s=args.fault_every, on_stuck=camera.stop,
            on_inject=lambda kind: print(f"{_clock(started)} fault: {kind}", flush=True),
        )  # fmt: skip
        memory = MemorySampler(interval_s=max(0.25, seconds / 400)).start()
        started = time.monotonic()
        feed = LiveFeed(camera, on_frame=audit.see).start()
        injector.start()
        try:
            summary = run(
                feed, camera.demodulate, tracker, outputs, stats=lambda: camera.stats,
                dropped=lambda: feed.dropped,
                prior=run_belt.at_frame,
                should_stop=lambda s: time.monotonic() - started >= seconds, events=relay,
            )  # fmt: skip
        finally:
            injector.stop()
            feed.stop()
            audit.finish()
        grown = memory.stop()
        if sink is not None:
            size = sum(f.stat().st_size for f in sink.files if f.exists())
            where = f"kept at {path}" if args.save else "deleted: --save FILE.rrd keeps it"
            print(f"{sink.summary()} ({size / MIB:.1f} MiB; {where})")
    print(run_belt.describe())
    return report(args, camera, summary, audit, injector, device_events, grown, line)


def _log_event(sink: RerunSink, event: DeviceEvent) -> None:
    sink.event(str(event), event_level(event))


def _count(counter: collections.Counter[str], event: DeviceEvent) -> None:
    counter[event.kind.value] += 1


def _clock(started: float) -> str:
    return f"[{time.monotonic() - started:7.1f} s]"


def report(
    args: argparse.Namespace,
    camera: Camera,
    summary: RunSummary,
    audit: LossAudit,
    injector: FaultInjector,
    device_events: collections.Counter[str],
    grown: MemoryGrowth,
    line: ConveyorLine | None,
) -> int:
    """Print the soak's report; 0 if it passed, 1 if not (the reasons are printed)."""
    stats = camera.stats
    print(
        f"frames: {summary.frames} processed in {summary.elapsed_s:.1f} s; "
        f"{summary.dropped} dropped by the tracker queue (the tracker fell behind)"
    )
    for text in describe_losses(stats):
        print(f"camera: {text}")
    accounted = audit.accounted
    print(f"lost frames by cause ({accounted} of {stats.lost} accounted for):")
    for cause, t in sorted(audit.tallies.items(), key=lambda kv: (kv[0].startswith("no "), kv[0])):
        text = (
            f"  {cause}: injected {t.injected}, lost {t.lost} ({t.estimated} estimated), "
            f"damaged {t.damaged}, reconnects {t.reconnects}"
        )
        if t.gaps:
            text += f"; sequence numbers {t.describe_ranges()}"
        print(text)
    if device_events:
        counts = ", ".join(f"{kind} {n}" for kind, n in sorted(device_events.items()))
        print(f"device events: {counts}")
    print(
        f"latency (arrival to tracks, {summary.latencies.count} frames): "
        f"p50 {summary.percentile_ms(50):.1f} ms, p95 {summary.percentile_ms(95):.1f} ms, "
        f"p99 {summary.percentile_ms(99):.1f} ms, max {summary.latencies.max_s * 1e3:.1f} ms"
    )
    growth_mib = grown.second_half_growth_b / MIB
    print(
        f"memory (RSS, {grown.samples} samples): {grown.start_b / MIB:.1f} MiB at the start, "
        f"{grown.half_b / MIB:.1f} at half time, {grown.end_b / MIB:.1f} at the end "
        f"(peak {grown.peak_b / MIB:.1f}); growth over the second half {growth_mib:.1f} MiB "
        f"(bound {args.max_growth_mib:g} MiB)"
    )
    if line is not None:
        print(line.summary())
    failures = []
    unexplained = audit.tallies.get(UNEXPLAINED)
    if unexplained is not None and (unexplained.lost or unexplained.damaged):
        failures.append(
            f"{unexplained.lost} lost and {unexplained.damaged} damaged frames no fault explains"
        )
    if accounted != stats.lost:
        failures.append(f"{stats.lost - accounted} lost frames were never attributed")
    if injector.unsettled:
        failures.append(f"the stream did not recover from: {', '.join(injector.unsettled)}")
    if growth_mib > args.max_growth_mib:
        failures.append(f"memory grew {growth_mib:.1f} MiB over the second half")
    overflow = audit.tallies.get(HOST_OVERFLOW)
    if overflow is not None:
        print(
            f"note: the camera's FIFO overflowed {overflow.gaps} times with no fault injected "
            "(the host read too slowly): lower --fps on a busy machine"
        )
    if failures:
        print("soak FAILED: " + "; ".join(failures), file=sys.stderr)
        return 1
    print("soak passed: every lost frame is explained, memory growth is within the bound")
    return 0
