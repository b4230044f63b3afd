"""`tofcut evaluate`: score a run against ground truth (the emulator's, or MOTChallenge or
MOTS rows), or a family of lines.

`tofcut evaluate CAPTURE --tracks T.jsonl --masks M.npz` scores one run. The truth is the
emulator's (`CAPTURE.truth.npz`, written by `tofcut record emulator:...`). Tracks are
matched to objects two ways, by 3D centroid within `--gate` and by mask IoU of at least
`--min-iou`, each scored for MOTA, IDF1 and ID switches; and the mask IoU of every scored
object-frame is averaged (`tofcut.tools.evaluation.scoring` says exactly what counts). The
first line printed is the centroid matching's, as it always was; the second adds the IoU
matching's; the third gives both matchings' HOTA, DetA and AssA
(`tofcut.tools.evaluation.hota`).

`tofcut evaluate --truth GT.txt --tracks T.jsonl` (MOTChallenge truth, by 3D centroid) or
`--truth GT.txt --masks M.npz` (MOTS truth, by mask IoU) scores a run against ground truth
from elsewhere (`tofcut.tools.evaluation.evaluate_files`).

`--per-object` adds, for every object, the view from its masks alone (no gate): in how many
of its frames a track held most of it, which tracks those were, and its mean mask IoU with
that track over all its frames (0 where none held it): "kept one id in every frame".

`tofcut evaluate --family NAME --seeds A-B` (or `--scene PATTERN --seeds A-B`) records,
tracks and scores a line per seed (`tofcut.tools.evaluation.family`): what a tracker does on
lines it was not tuned on, beside a baseline.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from tofcut.tools.commands.arguments import (
    UsageError,
    capture_file,
    existing_file,
    existing_folder,
    output_file,
)
from tofcut.tools.evaluation import evaluate_files, family, runs
from tofcut.tools.evaluation.run_scores import per_object
from tofcut.tools.evaluation.scoring import GATE_M, MIN_IOU, MIN_PIXELS, evaluate, read_run
from tofcut.tools.pipeline.mot import read_mot
from tofcut.tools.pipeline.mots import read_mots
from tofcut.tools.pipeline.sources import SourceError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "evaluate", help="score tracks and masks against emulator ground truth (or a family)"
    )
    p.add_argument("capture", type=capture_file, nargs="?", metavar="CAPTURE.tofcap")
    p.add_argument(
        "more", type=capture_file, nargs="*", metavar="CAPTURE",
        help="more captures: with --runs DIR, each one's run there is scored, as a batch",
    )  # fmt: skip
    p.add_argument(
        "--runs", type=existing_folder, metavar="DIR",
        help="the captures' runs, NAME.tracks.jsonl and NAME.masks.npz (as tofcut track "
        "CAPTURE ... --out DIR writes them): all scored, one task a capture",
    )  # fmt: skip
    p.add_argument(
        "--tracks", type=existing_file, metavar="FILE.jsonl",
        help="the run's --tracks-out (with --truth also its --mot-out)",
    )  # fmt: skip
    p.add_argument(
        "--masks", type=existing_file, metavar="FILE.npz",
        help="the run's --masks-out (with --truth also its --mots-out)",
    )  # fmt: skip
    p.add_argument(
        "--truth", type=existing_file, metavar="GT.txt",
        help="ground truth as MOTChallenge rows (matched to --tracks by 3D centroid) or MOTS "
        "lines (matched to --masks by mask IoU), instead of CAPTURE's emulator truth",
    )  # fmt: skip
    p.add_argument("--gate", type=float, default=GATE_M, help="match distance, metres (0.1)")
    p.add_argument("--min-pixels", type=int, default=MIN_PIXELS, help="smallest object scored (50)")
    p.add_argument(
        "--min-iou", type=float, default=MIN_IOU, help="smallest mask IoU that matches (0.5)"
    )
    p.add_argument("--per-object", action="store_true", help="also a line per object (masks)")
    p.add_argument("--json", type=output_file, help="also write every number here")
    family.add_family_options(
        p, "a family of lines (instead of CAPTURE --tracks --masks)", tasks="lines (or runs)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if family.wants_family(args):
        if args.capture or args.more or args.runs or args.tracks or args.masks or args.truth:
            raise SourceError("give either CAPTURE --tracks --masks, or --family/--scene, not both")
        return family.run(args)
    if args.runs is not None or args.more:
        if args.capture is None or args.runs is None or args.tracks or args.masks or args.truth:
            raise UsageError("a batch of runs is CAPTURE [CAPTURE ...] --runs DIR (no --tracks, "
                             "--masks or --truth: each capture's run is found in DIR)")  # fmt: skip
        if not 0.0 < args.min_iou <= 1.0 or args.gate <= 0 or args.min_pixels < 1:
            raise SourceError("--min-iou must be in (0, 1], --gate > 0 and --min-pixels >= 1")
        return runs.run(args, [args.capture, *args.more])
    if args.truth is not None:
        return _against_file(args)
    if args.capture is None or args.tracks is None or args.masks is None:
        raise SourceError(
            "evaluate needs CAPTURE --tracks FILE.jsonl --masks FILE.npz "
            "(or --truth GT.txt with --tracks or --masks, or --family NAME / --scene NAME "
            "with --seeds)"
        )
    if not 0.0 < args.min_iou <= 1.0 or args.gate <= 0 or args.min_pixels < 1:
        raise SourceError("--min-iou must be in (0, 1], --gate > 0 and --min-pixels >= 1")
    files = read_run(args.capture, args.tracks, args.masks)
    scores = evaluate(files.truths, files.tracks, files.masks, files.rays, args.gate,
                      args.min_pixels, args.min_iou)  # fmt: skip
    c, i = scores.by_centroid, scores.by_iou
    print(
        f"{scores.frames} frames, {c.objects} object-frames: "
        f"MOTA {c.mota:.3f}  IDF1 {c.idf1:.3f}  "
        f"ID switches {c.id_switches}  mean mask IoU {scores.matched_iou:.3f}  "
        f"(misses {c.misses}, false positives {c.false_positives})"
    )
    print(
        f"by mask IoU >= {args.min_iou:g}: MOTA {i.mota:.3f}  IDF1 {i.idf1:.3f}  "
        f"ID switches {i.id_switches}  (misses {i.misses}, false positives "
        f"{i.false_positives}); mask IoU of every object-frame {scores.mask_iou:.3f}"
    )
    hc, hi = c.hota, i.hota
    print(
        f"HOTA by centroid {hc.hota:.3f} (DetA {hc.deta:.3f}, AssA {hc.assa:.3f}); "
        f"by mask IoU {hi.hota:.3f} (DetA {hi.deta:.3f}, AssA {hi.assa:.3f})"
    )
    objects: list[dict[str, Any]] = []
    if args.per_object:
        objects = per_object(files.truths, files.masks, args.min_pixels)
        for o in objects:
            print(
                f"  {o['name']}: held by a track in {o['held']} of {o['frames']} frames, "
                f"ids {o['track_ids']}, mean mask IoU {o['iou']:.3f}"
            )
    if args.json:
        doc: dict[str, Any] = {
            **scores.to_json(), "gate": args.gate, "min_pixels": args.min_pixels,
            "min_iou": args.min_iou, **({"per_object": objects} if args.per_object else {}),
        }  # fmt: skip
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0


def _against_file(args: argparse.Namespace) -> int:
    """`tofcut evaluate --truth FILE (--tracks FILE | --masks FILE)`: print the scores."""
    if args.capture is not None or args.per_object:
        raise UsageError("--truth scores the run against that file: give no CAPTURE and no "
                          "--per-object (those are for the emulator's own truth)")  # fmt: skip
    if not 0.0 < args.min_iou <= 1.0 or args.gate <= 0:
        raise UsageError("--min-iou must be in (0, 1] and --gate > 0")
    kind = evaluate_files.truth_format(args.truth)
    if kind == evaluate_files.MOT:
        if args.tracks is None:
            raise UsageError(
                f"{args.truth} is MOTChallenge rows, matched by 3D centroid: give the run's "
                "tracks, --tracks FILE.jsonl (or its --mot-out)"
            )
        truth_rows = read_mot(args.truth)
        positions = evaluate_files.track_positions(args.tracks)
        scores = evaluate_files.score_centroids(args.truth, truth_rows, positions, args.gate)
        how = f"by 3D centroid within {args.gate:g} m"
    else:
        if args.masks is None:
            raise UsageError(f"{args.truth} is MOTS lines, matched by mask IoU: give the run's "
                              "masks, --masks FILE.npz (or its --mots-out)")  # fmt: skip
        truth = read_mots(args.truth)
        masks, size = evaluate_files.track_masks(args.masks)
        if truth and size is not None and size != (truth[0].height, truth[0].width):
            raise SourceError(f"{args.masks}: masks of {size[0]}x{size[1]} (height x width), "
                              f"the truth's are {truth[0].height}x{truth[0].width}")  # fmt: skip
        scores = evaluate_files.score_masks(args.truth, truth, masks, args.min_iou)
        how = f"by mask IoU >= {args.min_iou:g}"
    m = scores.matching
    print(f"{args.truth} ({kind}): {scores.frames} frames, {m.objects} object-frames, "
          f"matched {how}")  # fmt: skip
    print(
        f"MOTA {m.mota:.3f}  IDF1 {m.idf1:.3f}  HOTA {m.hota.hota:.3f} (DetA {m.hota.deta:.3f}, "
        f"AssA {m.hota.assa:.3f})  ID switches {m.id_switches}  (misses {m.misses}, "
        f"false positives {m.false_positives})"
    )
    if args.json:
        doc = {"truth": str(args.truth), **scores.to_json(), "gate": args.gate,
               "min_iou": args.min_iou}  # fmt: skip
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0
