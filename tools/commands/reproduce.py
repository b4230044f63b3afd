"""`tofcut reproduce`: the paper's segmentation experiments, written up as a report."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add the `reproduce` subcommand."""
    parser = subparsers.add_parser(
        "reproduce",
        help="run the paper's segmentation experiments on the emulator and write a report",
        description="Run Figures 1, 4 and 5 of Arif et al. on the emulator's built-in scenes "
        "(each where its premise holds and on the hard scene) with every energy, "
        "the support energy and OpenCV's grabCut, score the masks against ground truth, and "
        "write report.md with PNG panels.",
    )
    parser.add_argument(
        "--out", type=Path, default=Path("reproduce"), help="report folder (./reproduce)"
    )
    parser.add_argument("--seeds", type=int, default=3, help="noise seeds per scene, from 0 (3)")
    parser.add_argument(
        "--no-sweep", action="store_true", help="leave out the parameter sensitivity tables"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the experiments, print each claim's verdict, write the report."""
    from tofcut.driver.errors import ConfigError
    from tofcut.tools.experiments.reproduce import run_figures, write_report

    if args.seeds < 1:
        raise ConfigError(f"--seeds must be at least 1, not {args.seeds}")
    seeds = list(range(args.seeds))
    figures = run_figures(seeds, sweep=not args.no_sweep)
    path = write_report(args.out, figures, seeds)
    for fig in figures:
        for v in fig.verdicts:
            print(f"{'supported    ' if v.supported else 'NOT supported'}  {v.claim}")
    print(f"report: {path}")
    return 0
