"""A fault drill: every camera fault once, on the emulated camera in real time at 50 fps, read
by the driver as the live pipeline reads it; what each fault cost in frames and in time.

    python -m tofcut.sim.drill          # the table in the README's "Faults survived"

The tests check each fault's accounting exactly on a fake clock; this measures the costs
that only a real clock shows (the backoff, the silence before a reset, a FIFO overflowing
while a read times out).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from tofcut.driver.camera import Camera
from tofcut.sim.device import EmulatedCamera, EmulatedDevice
from tofcut.sim.pattern import TestPattern
from tofcut.sim.usb_backend import EmulatedBackend

Inject = Callable[[EmulatedBackend, EmulatedDevice], None]


def _later(seconds: float, action: Callable[[], object]) -> None:
    timer = threading.Timer(seconds, action)
    timer.daemon = True
    timer.start()


def _unplug_for(seconds: float) -> Inject:
    def inject(bus: EmulatedBackend, emu: EmulatedDevice) -> None:
        bus.unplug(emu)
        _later(seconds, lambda: bus.replug(emu))

    return inject


def _taken_on_return(back_s: float, held_s: float) -> Inject:
    def inject(bus: EmulatedBackend, emu: EmulatedDevice) -> None:
        bus.unplug(emu)

        def back_but_taken() -> None:
            bus.replug(emu)
            bus.hold(emu)
            _later(held_s, lambda: bus.release(emu))

        _later(back_s, back_but_taken)

    return inject


FAULTS: dict[str, Inject] = {
    "unplugged (power lost) for 0.5 s, back at another address": _unplug_for(0.5),
    "unplugged for 0.1 s": _unplug_for(0.1),
    "back after 0.1 s but held by another program for 0.5 s": _taken_on_return(0.1, 0.5),
    "stalled endpoint, between frames": lambda bus, emu: emu.stall_endpoint(),
    "stalled endpoint, mid-frame": lambda bus, emu: emu.stall_endpoint(after_packets=3),
    "endpoint stalling on every read": lambda bus, emu: emu.stall_endpoint(count=1000),
    "one read timed out": lambda bus, emu: emu.time_out_next(1),
    "hung firmware": lambda bus, emu: emu.hang(),
    "a 512-byte packet lost": lambda bus, emu: emu.damage_next("drop-packet"),
    "a 512-byte packet garbled": lambda bus, emu: emu.damage_next("corrupt-packet"),
    "a transfer cut short": lambda bus, emu: emu.damage_next("truncate"),
    "FIFO overflow, 10 frames": lambda bus, emu: emu.overflow_fifo(10),
}


@dataclass(frozen=True)
class DrillResult:
    """What one fault cost."""

    fault: str
    lost: int
    """Frames missing from the run, counted or estimated."""
    estimated: int
    """The part of `lost` estimated from time."""
    damaged: int
    interruption_s: float
    """The longest wait between two delivered frames, less the frame period."""
    events: tuple[str, ...]


def drill(name: str, inject: Inject, *, before: int = 10, after: int = 25) -> DrillResult:
    """Stream `before` frames, inject the fault, and stream until `after` more came."""
    emu = EmulatedCamera(TestPattern(32, 24, seed=1), realtime=True)
    bus = EmulatedBackend([emu])
    arrivals: list[float] = []
    with Camera.open(backend=bus, reconnect=True) as cam:
        period_s = emu.frame_period_us / 1e6
        for _ in cam.raw_frames(count=before + after):
            arrivals.append(time.monotonic())
            if len(arrivals) == before:
                inject(bus, emu)
    waits = [b - a for a, b in itertools.pairwise(arrivals)]
    stats = cam.stats
    return DrillResult(
        fault=name,
        lost=stats.lost,
        estimated=stats.lost_estimated,
        damaged=stats.damaged,
        interruption_s=max(0.0, max(waits) - period_s),
        events=tuple(e.kind.value for e in stats.events),
    )


def run(faults: Sequence[str] | None = None) -> list[DrillResult]:
    """The drill for the named faults (all of `FAULTS` by default), one after another."""
    return [drill(name, FAULTS[name]) for name in faults or list(FAULTS)]


def table(results: Sequence[DrillResult]) -> str:
    """The results as a Markdown table."""
    rows = [
        "| fault | what the driver did | frames lost (estimated) | damaged | stream stopped for |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in results:
        did = ", ".join(dict.fromkeys(r.events)) or "read on"
        rows.append(
            f"| {r.fault} | {did} | {r.lost} ({r.estimated}) | {r.damaged} "
            f"| {r.interruption_s * 1000:.0f} ms |"
        )
    return "\n".join(rows)


if __name__ == "__main__":
    print(table(run()))
