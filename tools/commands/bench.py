"""`tofcut bench [--quick] [--out DIR] [--stages ...]`: every stage timed against its naive
form and its peers, one process per stage pinned to one core; writes bench.json, README.md
(the tables) and scaling.png into DIR."""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from tofcut.tools.bench.plot import draw_scaling
from tofcut.tools.bench.report import fits, markdown, targets, to_json
from tofcut.tools.bench.runner import STAGES, bench_cpu, run_stage
from tofcut.tools.experiments.grabcut import INSTALL_HINT, have_opencv

DEFAULT_OUT = Path("tofcut-bench")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "bench",
        help="measure every stage on one core, against its naive form and its peers",
        description="Time demodulation, segmentation (against the full-frame cut and OpenCV's "
        "grabCut), the tracker with 1-20 objects, the live pipeline with rerun output and the "
        "emulator, each in its own process pinned to one core, and tofcut live with 1, 2, 4 "
        "and 8 emulated cameras on the whole machine; report the targets (PASS / "
        "MISS) and how each cost grows with objects and pixels. Exit status 1 when a stage "
        "failed to run; a MISS is a measurement, reported, not a failure of the command. "
        "--quick is a smoke run: it checks that every stage runs and reports, and its "
        "timings are too short to judge a target by (its MISS lines say so).",
    )
    p.add_argument(
        "--quick", action="store_true",
        help="a smoke run of a few seconds: checks that every stage works; its PASS / MISS "
        "are not a measurement and never fail it",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"folder ({DEFAULT_OUT})")
    p.add_argument(
        "--stages", nargs="+", choices=list(STAGES), default=list(STAGES), metavar="STAGE",
        help=f"stages to run (all): {', '.join(STAGES)}",
    )  # fmt: skip
    p.set_defaults(func=run)


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    if "segment" in args.stages and not have_opencv():
        print(f"note: {INSTALL_HINT}; the segmentation stage runs without it")
    cpu = bench_cpu()
    results: dict[str, Any] = {}
    errors: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="tofcut-bench-") as tmp:
        for name in args.stages:
            print(f"bench: {name} ...", end=" ", flush=True)
            stage = run_stage(name, args.quick, Path(tmp) / f"{name}.json", cpu)
            if stage.result is None:
                errors[name] = stage.error
                print(f"FAILED ({stage.seconds:.1f} s)\n{stage.error}")
            else:
                results[name] = stage.result
                print(f"{stage.seconds:.1f} s")
    meta = {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "quick": bool(args.quick),
        "stages": list(args.stages),
        "pinned_cpu": cpu,
        "cpus": len(os.sched_getaffinity(0)) if cpu is not None else None,
        "cpu_model": _cpu_model(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "errors": errors,
    }
    (out / "bench.json").write_text(json.dumps(to_json(results, meta), indent=1) + "\n")
    (out / "README.md").write_text(markdown(results, meta, errors), encoding="utf-8")
    draw_scaling(fits(results), out / "scaling.png")
    verdicts = targets(results)
    for t in verdicts:
        print(f"{t.verdict:>12}  {t.what}: {t.measured} (goal {t.goal})")
    misses = sum(t.verdict == "MISS" for t in verdicts)
    if args.quick:
        print(
            f"bench --quick is a smoke run: its timings are too short to judge a target, so "
            f"its {misses} MISS do not fail it (exit status 1 only if a stage failed); run "
            "'tofcut bench' without --quick to measure"
        )
    elif misses:
        print(
            f"{misses} targets MISSED (reported, not an error: exit status 0 unless a stage failed)"
        )
    print(f"wrote {out / 'README.md'}, {out / 'bench.json'} and {out / 'scaling.png'}")
    return 1 if errors else 0
