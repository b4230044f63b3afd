"""A parameter sweep: the tracker on a family of lines under every setting of a grid, and
what it scores over the family under each (`tofcut sweep`), the tool to tune it with.

Each line is recorded once (one task a seed; `--work` keeps the captures for the next
sweep), then tracked under every setting (one task a line and setting: `tofcut track CAPTURE
--set tracker.PARAM=VALUE ...`, its outputs in `seed-N/sweep/SETTING/`) and scored both ways
as the family evaluation scores (`tofcut.tools.evaluation.family`). A task that fails is run
once more; what still fails is in the table, and makes the exit status 1.
"""

from __future__ import annotations

import argparse
import functools
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from tofcut.sim.truth import load_truth, truth_path
from tofcut.tools.batch.pool import Pool
from tofcut.tools.batch.tasks import Outcome, failure_sections, run_tasks
from tofcut.tools.evaluation.family import (
    AGGREGATE_HEAD,
    Aggregate,
    LineResult,
    Plan,
    TrackerRun,
    aggregate_row,
    failed_exit,
    line_errors,
    line_of,
    plan_from_args,
    run_line,
    run_tracker,
    say,
    table,
    write_report,
)
from tofcut.tools.pipeline.settings import (
    PREFIX,
    Value,
    applied,
    as_arguments,
    grid,
    is_default,
    label,
)
from tofcut.tracker.params import TrackerParams

TRACKER = "tofcut"


@dataclass(frozen=True)
class Job:
    """One line tracked under one setting."""

    seed: int
    setting: int
    """Its index in the grid."""


def track(plan: Plan, settings: list[dict[str, Value]], job: Job) -> TrackerRun:
    """A task: the tracker on a recorded line under one setting, scored both ways."""
    values = settings[job.setting]
    line = plan.folder / f"seed-{job.seed}"
    folder = line / "sweep" / re.sub(r"[^\w.=,-]+", "_", label(values).replace(", ", ","))
    folder.mkdir(parents=True, exist_ok=True)
    capture = line / "capture.tofcap"
    truths = load_truth(truth_path(capture))
    return run_tracker(plan, TRACKER, capture, truths, folder, as_arguments(values))


def _on_retry(what: Callable[[Any], str]) -> Callable[[Any, str], None]:
    """The line said when a task is run once more: `what` names its item."""
    return lambda item, why: say(f"{what(item)} failed ({why}): running it once more")


def sweep(plan: Plan, settings: list[dict[str, Value]], pool: Pool) -> list[list[LineResult]]:
    """For each setting, its lines (in the order of the seeds), each with the tracker's run
    under that setting, or the error that stopped it."""
    recorded = run_tasks(
        functools.partial(run_line, replace(plan, trackers=())), plan.seeds, pool,
        failure=line_errors,
        on_done=lambda o: say(f"seed {o.item} recorded ({line_errors(line_of(plan, o)) or 'ok'})"),
        on_retry=_on_retry(lambda seed: f"recording seed {seed}"),
    )  # fmt: skip
    lines = {o.item: line_of(plan, o) for o in recorded}
    jobs = [Job(seed, i) for i in range(len(settings)) for seed in plan.seeds
            if not lines[seed].errors]  # fmt: skip
    done = 0

    def finished(o: Outcome[Job, TrackerRun]) -> None:
        nonlocal done
        done += 1
        run = o.result
        state = (run.error if run else o.error) or "ok"
        mota = f"MOTA {run.scores.by_centroid.mota:.3f}" if run and run.scores else "-"
        say(f"[{done}/{len(jobs)}] seed {o.item.seed}, {label(settings[o.item.setting])}: "
            f"{mota} ({state})")  # fmt: skip

    tracked = run_tasks(
        functools.partial(track, plan, settings), jobs, pool,
        failure=lambda run: run.error, on_done=finished,
        on_retry=_on_retry(lambda j: f"seed {j.seed}, {label(settings[j.setting])}"),
    )  # fmt: skip
    runs = {(o.item.seed, o.item.setting): o for o in tracked}
    out = []
    for i in range(len(settings)):
        row = []
        for seed in plan.seeds:
            line = lines[seed]
            o = runs.get((seed, i))
            if o is not None:
                run = o.result or TrackerRun(TRACKER, None, o.error)
                line = replace(line, runs=(run,), retried=o.retried or line.retried)
            row.append(line)
        out.append(row)
    return out


def report(
    plan: Plan, settings: list[dict[str, Value]], results: list[list[LineResult]]
) -> tuple[str, dict[str, Any]]:
    """The Markdown and the JSON document of a sweep: a row of scores a setting."""
    aggregates = [Aggregate.of_runs(TRACKER, lines) for lines in results]
    rows = [["setting", *AGGREGATE_HEAD]]
    for values, a in zip(settings, aggregates, strict=True):
        rows.append(aggregate_row(label(values) + (" (defaults)" if is_default(values) else ""), a))
    out = [f"## {TRACKER} on {len(plan.seeds)} lines of emulator:{plan.pattern}, per setting",
           "", *table(rows), "",
           "Each cell: by centroid / by mask IoU; ID switches summed over the lines."]  # fmt: skip
    failed = [(values, r) for values, lines in zip(settings, results, strict=True)
              for r in lines if r.errors]  # fmt: skip
    retried = [(values, r) for values, lines in zip(settings, results, strict=True)
               for r in lines if r.retried]  # fmt: skip
    out += failure_sections(
        [(f"seed {r.seed}, {label(v)}", "; ".join(r.errors)) for v, r in failed],
        [(f"seed {r.seed}, {label(v)}", r.retried or "") for v, r in retried],
    )
    doc = {
        "pattern": plan.pattern, "seeds": list(plan.seeds), "frames": plan.frames,
        "seconds": plan.seconds if plan.frames is None else None, "tracker": TRACKER,
        "gate": plan.gate, "min_pixels": plan.min_pixels, "min_iou": plan.min_iou,
        "settings": [
            {"values": {f"{PREFIX}{k}": v for k, v in values.items()},
             "defaults": is_default(values), "aggregate": a.to_json(),
             "lines": [r.to_json() for r in lines]}
            for values, a, lines in zip(settings, aggregates, results, strict=True)
        ],
        "failed": [{"seed": r.seed, "setting": label(v), "errors": r.errors} for v, r in failed],
        "retried": [{"seed": r.seed, "setting": label(v), "first_error": r.retried}
                    for v, r in retried],
    }  # fmt: skip
    return "\n".join(out) + "\n", doc


def run(args: argparse.Namespace) -> int:
    """`tofcut sweep`: 0 if every line ran under every setting, else 1."""
    settings = grid(args.set)
    for values in settings:
        applied(TrackerParams(), values)  # every setting checked before anything is recorded
    plan = plan_from_args(args, (TRACKER,))
    try:
        with Pool.from_args(args) as pool:
            say(f"sweeping {len(settings)} settings of {', '.join(str(s) for s in args.set)} "
                f"on {len(plan.seeds)} lines of emulator:{plan.pattern}, {pool.where}, "
                f"in {plan.folder}")  # fmt: skip
            results = sweep(plan, settings, pool)
    finally:
        if args.work is None:
            shutil.rmtree(plan.work, ignore_errors=True)
    text, doc = report(plan, settings, results)
    write_report(args, "sweep", text, doc)
    failed = sum(1 for lines in results for r in lines if r.errors)
    return failed_exit(failed, len(settings) * len(plan.seeds), "runs")
