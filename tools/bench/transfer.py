"""What it costs to hand a frame's bytes from the emulator's process to the driver's: a pipe
(a socket pair, what `tofcut.sim.process` uses) against a shared-memory ring (a memfd both
map).

    python -m tofcut.tools.bench.transfer      # the table in docs/benchmarks.md

Each way runs the proxy's pattern: the parent asks for one bulk read (a small message), the
child answers with a short header and the frame's bytes (the conveyor's 202,816), and the
parent lands them in the driver's buffer. Reported: the parent's CPU time and wall time per
frame (the parent is the process that must keep up), and the child's CPU time per frame.
"""

from __future__ import annotations

import mmap
import os
import resource
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection

FRAME_BYTES = 64 + 4 * 176 * 144 * 2
"""A 176×144 frame on the wire: header and four taps of 16 bits."""
RING_SLOTS = 4


@dataclass(frozen=True)
class TransferCost:
    """One way of handing frames over, per frame."""

    way: str
    parent_cpu_us: float
    parent_wall_us: float
    child_cpu_us: float


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _child(fd: int, way: str, ring_fd: int) -> None:
    """The emulator's side: answer each request with a frame, until the parent hangs up."""
    conn = Connection(fd)
    frame = bytes(range(256)) * (FRAME_BYTES // 256) + bytes(FRAME_BYTES % 256)
    shm = mmap.mmap(ring_fd, RING_SLOTS * FRAME_BYTES) if way == "shm" else None
    slot = 0
    start = _cpu_s()
    while True:
        try:
            size = conn.recv()
        except EOFError:
            break
        if size is None:
            conn.send(_cpu_s() - start)
            break
        if shm is None:
            conn.send(("ok", len(frame)))
            conn.send_bytes(frame)
        else:
            at = slot * FRAME_BYTES
            shm[at : at + len(frame)] = frame
            conn.send(("ok", slot, len(frame)))
            slot = (slot + 1) % RING_SLOTS
    if shm is not None:
        shm.close()


def measure(way: str, frames: int = 500) -> TransferCost:
    """Hand `frames` frames over `way` ('pipe' or 'shm') and time it."""
    ours, theirs = socket.socketpair()
    ring_fd = os.memfd_create("tofcut-ring")
    os.ftruncate(ring_fd, RING_SLOTS * FRAME_BYTES)
    shm = mmap.mmap(ring_fd, RING_SLOTS * FRAME_BYTES) if way == "shm" else None
    code = (
        "from tofcut.tools.bench.transfer import _child; "
        f"_child({theirs.fileno()}, {way!r}, {ring_fd})"
    )
    child = subprocess.Popen([sys.executable, "-c", code], pass_fds=[theirs.fileno(), ring_fd])
    theirs.close()
    os.close(ring_fd)
    conn = Connection(ours.detach())
    buffer = bytearray(-(-FRAME_BYTES // 512) * 512)
    view = memoryview(buffer)
    try:
        conn.send(len(buffer))  # one round trip before the clock starts: the child is up
        _land(conn, view, shm)
        cpu0, wall0 = _cpu_s(), time.perf_counter()
        for _ in range(frames):
            conn.send(len(buffer))
            _land(conn, view, shm)
        cpu, wall = _cpu_s() - cpu0, time.perf_counter() - wall0
        conn.send(None)
        child_cpu = float(conn.recv())
    finally:
        conn.close()
        child.wait()
        if shm is not None:
            shm.close()
    per = 1e6 / frames
    return TransferCost(way, cpu * per, wall * per, child_cpu * 1e6 / (frames + 1))


def _land(conn: Connection, view: memoryview, shm: mmap.mmap | None) -> None:
    header = conn.recv()
    if shm is None:
        conn.recv_bytes_into(view)
    else:
        _, slot, n = header
        at = slot * FRAME_BYTES
        view[:n] = memoryview(shm)[at : at + n]


def table(costs: list[TransferCost]) -> str:
    """The costs as a Markdown table."""
    rows = [
        "| way | parent CPU / frame | parent wall / frame | child CPU / frame |",
        "| --- | --- | --- | --- |",
    ]
    for c in costs:
        rows.append(
            f"| {c.way} | {c.parent_cpu_us:.0f} µs | {c.parent_wall_us:.0f} µs "
            f"| {c.child_cpu_us:.0f} µs |"
        )
    return "\n".join(rows)


if __name__ == "__main__":
    print(table([measure(way) for way in ("pipe", "shm", "pipe", "shm")]))
