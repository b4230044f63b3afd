"""Bench stage "cameras per box": `tofcut live` with N emulated cameras at once (N = 1, 2, 4,
8), as a user runs it, each camera's worker tracking a crowd of 10 boxes at 50 fps and
saving its rerun recording to a file; the frames each camera lost and the CPU each spent per
frame.

The cameras' own work is not the box's: the crowd is recorded once before the runs, and
each emulated camera, in a process of its own, replays that capture round and round
(`tofcut live emulator:crowd.tofcap --loop`), so in the run it only does what a camera's
firmware does. The CPU per camera-frame is the worker's (parse, demodulate, track, log to
rerun, write the file: every thread of its process) from the moment the cameras start
together to the end of its outputs (the median over the cameras). Unlike the other stages
this one is not pinned to one core: it measures the whole machine, as the cameras share it,
and so whatever else runs on it too; each run also gives the cores other programs used
meanwhile (`/proc/stat`'s busy time less the run's).
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tofcut.driver.toml_writer import dumps
from tofcut.sim.crowd import crowd_doc

OBJECTS = 10
CAMERAS = (1, 2, 4, 8)
SECONDS = 10.0
RECORDED = 100
"""Frames of the crowd recorded before the runs, which each camera replays (2 s at 50 fps)."""
REPEATS = 3


def _busy_s() -> float | None:
    """CPU time every core of the machine has spent busy since boot (`/proc/stat`), or None
    where there is no such file."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    except OSError:
        return None
    ticks = [int(f) for f in fields]
    idle = ticks[3] + ticks[4]  # idle, iowait
    return (sum(ticks[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def _children_cpu_s() -> float:
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def _tofcut(*argv: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "tofcut.tools.cli", "-q", *argv]
    proc = subprocess.run(command, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"tofcut {' '.join(argv[:3])} ...: exit {proc.returncode}: {tail}")
    return proc


def record_crowd(folder: Path) -> Path:
    """A capture of the crowd, `RECORDED` frames at its 50 fps (on the emulator's clock)."""
    scene = folder / f"crowd-{OBJECTS}.toml"
    scene.write_text(dumps(crowd_doc(OBJECTS)), encoding="utf-8")
    capture = folder / "crowd.tofcap"
    _tofcut("record", f"emulator:{scene}", "-o", str(capture), "--frames", str(RECORDED),
            "--fast")  # fmt: skip
    return capture


def run_box(cameras: int, seconds: float, capture: Path, folder: Path) -> dict[str, Any]:
    """One `tofcut live` with `cameras` emulated cameras replaying `capture` for `seconds`."""
    summary = folder / f"summary-{cameras}.json"
    argv = [
        "live", *[f"emulator:{capture}"] * cameras, "--loop", "--seconds", str(seconds),
        "--save", str(folder / f"run-{cameras}.rrd"), "--rerun-per-camera", "file",
        "--restarts", "0", "--summary-json", str(summary),
    ]  # fmt: skip
    busy0, own0, wall0 = _busy_s(), _children_cpu_s(), time.perf_counter()
    _tofcut(*argv)
    busy1, own1, wall = _busy_s(), _children_cpu_s(), time.perf_counter() - wall0
    each = json.loads(summary.read_text(encoding="utf-8"))["cameras"]
    frames = sum(c["frames"] for c in each)
    for rrd in folder.glob(f"run-{cameras}-*.rrd"):
        rrd.unlink()
    lost = sum(c["lost"] for c in each)
    return {
        "cameras": cameras,
        "frames": frames,
        "lost": lost,
        "lost_share": lost / max(frames + lost, 1),
        "lost_most": max(c["lost"] for c in each),
        "cpu_ms_per_camera_frame": statistics.median(
            c["cpu_ms_per_frame"] for c in each if c["cpu_ms_per_frame"] is not None
        ),
        # other programs' share of the machine over the command (start-up included), cores
        "others_cores": None if busy0 is None or busy1 is None
        else max(0.0, (busy1 - busy0) - (own1 - own0)) / wall,
    }  # fmt: skip


def run(quick: bool) -> dict[str, Any]:
    counts, seconds, repeats = ((2,), 1.0, 1) if quick else (CAMERAS, SECONDS, REPEATS)
    with tempfile.TemporaryDirectory(prefix="tofcut-bench-cameras-") as tmp:
        folder = Path(tmp)
        capture = record_crowd(folder)
        runs = [run_box(n, seconds, capture, folder) for _ in range(repeats) for n in counts]
    keys = ("frames", "lost", "lost_share", "lost_most", "cpu_ms_per_camera_frame")
    rows = []
    for n in counts:
        mine = [r for r in runs if r["cameras"] == n]
        row = {key: statistics.median(r[key] for r in mine) for key in keys}
        each = {key: [r[key] for r in mine] for key in ("lost", "others_cores")}
        rows.append({"cameras": n, "runs": len(mine), **row, "lost_each_run": each["lost"],
                     "others_cores_each_run": each["others_cores"]})  # fmt: skip
    return {
        "objects": OBJECTS,
        "fps": 50,
        "seconds": seconds,
        "recorded_frames": RECORDED,
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "load_average": os.getloadavg()[0],
        "rows": rows,
    }
