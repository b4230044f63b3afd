"""Many runs scored as one batch: `tofcut evaluate A.tofcap B.tofcap ... --runs DIR`, one
task a capture, its run (`DIR/NAME.tracks.jsonl`, `DIR/NAME.masks.npz`, as `tofcut track
A.tofcap B.tofcap ... --out DIR` writes them) scored both ways against its emulator truth;
a table of every run and of all of them together."""

from __future__ import annotations

import argparse
import functools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tofcut.tools.batch.captures import run_files, run_names
from tofcut.tools.batch.pool import Pool
from tofcut.tools.batch.tasks import Outcome, failure_sections, run_tasks
from tofcut.tools.evaluation.family import (
    AGGREGATE_HEAD,
    SCORE_HEAD,
    Aggregate,
    aggregate_row,
    failed_exit,
    say,
    score_cells,
    table,
    write_report,
)
from tofcut.tools.evaluation.scoring import Scores, evaluate, read_run

Job = tuple[Path, str]
"""A capture and its run's name."""


def score_run(runs: Path, gate: float, min_pixels: int, min_iou: float, job: Job) -> Scores:
    """A task: one capture's run in `runs`, scored both ways."""
    capture, name = job
    tracks, masks = run_files(runs, name)
    f = read_run(capture, tracks, masks)
    return evaluate(f.truths, f.tracks, f.masks, f.rays, gate, min_pixels, min_iou)


def report(outcomes: Sequence[Outcome[Job, Scores]]) -> tuple[str, dict[str, Any]]:
    """The Markdown and JSON of a batch of runs: a row a run, and all of them."""
    rows = [["capture", "frames", *SCORE_HEAD]]
    for o in outcomes:
        s = o.result
        cells = [str(s.frames), *score_cells(s)] if s else ["failed", *[""] * len(SCORE_HEAD)]
        rows.append([str(o.item[0]), *cells])
    scored = [o.result for o in outcomes if o.result is not None]
    total = Aggregate.of_scores("runs", scored, len(outcomes))
    out = ["## Runs", "", *table(rows), "",
           "MOTA, IDF1, HOTA, DetA, AssA and ID switches: by centroid / by mask IoU.", "",
           "## All runs", "", *table([["", *AGGREGATE_HEAD], aggregate_row("all", total)]), "",
           "Each cell: by centroid / by mask IoU; ID switches summed over the runs."]  # fmt: skip
    out += failure_sections(
        [(str(o.item[0]), o.error) for o in outcomes if o.error],
        [(str(o.item[0]), o.retried) for o in outcomes if o.retried],
    )
    doc = {
        "runs": [{"capture": str(o.item[0]), "name": o.item[1], "error": o.error,
                  "retried": o.retried, **({"scores": o.result.to_json()} if o.result else {})}
                 for o in outcomes],
        "aggregate": total.to_json(),
    }  # fmt: skip
    return "\n".join(out) + "\n", doc


def run(args: argparse.Namespace, captures: list[Path]) -> int:
    """`tofcut evaluate A.tofcap ... --runs DIR`: 0 if every run was scored, else 1."""
    names = run_names(captures)
    jobs = list(zip(captures, names, strict=True))
    score = functools.partial(score_run, args.runs, args.gate, args.min_pixels, args.min_iou)
    with Pool.from_args(args) as pool:
        say(f"scoring {len(jobs)} runs in {args.runs}, {pool.where}")
        outcomes = run_tasks(
            score, jobs, pool,
            on_done=lambda o: say(f"{o.item[1]}: " + (
                f"MOTA {o.result.by_centroid.mota:.3f}" if o.result else f"failed: {o.error}")),
            on_retry=lambda job, why: say(f"{job[1]} failed ({why}): scoring it once more"),
        )  # fmt: skip
    text, doc = report(outcomes)
    write_report(args, "evaluation", text, doc)
    return failed_exit(sum(o.failed for o in outcomes), len(outcomes), "runs")
