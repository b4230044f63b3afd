"""`tofcut track SOURCE`: track objects in a capture or from a camera (the run is
`tracking.track`, which `tofcut live` shares).

`tofcut track A.tofcap B.tofcap ... --out DIR` tracks many captures as a batch, one task a
capture (`tofcut.tools.batch.captures`), on this machine's cores or a Ray cluster, and
writes a table of what each gave."""

from __future__ import annotations

import argparse
import functools
from pathlib import Path
from typing import Any

from tofcut.tools.batch.captures import Tracked, run_names, track_capture
from tofcut.tools.batch.pool import Pool, add_batch_options
from tofcut.tools.batch.tasks import Outcome, failure_sections, run_tasks
from tofcut.tools.commands.arguments import UsageError, capture_file
from tofcut.tools.commands.options import (
    add_camera_options,
    add_loop_option,
    add_source_argument,
)
from tofcut.tools.commands.tracking import add_tracking_options, track
from tofcut.tools.evaluation.family import failed_exit, say, table, write_report
from tofcut.tools.pipeline.conveyor_line import add_conveyor_options

ONE_RUN_ONLY = ("tracks_out", "mot_out", "mots_out", "masks_out", "target_pixel",
                "target_point", "scene_target", "save", "connect", "serve", "spawn", "stdout",
                "conveyor", "conveyor_emulator", "loop")  # fmt: skip
"""Options of one run, refused for a batch (its outputs are named in --out)."""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("track", help="track objects in a capture or from a camera")
    add_source_argument(p)
    p.add_argument(
        "more", type=capture_file, nargs="*", metavar="CAPTURE",
        help="more captures: all tracked as a batch, each run written to --out DIR",
    )  # fmt: skip
    add_tracking_options(p)
    add_camera_options(p)
    add_loop_option(p)
    add_conveyor_options(p)
    g = p.add_argument_group("a batch of captures (SOURCE and CAPTURE ... all captures)")
    g.add_argument(
        "--out", type=Path, metavar="DIR",
        help="each capture's run here: NAME.tracks.jsonl, NAME.masks.npz, NAME.log; and the "
        "batch's table, track.md and track.json",
    )  # fmt: skip
    g.add_argument("--json", type=Path, metavar="FILE", help="also write the table's JSON here")
    add_batch_options(g, "captures")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not args.more and args.out is None:
        return track(args, live=args.source.kind != "capture")
    return run_batch(args)


def _passed_on(args: argparse.Namespace) -> list[str]:
    """The options every capture's `tofcut track` gets."""
    out = [a for s in args.set for a in ("--set", str(s))]
    if args.frames is not None:
        out += ["--frames", str(args.frames)]
    if args.seconds is not None:
        out += ["--seconds", str(args.seconds)]
    if args.amplitude_threshold:
        out += ["--amplitude-threshold", str(args.amplitude_threshold)]
    return out + [f for f, on in (("--deformable", args.deformable),
                                  ("--keep-going", args.keep_going)) if on]  # fmt: skip


def run_batch(args: argparse.Namespace) -> int:
    """`tofcut track A.tofcap B.tofcap ... --out DIR`: 0 if every capture was tracked."""
    if args.source.kind != "capture" or args.out is None:
        raise UsageError("a batch tracks captures (FILE.tofcap ...) into --out DIR")
    given = [n for n in ONE_RUN_ONLY if getattr(args, n, None)]
    if given:
        raise UsageError(f"--{given[0].replace('_', '-')} is for one run; a batch writes each "
                         "capture's tracks and masks to --out DIR")  # fmt: skip
    captures = [capture_file(str(args.source.arg)), *args.more]
    names = run_names(captures)
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = list(zip(captures, names, strict=True))
    with Pool.from_args(args) as pool:
        say(f"tracking {len(jobs)} captures, {pool.where}, into {args.out}")
        outcomes = run_tasks(
            functools.partial(track_capture, args.out, _passed_on(args)), jobs, pool,
            on_done=lambda o: say(f"{o.item[1]}: {_state(o)}"),
            on_retry=lambda job, why: say(f"{job[1]} failed ({why}): running it once more"),
        )  # fmt: skip
    text, doc = _report(outcomes)
    write_report(args, "track", text, doc)
    return failed_exit(sum(o.failed for o in outcomes), len(outcomes), "captures")


def _state(o: Outcome[tuple[Path, str], Tracked]) -> str:
    if o.result is None:
        return f"failed: {o.error}"
    r = o.result
    return f"{r.frames} frames, {r.tracks} tracks, {r.seconds:.1f} s"


def _report(outcomes: list[Outcome[tuple[Path, str], Tracked]]) -> tuple[str, dict[str, Any]]:
    rows = [["capture", "frames", "tracks", "seconds", "state"]]
    for o in outcomes:
        r = o.result
        cells = [str(r.frames), str(r.tracks), f"{r.seconds:.1f}"] if r else ["—", "—", "—"]
        state = "failed" if r is None else "ok, run twice" if o.retried else "ok"
        rows.append([str(o.item[0]), *cells, state])
    out = ["## Captures tracked", "", *table(rows)]
    out += failure_sections(
        [(str(o.item[0]), o.error) for o in outcomes if o.error],
        [(str(o.item[0]), o.retried) for o in outcomes if o.retried],
    )
    doc = {"captures": [{**(o.result.to_json() if o.result else {"capture": str(o.item[0])}),
                         "name": o.item[1], "error": o.error, "retried": o.retried}
                        for o in outcomes]}  # fmt: skip
    return "\n".join(out) + "\n", doc
