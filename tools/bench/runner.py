"""Running `tofcut bench` stages: each in a fresh Python process of its own, pinned to one
core, with every numeric library held to one thread, so no stage warms or slows another and
the numbers are one core's. `python -m tofcut.tools.bench.runner STAGE OUT.json [--quick]
[--cpu N]` is what the parent runs for each stage.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

STAGES = {
    "demod": "tofcut.tools.bench.demod",
    "segment": "tofcut.tools.bench.segment",
    "tracker": "tofcut.tools.bench.tracker",
    "live": "tofcut.tools.bench.live",
    "rerun": "tofcut.tools.bench.rerun_logging",
    "render": "tofcut.tools.bench.render",
    "cameras": "tofcut.tools.bench.cameras",
}
"""Stage name → module with `run(quick: bool) -> dict` (JSON-able)."""
WHOLE_MACHINE = frozenset({"cameras"})
"""Stages that measure the whole machine (several processes at once): not pinned."""

ONE_THREAD = {
    name: "1"
    for name in (
        "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
        "VECLIB_MAXIMUM_THREADS", "RAYON_NUM_THREADS",
    )
}  # fmt: skip


@dataclass(frozen=True)
class StageRun:
    """What one stage's process gave back."""

    name: str
    result: dict[str, Any] | None
    """The stage's measurements, or None if it failed."""
    seconds: float
    error: str = ""


def bench_cpu() -> int | None:
    """The core stages are pinned to (the last this process may use), or None if pinning is
    not available here."""
    if not hasattr(os, "sched_getaffinity"):
        return None
    return max(os.sched_getaffinity(0))


def run_stage(name: str, quick: bool, out: Path, cpu: int | None) -> StageRun:
    """Run one stage in its own process; its JSON goes to `out`."""
    if name not in STAGES:
        raise ValueError(f"no bench stage {name!r}; the stages are {', '.join(STAGES)}")
    cmd = [sys.executable, "-m", "tofcut.tools.bench.runner", name, str(out)]
    if quick:
        cmd.append("--quick")
    if cpu is not None and name not in WHOLE_MACHINE:
        cmd += ["--cpu", str(cpu)]
    start = time.perf_counter()
    proc = subprocess.run(
        cmd, env={**os.environ, **ONE_THREAD}, capture_output=True, text=True, check=False
    )
    seconds = time.perf_counter() - start
    if proc.returncode != 0 or not out.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-5:]
        return StageRun(name, None, seconds, "\n".join(tail) or f"exit {proc.returncode}")
    return StageRun(name, json.loads(out.read_text(encoding="utf-8")), seconds)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tofcut.tools.bench.runner")
    p.add_argument("stage", choices=sorted(STAGES))
    p.add_argument("out", type=Path)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--cpu", type=int)
    args = p.parse_args(argv)
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    result = importlib.import_module(STAGES[args.stage]).run(args.quick)
    args.out.write_text(json.dumps(result, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
