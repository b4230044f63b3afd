"""Evaluating trackers on a family of lines: one bare capture per seed, every tracker, both
matchings, and what each tracker scores over the family.

`tofcut evaluate --family conveyor --seeds 1000-1039` runs, for each seed, the line
`emulator:family:conveyor:SEED`; `--scene PATTERN` names the line itself (`{seed}` in it is
replaced by the seed; without it, every seed renders the same scene). The seed is also the
emulator's noise seed, so `--scene conveyor --seeds 0-3` is the built-in conveyor with four
noise seeds. For each line:

1. record a bare capture from the emulator (`tofcut record SOURCE --bare --fast --seed SEED
   --frames N`: nothing but the camera's stream, and the ground truth beside it), unless
   `--work` already holds a complete one recorded the same way;
2. run each tracker on it as a user would, in its own process: `tofcut track CAPTURE
   --tracks-out ... --masks-out ...`, and `python -m tofcut.tools.evaluation.baseline CAPTURE ...`;
3. score each run both ways (`tofcut.tools.evaluation.scoring`).

Each line is a task (`tofcut.tools.batch`): `--workers` at once on a Ray started here, or
on a Ray cluster (`--ray-address`). A line that fails is run once more; if it fails again it
is reported with its seed and the error, and makes the exit code 1; it is never dropped.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from tofcut.driver.belt import KnownBelt
from tofcut.driver.capture import CaptureReader
from tofcut.driver.errors import TofcutError
from tofcut.sim.device import EmulatedCamera
from tofcut.sim.family import draw_line, parse_family_name
from tofcut.sim.renderer import SceneSource
from tofcut.sim.truth import FrameTruth, load_truth, truth_path
from tofcut.tools.batch.pool import BatchError, Pool, add_batch_options
from tofcut.tools.batch.steps import StepFailed, cli, describe, run_step
from tofcut.tools.batch.tasks import Outcome, failure_sections, run_tasks
from tofcut.tools.evaluation.holding import Holding, holding
from tofcut.tools.evaluation.line_noise import BANDS, band, belt_noise
from tofcut.tools.evaluation.scoring import GATE_M, MIN_IOU, MIN_PIXELS, Scores, evaluate, read_run
from tofcut.tools.evaluation.situations import MIN_STEP_M, Situations, situations
from tofcut.tools.pipeline.sources import SourceError, scene_metadata, scene_source

DEFAULT_SECONDS = 20.0
TRACKERS = ("tofcut", "baseline")


def _tofcut(capture: Path, tracks: Path, masks: Path) -> list[str]:
    """`tofcut track` as a user runs it (its rerun recording thrown away)."""
    return cli("track", str(capture), "--tracks-out", str(tracks), "--masks-out", str(masks),
                "--save", os.devnull)  # fmt: skip


def _baseline(capture: Path, tracks: Path, masks: Path) -> list[str]:
    return [sys.executable, "-m", "tofcut.tools.evaluation.baseline", str(capture),
            "--tracks-out", str(tracks), "--masks-out", str(masks)]  # fmt: skip


COMMANDS: dict[str, Callable[[Path, Path, Path], list[str]]] = {
    "tofcut": _tofcut,
    "baseline": _baseline,
}
"""Each tracker's command line: capture, tracks out, masks out → argv."""


def parse_seeds(text: str) -> tuple[int, ...]:
    """`1000-1039`, `0-3`, `5` or `1,4,7-9`: the seeds in the order given, each once."""
    seeds: list[int] = []
    for part in text.split(","):
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if m is None or (m[2] is not None and int(m[2]) < int(m[1])):
            raise argparse.ArgumentTypeError(f"{text!r} is not seeds: e.g. 1000-1039 or 0,2,5-7")
        seeds.extend(range(int(m[1]), int(m[2] or m[1]) + 1))
    return tuple(dict.fromkeys(seeds))


def parse_trackers(text: str) -> tuple[str, ...]:
    """`tofcut,baseline`: tracker names from `COMMANDS`, each once."""
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    unknown = [n for n in names if n not in COMMANDS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"{text!r}: trackers are a comma-separated choice of {', '.join(COMMANDS)}"
        )
    return names


def add_family_options(
    p: argparse.ArgumentParser, title: str, *, trackers: bool = True, tasks: str = "lines"
) -> None:
    """The options of a family evaluation (`tofcut evaluate --family ... --seeds ...`) in a
    group of that `title`; without `trackers`, no `--trackers` (a sweep runs tofcut's);
    `tasks` says what `--workers` runs at once."""
    g = p.add_argument_group(title)
    which = g.add_mutually_exclusive_group()
    which.add_argument("--family", metavar="NAME", help="the lines emulator:family:NAME:SEED")
    which.add_argument(
        "--scene", metavar="PATTERN",
        help="the lines emulator:PATTERN, {seed} in it replaced by each seed (without it, the "
        "same scene with each noise seed: --scene conveyor --seeds 0-3)",
    )  # fmt: skip
    g.add_argument("--seeds", type=parse_seeds, metavar="A-B", help="e.g. 1000-1039 or 0,2,5-7")
    length = g.add_mutually_exclusive_group()
    length.add_argument(
        "--seconds",
        type=float,
        help=f"length of each line, scene time (default {DEFAULT_SECONDS:g})",
    )
    length.add_argument("--frames", type=int, help="length of each line in frames")
    g.add_argument(
        "--work", type=Path, metavar="DIR",
        help="keep captures and runs here; complete captures recorded the same way are reused "
        "(default: a temporary folder, removed at the end)",
    )  # fmt: skip
    if trackers:
        g.add_argument(
            "--trackers", type=parse_trackers, default=TRACKERS, metavar="NAMES",
            help=f"comma-separated, of {', '.join(COMMANDS)} (default: all)",
        )  # fmt: skip
    add_batch_options(g, tasks)
    g.add_argument("--out", type=Path, metavar="DIR", help="write the tables here, .md and .json")


def wants_family(args: argparse.Namespace) -> bool:
    """Whether the arguments ask for a family evaluation."""
    return args.family is not None or args.scene is not None


@dataclass(frozen=True)
class Plan:
    """What a family evaluation runs: which lines, how long, which trackers, how scored."""

    pattern: str
    """The emulator's scene name of a line, `{seed}` standing for its seed."""
    seeds: tuple[int, ...]
    trackers: tuple[str, ...]
    work: Path
    seconds: float = DEFAULT_SECONDS
    frames: int | None = None
    """Frames of each line; None: `seconds` of scene time at the scene's frame rate."""
    gate: float = GATE_M
    min_pixels: int = MIN_PIXELS
    min_iou: float = MIN_IOU

    def scene(self, seed: int) -> str:
        return self.pattern.replace("{seed}", str(seed))

    def source(self, seed: int) -> str:
        return f"emulator:{self.scene(seed)}"

    @property
    def folder(self) -> Path:
        """Where this pattern's lines are kept in `work`."""
        slug = re.sub(r"[^\w.-]+", "-", self.pattern.replace("{seed}", "")).strip("-.")
        return self.work / (slug or "scene")


@dataclass(frozen=True)
class TrackerRun:
    """One tracker on one line: its scores, or what went wrong."""

    tracker: str
    scores: Scores | None
    error: str | None = None
    seconds: float = 0.0
    """Wall time of the tracker's process."""
    situations: Situations | None = None
    """How it did from the first frame and on touching pairs (`tools.evaluation.situations`)."""
    holding: Holding | None = None
    """How each object-frame was held (`tools.evaluation.holding`)."""

    def to_json(self) -> dict[str, Any]:
        seen, held = self.situations, self.holding
        return {"tracker": self.tracker, "error": self.error, "seconds": round(self.seconds, 2),
                **({"scores": self.scores.to_json()} if self.scores else {}),
                **({"situations": seen.to_json()} if seen else {}),
                **({"holding": held.to_json()} if held else {})}  # fmt: skip


@dataclass(frozen=True)
class LineResult:
    """One line of the family: what it was, and each tracker's run on it."""

    seed: int
    source: str
    scene: str = ""
    """A summary of the line (scene, belt, objects), where known."""
    frames: int = 0
    runs: tuple[TrackerRun, ...] = ()
    error: str | None = None
    """What stopped the line before any tracker ran (recording it, say)."""
    retried: str | None = None
    """What failed the first time the line ran, when it was run once more."""
    belt_noise_m: float | None = None
    """The range noise its belt shows in the first frame (`line_noise.belt_noise`)."""

    @property
    def errors(self) -> list[str]:
        """Everything that went wrong on this line, one line each."""
        own = [self.error] if self.error else []
        return own + [f"{r.tracker}: {r.error}" for r in self.runs if r.error]

    def run(self, tracker: str) -> TrackerRun | None:
        return next((r for r in self.runs if r.tracker == tracker), None)

    def to_json(self) -> dict[str, Any]:
        return {"seed": self.seed, "source": self.source, "scene": self.scene,
                "frames": self.frames, "error": self.error,
                "runs": {r.tracker: r.to_json() for r in self.runs},
                "belt_noise_m": self.belt_noise_m,
                **({"retried": self.retried} if self.retried else {})}  # fmt: skip


def _line_facts(plan: Plan, seed: int) -> tuple[int, str, KnownBelt | None]:
    """The line's length in frames (from the emulated camera's frame rate), its summary and
    its belt (None where the scene has none)."""
    source = scene_source(plan.scene(seed), seed)
    belt = source.belt if isinstance(source, SceneSource) else None
    registers = source.settings.registers if isinstance(source, SceneSource) else None
    period_us = EmulatedCamera(source, realtime=False, registers=registers).frame_period_us
    frames = plan.frames if plan.frames is not None else round(plan.seconds * 1e6 / period_us)
    meta = scene_metadata(source)
    summary = str(meta.get("scene", plan.scene(seed)))
    if "belt" in meta:
        summary += f", belt {meta['belt']['speed_mps']:.2f} m/s"
    return max(1, frames), summary, belt


def _complete(capture: Path, marker: Path, wanted: dict[str, Any]) -> bool:
    """Whether `capture` is whole, has its truth, and was recorded as `wanted` says."""
    try:
        if json.loads(marker.read_text(encoding="utf-8")) != wanted:
            return False
        with np.load(truth_path(capture)) as z:
            truths = int(z["sequence"].size)
        return bool(len(CaptureReader(capture)) == truths == wanted["frames"])
    except (OSError, ValueError, KeyError, TofcutError):
        return False


def record_line(plan: Plan, seed: int, frames: int, folder: Path) -> Path:
    """The line's bare capture in `folder`, recorded now unless a complete one is there.

    It is recorded under another name and renamed when whole, so an interrupted recording
    is never taken for a capture; `capture.json` says how it was recorded.
    """
    capture, marker = folder / "capture.tofcap", folder / "capture.json"
    source = plan.source(seed)
    wanted = {"source": source, "seed": seed, "frames": frames, "bare": True, "fast": True}
    if _complete(capture, marker, wanted):
        return capture
    for p in (marker, capture, truth_path(capture)):
        p.unlink(missing_ok=True)
    part = folder / "capture.part.tofcap"
    run_step(cli("record", source, "-o", str(part), "--frames", str(frames), "--fast",
              "--seed", str(seed), "--bare"), folder / "record.log", "record")  # fmt: skip
    if not truth_path(part).is_file():
        raise StepFailed(f"record wrote no ground truth for {source}")
    truth_path(part).replace(truth_path(capture))
    part.replace(capture)
    marker.write_text(json.dumps(wanted) + "\n", encoding="utf-8")
    return capture


def prepare_line(plan: Plan, seed: int) -> tuple[LineResult, list[FrameTruth]]:
    """Record (or reuse) one line: the line with no runs yet, and its ground truth."""
    folder = plan.folder / f"seed-{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    frames, summary, belt = _line_facts(plan, seed)
    capture = record_line(plan, seed, frames, folder)
    truths = load_truth(truth_path(capture))
    seen = {o.id for t in truths for o in t.objects if o.pixels >= plan.min_pixels}
    noise = belt_noise(capture, truths[0], belt.geometry) if belt and truths else None
    line = LineResult(seed, plan.source(seed), f"{summary}, {len(seen)} objects", frames)
    return replace(line, belt_noise_m=noise), truths


def touching_pairs(plan: Plan, seed: int) -> tuple[tuple[str, str], ...]:
    """The objects of a family line that touch (side by side or nose to tail) with heights
    `MIN_STEP_M` or more apart, by name, from the line's drawing; none for other scenes."""
    family = parse_family_name(plan.scene(seed))
    if family is None:
        return ()
    line = draw_line(*family)
    height = {o.name: o.height_m for o in line.objects}
    return tuple(
        (c.a, c.b) for c in line.contacts()
        if c.kind in ("side", "nose") and abs(height[c.a] - height[c.b]) >= MIN_STEP_M
    )  # fmt: skip


def run_tracker(
    plan: Plan, tracker: str, capture: Path, truths: list[FrameTruth], folder: Path,
    extra: Sequence[str] = (), touching: Sequence[tuple[str, str]] = (),
) -> TrackerRun:  # fmt: skip
    """One tracker on a recorded line, its outputs in `folder` (`extra`: more arguments to
    its command), scored both ways and in the two situations (`touching`: the line's
    touching pairs); what goes wrong is the run's error, not an exception."""
    tracks, masks = folder / f"{tracker}.tracks.jsonl", folder / f"{tracker}.masks.npz"
    start = time.perf_counter()
    try:
        for p in (tracks, masks):
            p.unlink(missing_ok=True)
        argv = [*COMMANDS[tracker](capture, tracks, masks), *extra]
        run_step(argv, folder / f"{tracker}.log", tracker)
        elapsed = time.perf_counter() - start
        files = read_run(capture, tracks, masks, truths)
        scores = evaluate(files.truths, files.tracks, files.masks, files.rays, plan.gate,
                          plan.min_pixels, plan.min_iou)  # fmt: skip
        masks_in_order = [files.masks.get(t.sequence) for t in files.truths]
        seen = situations(files.truths, masks_in_order, touching)
        held = holding(files.truths, masks_in_order)
        return TrackerRun(tracker, scores, seconds=elapsed, situations=seen, holding=held)
    except Exception as exc:
        return TrackerRun(tracker, None, describe(exc), time.perf_counter() - start)


def run_line(plan: Plan, seed: int) -> LineResult:
    """Record (or reuse) one line, run every tracker on it, score each run both ways.

    Whatever goes wrong is the line's error, or one tracker's, never an exception.
    """
    try:
        line, truths = prepare_line(plan, seed)
    except Exception as exc:
        return LineResult(seed, plan.source(seed), error=describe(exc))
    folder = plan.folder / f"seed-{seed}"
    capture = folder / "capture.tofcap"
    touching = touching_pairs(plan, seed)
    runs = tuple(
        run_tracker(plan, t, capture, truths, folder, touching=touching) for t in plan.trackers
    )
    return replace(line, runs=runs)


def line_errors(result: LineResult) -> str | None:
    """A line's errors in one line, or None when all went well."""
    return "; ".join(result.errors) or None


def run_lines(plan: Plan, pool: Pool, say: Callable[[str], None] = print) -> list[LineResult]:
    """Every line of the plan, one task each on the pool; in the order of the seeds. A line
    that fails is run once more, and what failed the first time is kept (`retried`)."""
    done = 0

    def finished(outcome: Outcome[int, LineResult]) -> None:
        nonlocal done
        done += 1
        result = line_of(plan, outcome)
        state = line_errors(result) or "ok"
        scores = ", ".join(
            f"{r.tracker} MOTA {r.scores.by_centroid.mota:.3f}" for r in result.runs if r.scores
        )
        say(f"[{done}/{len(plan.seeds)}] seed {result.seed}: {scores or '-'} ({state})")

    outcomes = run_tasks(
        functools.partial(run_line, plan), plan.seeds, pool, failure=line_errors,
        on_done=finished,
        on_retry=lambda seed, why: say(f"seed {seed} failed ({why}): running it once more"),
    )  # fmt: skip
    return [line_of(plan, o) for o in outcomes]


def line_of(plan: Plan, outcome: Outcome[int, LineResult]) -> LineResult:
    """An outcome as its line: a task that returned nothing failed as a whole."""
    seed = outcome.item
    line = outcome.result or LineResult(seed, plan.source(seed), error=outcome.error)
    return replace(line, retried=outcome.retried)


@dataclass(frozen=True)
class FamilyScore:
    """One tracker's scores by one matching over the lines it ran on."""

    median_mota: float
    median_idf1: float
    p10_mota: float
    """The 10th percentile of the lines' MOTA (linear interpolation): how bad the bad lines are."""
    id_switches: int
    """Summed over the lines."""
    median_hota: float
    median_deta: float
    median_assa: float

    @classmethod
    def of(cls, matchings: Sequence[Any]) -> FamilyScore:
        mota = [m.mota for m in matchings]

        def median(values: Sequence[float]) -> float:
            return float(np.median(values))

        return cls(
            median(mota), median([m.idf1 for m in matchings]),
            float(np.percentile(mota, 10)), sum(m.id_switches for m in matchings),
            median([m.hota.hota for m in matchings]), median([m.hota.deta for m in matchings]),
            median([m.hota.assa for m in matchings]),
        )  # fmt: skip

    def to_json(self) -> dict[str, float | int]:
        return {"median_mota": self.median_mota, "median_idf1": self.median_idf1,
                "p10_mota": self.p10_mota, "id_switches": self.id_switches,
                "median_hota": self.median_hota, "median_deta": self.median_deta,
                "median_assa": self.median_assa}  # fmt: skip


@dataclass(frozen=True)
class Aggregate:
    """One tracker over the family: both matchings and the mean of the lines' mask IoU."""

    tracker: str
    lines: int
    """Lines it was scored on."""
    of: int
    """Lines in the family."""
    by_centroid: FamilyScore | None
    by_iou: FamilyScore | None
    mean_mask_iou: float | None
    situations: Situations | None = None
    """Summed over the lines."""
    holding: Holding | None = None
    """Summed over the lines."""

    @classmethod
    def of_runs(cls, tracker: str, results: Sequence[LineResult]) -> Aggregate:
        runs = [run for r in results if (run := r.run(tracker)) and run.scores]
        seen = [run.situations for run in runs if run.situations]
        held = [run.holding for run in runs if run.holding]
        scores = [run.scores for run in runs if run.scores]
        return replace(
            cls.of_scores(tracker, scores, len(results)),
            situations=sum(seen[1:], seen[0]) if seen else None,
            holding=sum(held[1:], held[0]) if held else None,
        )

    @classmethod
    def of_scores(cls, tracker: str, scores: Sequence[Scores], of: int) -> Aggregate:
        """Over the runs that were scored, of `of` in all."""
        if not scores:
            return cls(tracker, 0, of, None, None, None)
        return cls(
            tracker, len(scores), of,
            FamilyScore.of([s.by_centroid for s in scores]),
            FamilyScore.of([s.by_iou for s in scores]),
            float(np.mean([s.mask_iou for s in scores])),
        )  # fmt: skip

    def to_json(self) -> dict[str, Any]:
        return {
            "tracker": self.tracker, "lines": self.lines, "of": self.of,
            "by_centroid": self.by_centroid.to_json() if self.by_centroid else None,
            "by_iou": self.by_iou.to_json() if self.by_iou else None,
            "mean_mask_iou": self.mean_mask_iou,
            "situations": self.situations.to_json() if self.situations else None,
            "holding": self.holding.to_json() if self.holding else None,
        }  # fmt: skip


def _pair(a: float | None, b: float | None, signed: bool = False) -> str:
    """`centroid / IoU`, three decimals; `—` for a missing number."""
    fmt = "{:+.3f}" if signed else "{:.3f}"
    return " / ".join("—" if x is None else fmt.format(x) for x in (a, b))


FAMILY_COLUMNS = {
    "median MOTA": "median_mota", "median IDF1": "median_idf1", "median HOTA": "median_hota",
    "median DetA": "median_deta", "median AssA": "median_assa",
    "10th-percentile MOTA": "p10_mota",
}  # fmt: skip
"""The family table's columns of scores by both matchings (`FamilyScore`'s fields)."""


def _difference(x: Aggregate, y: Aggregate) -> list[str]:
    """The family table's row of what tracker `x` scores over `y`."""
    row = [f"{x.tracker} − {y.tracker}", ""]
    for field in FAMILY_COLUMNS.values():
        pair = [
            getattr(a, field) - getattr(b, field) if a and b else None
            for a, b in ((x.by_centroid, y.by_centroid), (x.by_iou, y.by_iou))
        ]
        row.append(_pair(pair[0], pair[1], signed=True))
    xi, yi = x.mean_mask_iou, y.mean_mask_iou
    return [*row, "", "—" if xi is None or yi is None else f"{xi - yi:+.3f}"]


AGGREGATE_HEAD = ["lines", *FAMILY_COLUMNS, "ID switches", "mean mask IoU"]
"""The columns of a tracker's scores over a family, after the first (what is scored)."""


def aggregate_row(first: str, a: Aggregate) -> list[str]:
    """A row of `AGGREGATE_HEAD` after `first`: each cell by centroid / by mask IoU."""
    fc, fi = a.by_centroid, a.by_iou
    if fc is None or fi is None or a.mean_mask_iou is None:
        return [first, f"{a.lines} of {a.of}", *["—"] * (len(AGGREGATE_HEAD) - 1)]
    pairs = [_pair(getattr(fc, f), getattr(fi, f)) for f in FAMILY_COLUMNS.values()]
    return [first, f"{a.lines} of {a.of}", *pairs, f"{fc.id_switches} / {fi.id_switches}",
            f"{a.mean_mask_iou:.3f}"]  # fmt: skip


SCORE_HEAD = ["MOTA", "IDF1", "HOTA", "DetA", "AssA", "switches", "mask IoU"]
"""The columns of one run's scores (`score_cells`)."""


def score_cells(s: Scores) -> list[str]:
    """One run's `SCORE_HEAD`: each by centroid / by mask IoU, but the mask IoU."""
    c, i = s.by_centroid, s.by_iou
    return [_pair(c.mota, i.mota), _pair(c.idf1, i.idf1), _pair(c.hota.hota, i.hota.hota),
            _pair(c.hota.deta, i.hota.deta), _pair(c.hota.assa, i.hota.assa),
            f"{c.id_switches} / {i.id_switches}", f"{s.mask_iou:.3f}"]  # fmt: skip


def table(rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table: the first row its head."""
    lines = ["| " + " | ".join(rows[0]) + " |", "| " + " | ".join(["---"] * len(rows[0])) + " |"]
    return lines + ["| " + " | ".join(r) + " |" for r in rows[1:]]


def _share(n: int, of: int) -> str:
    return f"{n} of {of} ({100 * n / of:.0f}%)" if of else "none in these lines"


def situations_section(aggregates: Sequence[Aggregate]) -> list[str]:
    """The table of the two situations (`tools.evaluation.situations`), summed per tracker."""
    rows = [
        [
            "tracker",
            "in view from the first frame: held by frame 10 and kept",
            "touching pairs 4 cm or more apart in height: two tracks 5 frames after whole",
        ]
    ]
    rows += [[a.tracker, _share(s.from_start_held, s.from_start), _share(s.touching_apart,
              s.touching)] for a in aggregates if (s := a.situations)]  # fmt: skip
    if len(rows) == 1:
        return []
    return ["", "## Two situations", "", *table(rows), "",
            "Held: matched by mask IoU >= 0.5. From the first frame: every object in view in "
            "the line's first frame, held by frame 10 and then by that one track wherever it "
            "shows half its largest view, to its leaving. Touching: each passage of a pair "
            "that touches side by side or nose to tail, judged 5 frames after both are wholly "
            "in view (see `tofcut.tools.evaluation.situations`)."]  # fmt: skip


def holding_section(aggregates: Sequence[Aggregate]) -> list[str]:
    """The object-frames by how they were held (`tools.evaluation.holding`), per tracker."""
    rows = [["tracker", "object-frames", "held", "merged", "partly held", "missed"]]
    rows += [[a.tracker, str(h.total)] + [f"{100 * n / h.total:.1f}%" for n in
              (h.held, h.merged, h.partly, h.missed)]
             for a in aggregates if (h := a.holding) and h.total]  # fmt: skip
    if len(rows) == 1:
        return []
    return ["", "## Where the objects are lost", "", *table(rows), "",
            "Each frame of each object in view, once. Held: a track's mask has an IoU >= 0.5 "
            "with it; merged: the track holding most of it has 30% or more of its mask on "
            "other objects; partly held: some of it is in a track's mask, but not enough; "
            "missed: none of it is (see `tofcut.tools.evaluation.holding`)."]  # fmt: skip


def noise_section(trackers: Sequence[str], results: Sequence[LineResult]) -> list[str]:
    """The family's scores split by how loud each line's belt is (`line_noise`)."""
    head = ["belt's range noise", "lines"]
    for t in trackers:
        head += [f"{t} median MOTA", f"{t} median IDF1", f"{t} mean mask IoU"]
    rows = [head]
    for name, _, _ in BANDS:
        lines = [r for r in results if band(r.belt_noise_m) == name]
        if not lines:
            continue
        row = [name, str(len(lines))]
        for t in trackers:
            a = Aggregate.of_runs(t, lines)
            fc, fi = a.by_centroid, a.by_iou
            row += (
                [_pair(fc.median_mota, fi.median_mota), _pair(fc.median_idf1, fi.median_idf1),
                 f"{a.mean_mask_iou:.3f}"]
                if fc and fi and a.mean_mask_iou is not None else ["—"] * 3
            )  # fmt: skip
        rows.append(row)
    if len(rows) == 1:
        return []
    return ["", "## By the belt's range noise", "", *table(rows), "",
            "The median range noise over the pixels that show the bare belt in each line's "
            "first frame, as the tracker estimates it; each cell by centroid / by mask "
            "IoU."]  # fmt: skip


def markdown(plan: Plan, results: Sequence[LineResult], aggregates: Sequence[Aggregate]) -> str:
    """The per-line table, the family table and the failed lines, as Markdown."""
    trackers = plan.trackers
    head = ["seed", "scene", "frames"]
    for t in trackers:
        head += [f"{t} {name}" for name in SCORE_HEAD]
    rows = [head]
    for r in results:
        row = [str(r.seed), r.scene or r.source, str(r.frames or "—")]
        for t in trackers:
            run = r.run(t)
            s = run.scores if run else None
            if s is None:
                row += ["failed" if r.errors else "—", *[""] * (len(SCORE_HEAD) - 1)]
                continue
            row += score_cells(s)
        rows.append(row)
    out = ["## Lines", "", *table(rows), "",
           "MOTA, IDF1, HOTA (its detection and association parts DetA and AssA, by "
           "TrackEval) and ID switches: by centroid / by mask IoU.", "",
           "## Over the family", ""]  # fmt: skip
    fam = [["tracker", *AGGREGATE_HEAD]]
    fam += [aggregate_row(a.tracker, a) for a in aggregates]
    if len(aggregates) >= 2:
        fam.append(_difference(aggregates[0], aggregates[1]))
    out += table(fam)
    out += ["", "Each cell: by centroid / by mask IoU; ID switches summed over the lines."]
    out += situations_section(aggregates)
    out += holding_section(aggregates)
    out += noise_section(trackers, results)
    out += failure_sections(
        [(f"seed {r.seed} ({r.source})", "; ".join(r.errors)) for r in results if r.errors],
        [(f"seed {r.seed}", r.retried) for r in results if r.retried],
    )
    return "\n".join(out) + "\n"


def report(plan: Plan, results: Sequence[LineResult]) -> tuple[str, dict[str, Any]]:
    """The Markdown and the JSON document of a family's results."""
    aggregates = [Aggregate.of_runs(t, results) for t in plan.trackers]
    doc = {
        "pattern": plan.pattern, "seeds": list(plan.seeds), "trackers": list(plan.trackers),
        "frames": plan.frames, "seconds": plan.seconds if plan.frames is None else None,
        "gate": plan.gate, "min_pixels": plan.min_pixels, "min_iou": plan.min_iou,
        "lines": [r.to_json() for r in results],
        "aggregate": [a.to_json() for a in aggregates],
        "failed": [{"seed": r.seed, "source": r.source, "errors": r.errors}
                   for r in results if r.errors],
        **({"retried": [{"seed": r.seed, "first_error": r.retried} for r in results
                        if r.retried]} if any(r.retried for r in results) else {}),
    }  # fmt: skip
    return markdown(plan, results, aggregates), doc


def plan_from_args(args: argparse.Namespace, trackers: tuple[str, ...]) -> Plan:
    """The plan the family options ask for, every value checked; `work` is a new temporary
    folder unless `--work` names one (which a cluster's nodes must all see)."""
    if not args.seeds:
        raise SourceError("--family/--scene needs --seeds, e.g. --seeds 1000-1039")
    if args.frames is not None and args.frames < 1:
        raise SourceError("--frames must be at least 1")
    if args.seconds is not None and args.seconds <= 0:
        raise SourceError("--seconds must be more than 0")
    if not 0.0 < args.min_iou <= 1.0 or args.gate <= 0 or args.min_pixels < 1:
        raise SourceError("--min-iou must be in (0, 1], --gate > 0 and --min-pixels >= 1")
    if args.ray_address is not None and args.work is None:
        raise BatchError("--ray-address needs --work DIR, a folder every node sees at that path")
    pattern = f"family:{args.family}:{{seed}}" if args.family is not None else args.scene
    work = args.work or Path(tempfile.mkdtemp(prefix="tofcut-evaluate-"))
    return Plan(
        pattern, args.seeds, trackers, work,
        seconds=args.seconds if args.seconds is not None else DEFAULT_SECONDS,
        frames=args.frames, gate=args.gate, min_pixels=args.min_pixels, min_iou=args.min_iou,
    )  # fmt: skip


def write_report(args: argparse.Namespace, name: str, text: str, doc: dict[str, Any]) -> None:
    """Print the Markdown; write it and the JSON as `--out`/NAME.md and .json, and the JSON
    to `--json`."""
    print()
    print(text, end="")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / f"{name}.md").write_text(text, encoding="utf-8")
        (args.out / f"{name}.json").write_text(json.dumps(doc, indent=2) + "\n", "utf-8")
        print(f"wrote {args.out / f'{name}.md'} and {args.out / f'{name}.json'}")
    if args.json:
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")


def failed_exit(failed: int, of: int, what: str) -> int:
    """The exit status of a batch: 1, said on stderr, when any of its tasks failed."""
    if failed:
        print(f"tofcut: error: {failed} of {of} {what} failed (see above)", file=sys.stderr)
        return 1
    return 0


def say(text: str) -> None:
    print(text, flush=True)


def run(args: argparse.Namespace) -> int:
    """`tofcut evaluate --family/--scene ... --seeds ...`: 0 if every line ran, else 1."""
    plan = plan_from_args(args, args.trackers)
    try:
        with Pool.from_args(args) as pool:
            say(f"evaluating {', '.join(plan.trackers)} on {len(plan.seeds)} lines of "
                f"emulator:{plan.pattern}, {pool.where}, in {plan.folder}")  # fmt: skip
            results = run_lines(plan, pool, say)
    finally:
        if args.work is None:
            shutil.rmtree(plan.work, ignore_errors=True)
    text, doc = report(plan, results)
    write_report(args, "evaluation", text, doc)
    return failed_exit(sum(1 for r in results if r.errors), len(results), "lines")
