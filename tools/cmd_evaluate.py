"""`tofcut evaluate CAPTURE --tracks T.jsonl --masks M.npz`: score a run against ground truth.

The truth is the emulator's (`CAPTURE.truth.npz`, written by `tofcut record emulator:...`).
Scored per frame: every object with at least `--min-pixels` visible pixels that moves
during the run (static scenery is background by definition of the empty-scene model).
An object's position is the centroid of its visible surface (truth range along each of its
pixels' rays), a track's the centroid it reports; they match within `--gate` metres
(py-motmetrics, Hungarian matching). Tracks within the gate of an object too small to
score, or of static scenery, are ignored: neither hits nor false positives. An object that
leaves the field of view and comes back (the emulated scenes loop) is a new object to
score, as it is to any tracker: its centroid's leaving the view ends a visit.

`--per-object` adds, for every object, the view from its masks alone (no gate): in how many
of its frames a track held most of it, which tracks those were, and its mean mask IoU with
that track over all its frames (0 where none held it): "kept one id in every frame".
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import motmetrics as mm
import numpy as np

from tofcut.driver.calibration import pixel_rays
from tofcut.driver.capture import CaptureReader
from tofcut.sim.truth import FrameTruth, load_truth, truth_path
from tofcut.tools.sources import SourceError

VISITS = 1000
"""Object ids in the scores are object × VISITS + visit (see the module's docstring)."""
STATIC_M = 0.01
"""An object whose centroid moves less than this over the run is scenery."""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("evaluate", help="score tracks and masks against emulator ground truth")
    p.add_argument("capture", type=Path, metavar="CAPTURE.tofcap")
    p.add_argument("--tracks", type=Path, required=True, metavar="FILE.jsonl")
    p.add_argument("--masks", type=Path, required=True, metavar="FILE.npz")
    p.add_argument("--gate", type=float, default=0.1, help="match distance, metres (0.1)")
    p.add_argument("--min-pixels", type=int, default=50, help="smallest object scored (50)")
    p.add_argument("--per-object", action="store_true", help="also a line per object (masks)")
    p.add_argument("--json", type=Path, help="also write the scores here")
    p.set_defaults(func=run)


def score(
    truths: list[FrameTruth],
    tracks: dict[int, list[dict[str, Any]]],
    masks: dict[int, np.ndarray],
    rays: np.ndarray,
    gate: float = 0.1,
    min_pixels: int = 50,
) -> dict[str, float]:
    """MOTA, IDF1, ID switches and mean mask IoU of matched objects over the given frames."""
    centres = [o.centroid for t in truths for o in t.objects]
    ids = [o.id for t in truths for o in t.objects]
    moving = {
        i for i in set(ids)
        if np.ptp(np.array([c for c, j in zip(centres, ids, strict=True) if j == i]), axis=0).max()
        >= STATIC_M
    }  # fmt: skip
    acc = mm.MOTAccumulator(auto_id=False)
    ious: list[float] = []
    corners = rays[[0, 0, -1, -1], [0, -1, 0, -1]]
    lo = (corners[:, :2] / corners[:, 2:]).min(axis=0)
    hi = (corners[:, :2] / corners[:, 2:]).max(axis=0)
    visits: dict[int, int] = {}
    left: dict[int, bool] = {}
    for truth in truths:
        seq = truth.sequence
        for o in truth.objects:
            c = o.centroid
            inside = bool(c[2] > 0 and np.all((lo <= c[:2] / c[2]) & (c[:2] / c[2] <= hi)))
            if o.pixels > 0 and left.get(o.id, True):
                visits[o.id] = visits.get(o.id, 0) + 1
                left[o.id] = False
            if not inside and o.pixels == 0:
                left[o.id] = True
        hyps = tracks.get(seq, [])
        counts = np.bincount(truth.labels.ravel(), minlength=max(ids, default=0) + 1)
        gt_ids, gt_pos, ignored = [], [], []
        for oid in sorted(set(ids)):
            n = int(counts[oid]) if oid < len(counts) else 0
            if n == 0:
                continue
            mask = truth.labels == oid
            pos = (rays[mask] * truth.range[mask][:, None]).mean(axis=0)
            if oid in moving and n >= min_pixels:
                gt_ids.append(oid * VISITS + visits.get(oid, 1))
                gt_pos.append(pos)
            else:
                ignored.append(pos)
        hyps = [
            h for h in hyps
            if all(np.linalg.norm(np.array(h["centroid"]) - p) >= gate for p in ignored)
        ]  # fmt: skip
        hyp_pos = np.array([h["centroid"] for h in hyps]).reshape(-1, 3)
        dist = mm.distances.norm2squared_matrix(
            np.array(gt_pos).reshape(-1, 3), hyp_pos, max_d2=gate * gate
        )
        acc.update(gt_ids, [h["id"] for h in hyps], np.sqrt(dist), frameid=seq)
    # mask IoU of every matched pair (read once: mot_events is rebuilt on each access)
    by_seq = {t.sequence: t for t in truths}
    events = acc.mot_events
    matched = events[events.Type.isin(["MATCH", "SWITCH"])]
    for (seq, _), ev in matched.iterrows():
        labels = masks.get(int(seq))
        if labels is None:
            continue
        a = by_seq[int(seq)].labels == int(ev.OId) // VISITS
        b = labels == int(ev.HId)
        ious.append(float((a & b).sum() / max(1, (a | b).sum())))
    mh = mm.metrics.create()
    summary = mh.compute(
        acc, metrics=["mota", "idf1", "num_switches", "num_objects", "num_false_positives",
                      "num_misses"], name="run",
    )  # fmt: skip
    row = summary.loc["run"]
    return {
        "mota": float(row["mota"]),
        "idf1": float(row["idf1"]),
        "id_switches": int(row["num_switches"]),
        "objects": int(row["num_objects"]),
        "false_positives": int(row["num_false_positives"]),
        "misses": int(row["num_misses"]),
        "mean_iou": float(np.mean(ious)) if ious else 0.0,
        "frames": len(truths),
    }


def per_object(
    truths: list[FrameTruth], masks: dict[int, np.ndarray], min_pixels: int = 50
) -> list[dict[str, Any]]:
    """Per object (all its frames with at least `min_pixels` visible pixels): frames, frames
    a track held most of it, the ids of those tracks, and the mean mask IoU with them."""
    seen: dict[int, dict[str, Any]] = {}
    for truth in truths:
        labels = masks.get(truth.sequence)
        for obj in truth.objects:
            mine = truth.labels == obj.id
            n = int(mine.sum())
            if n < min_pixels:
                continue
            row = seen.setdefault(obj.id, {"id": obj.id, "name": obj.name, "frames": 0,
                                           "held": 0, "track_ids": set(), "iou": 0.0})  # fmt: skip
            row["frames"] += 1
            if labels is None:
                continue
            ids, counts = np.unique(labels[mine], return_counts=True)
            best = int(ids[np.argmax(counts)])
            if best == 0 or counts.max() * 2 <= n:
                continue
            held = labels == best
            row["held"] += 1
            row["track_ids"].add(best)
            row["iou"] += float((held & mine).sum() / (held | mine).sum())
    return [
        {**r, "track_ids": sorted(r["track_ids"]), "iou": r["iou"] / r["frames"]}
        for r in sorted(seen.values(), key=lambda r: int(r["id"]))
    ]


def run(args: argparse.Namespace) -> int:
    path = truth_path(args.capture)
    if not path.is_file():
        raise SourceError(f"no ground truth beside the capture ({path}): record from the emulator")
    reader = CaptureReader(args.capture)
    truths = load_truth(path)
    tracks: dict[int, list[dict[str, Any]]] = {}
    for line in args.tracks.read_text(encoding="utf-8").splitlines():
        rec = json.loads(line)
        tracks[int(rec["seq"])] = list(rec["tracks"])
    with np.load(args.masks) as z:
        labels, seqs = z["labels"], z["seq"]  # read once: each z[...] decompresses anew
    masks = {int(s): labels[i] for i, s in enumerate(seqs)}
    scored = [t for t in truths if t.sequence in tracks]
    if not scored:
        raise SourceError("the tracks and the ground truth share no frame")
    result = score(scored, tracks, masks, pixel_rays(reader.calibration), args.gate,
                   args.min_pixels)  # fmt: skip
    print(
        f"{result['frames']} frames, {result['objects']} object-frames: "
        f"MOTA {result['mota']:.3f}  IDF1 {result['idf1']:.3f}  "
        f"ID switches {result['id_switches']}  mean mask IoU {result['mean_iou']:.3f}  "
        f"(misses {result['misses']}, false positives {result['false_positives']})"
    )
    if args.per_object:
        objects = per_object(scored, masks, args.min_pixels)
        for o in objects:
            print(
                f"  {o['name']}: held by a track in {o['held']} of {o['frames']} frames, "
                f"ids {o['track_ids']}, mean mask IoU {o['iou']:.3f}"
            )
    if args.json:
        doc: dict[str, Any] = {**result, **({"per_object": objects} if args.per_object else {})}
        args.json.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return 0
