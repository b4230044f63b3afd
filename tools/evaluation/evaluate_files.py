"""`tofcut evaluate --truth FILE`: a run scored against ground truth in MOTChallenge or MOTS.

The truth's format is read from its first row: MOTChallenge rows
(`tofcut.tools.pipeline.mot`, commas, 7 to 10 fields) are matched to the run's tracks by 3D
centroid (their x, y, z) within `--gate`; MOTS lines (`tofcut.tools.pipeline.mots`, 6
fields) to the run's masks by mask IoU of at least `--min-iou`. The run is given as
`--tracks` (its `--tracks-out` JSONL or its `--mot-out` rows) for MOTChallenge truth, and as
`--masks` (its `--masks-out` .npz or its `--mots-out` lines) for MOTS truth.

Frames are lined up by the run-wide index (`tofcut.tools.pipeline.frame_stamp`):
MOTChallenge's frame 1 is index 0, MOTS's `time_frame` is the index (KITTI MOTS counts from
0), the JSONL's `frame` and the masks' `frame` are it (files written before they had it: the
n-th line or image is index n − 1). Every frame from the first to the last either file names
is scored.

What is not scored, as TrackEval has it: a MOTChallenge truth row whose `conf` is 0 (a
track within the gate of one is neither a hit nor a false positive), and a MOTS region of
class 10 (a track that matches no object and lies more than half in such regions is
dropped). Each matching is scored with py-motmetrics (MOTA, IDF1, ID switches) and with
TrackEval (HOTA, DetA, AssA: `tofcut.tools.evaluation.hota`).
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import motmetrics as mm
import numpy as np
import numpy.typing as npt
from pycocotools import mask as coco_mask
from scipy.optimize import linear_sum_assignment

from tofcut.tools.evaluation.hota import FrameMatch, centroid_similarity, mask_similarity
from tofcut.tools.evaluation.scoring import Matching, summary
from tofcut.tools.pipeline.mot import MotRow, parse_row, read_mot
from tofcut.tools.pipeline.mots import IGNORE_CLASS, MotsObject, parse_line, read_mots
from tofcut.tools.pipeline.sources import SourceError

Rle = dict[str, object]
MOT, MOTS = "MOTChallenge", "MOTS"


def truth_format(path: Path) -> str:
    """MOT or MOTS, from the file's first row that is not blank."""
    try:
        with path.open(encoding="utf-8") as f:
            first = next((line for line in f if line.strip()), None)
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"cannot read ground truth {path}: {exc}") from None
    if first is None:
        raise SourceError(f"ground truth {path} is empty")
    try:
        if len(first.split()) == 6 and "," not in first:
            parse_line(first)
            return MOTS
        parse_row(first)
        return MOT
    except ValueError:
        raise SourceError(
            f"{path} is neither MOTChallenge rows (frame,id,bb_left,bb_top,bb_width,bb_height,"
            "conf,x,y,z) nor MOTS lines (time_frame id class_id img_height img_width rle)"
        ) from None


def _is_zip(path: Path) -> bool:
    with path.open("rb") as f:
        return f.read(4) == b"PK\x03\x04"


def _is_jsonl(path: Path) -> bool:
    with path.open("rb") as f:
        return f.read(64).lstrip()[:1] == b"{"


# --- the run's tracks and masks, by run-wide frame index --------------------------------------

Positions = dict[int, list[tuple[int, npt.NDArray[np.float64]]]]
Masks = dict[int, list[tuple[int, Rle]]]


def track_positions(path: Path) -> Positions:
    """Each frame's tracks (id, 3D centroid), from `--tracks-out` JSONL or `--mot-out` rows."""
    out: Positions = defaultdict(list)
    if _is_zip(path):
        raise SourceError(f"{path} is an .npz file: --tracks takes the run's --tracks-out "
                          "(JSONL) or --mot-out (MOTChallenge rows)")  # fmt: skip
    if _is_jsonl(path):
        try:
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines()):
                rec = json.loads(line)
                frame = int(rec.get("frame", n))
                for t in rec["tracks"]:
                    out[frame].append((int(t["id"]), np.array(t["centroid"], np.float64)))
        except (ValueError, KeyError, TypeError) as exc:
            raise SourceError(f"{path} is not a tracks file (one JSON object a frame): "
                              f"{exc}") from None  # fmt: skip
        return out
    for row in read_mot(path):
        if row.xyz is None:
            raise SourceError(
                f"{path}: frame {row.frame}, id {row.id} has no x,y,z: matching by centroid "
                "needs the 3D centroid (--mot-out writes it)"
            )
        out[row.frame - 1].append((row.id, np.array(row.xyz)))
    return out


def track_masks(path: Path) -> tuple[Masks, tuple[int, int] | None]:
    """Each frame's track masks (id, COCO RLE) and their size, from `--masks-out` or
    `--mots-out`."""
    out: Masks = defaultdict(list)
    if not _is_zip(path):
        objects = [o for o in read_mots(path) if o.class_id != IGNORE_CLASS]
        for o in objects:
            out[o.frame].append((o.id, o.rle))
        return out, (objects[0].height, objects[0].width) if objects else None
    try:
        with np.load(path) as z:
            labels = z["labels"]
            frames = z["frame"] if "frame" in z.files else np.arange(len(labels))
    except (OSError, ValueError, KeyError) as exc:
        raise SourceError(f"{path} is not a masks file (labels and seq): {exc}") from None
    if labels.ndim != 3 or len(frames) != len(labels):
        raise SourceError(f"{path}: labels are not one image per frame")
    for frame, image in zip(frames, labels, strict=True):
        for ident in np.unique(image):
            if ident:
                rle = coco_mask.encode(np.asfortranarray(image == ident, dtype=np.uint8))
                out[int(frame)].append((int(ident), rle))
    return out, (int(labels.shape[1]), int(labels.shape[2]))


# --- scoring -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class TruthScores:
    """A run scored against a ground-truth file."""

    format: str
    """MOT or MOTS."""
    frames: int
    matching: Matching

    def to_json(self) -> dict[str, Any]:
        return {"format": self.format, "frames": self.frames, **self.matching.to_json()}


def _frames(*keys: Iterable[int]) -> range:
    last = max((k for ks in keys for k in ks), default=-1)
    return range(0, last + 1)


def _unique(path: Path, frame: int, ids: list[int]) -> None:
    if len(set(ids)) != len(ids):
        raise SourceError(f"{path}: an id is given twice in frame {frame}")


def score_centroids(path: Path, truth: list[MotRow], tracks: Positions, gate: float) -> TruthScores:
    """MOTChallenge truth against tracks by 3D centroid within `gate` metres."""
    by_frame: dict[int, list[MotRow]] = defaultdict(list)
    for row in truth:
        if row.xyz is None:
            raise SourceError(f"{path}: frame {row.frame}, id {row.id} has no x,y,z (or -1): "
                              "matching by centroid needs the 3D centroid")  # fmt: skip
        by_frame[row.frame - 1].append(row)
    acc = mm.MOTAccumulator(auto_id=False)
    matches: list[FrameMatch] = []
    frames = _frames(by_frame, tracks)
    for f in frames:
        rows = by_frame.get(f, [])
        scored = [r for r in rows if r.conf != 0]
        ignored = np.array([r.xyz for r in rows if r.conf == 0], np.float64).reshape(-1, 3)
        ids = [r.id for r in scored]
        _unique(path, f + 1, ids)
        hyps = [
            (i, p) for i, p in tracks.get(f, [])
            if not len(ignored) or np.linalg.norm(ignored - p, axis=1).min() >= gate
        ]  # fmt: skip
        positions = np.array([r.xyz for r in scored], np.float64).reshape(-1, 3)
        hyp_pos = np.array([p for _, p in hyps], np.float64).reshape(-1, 3)
        hyp_ids = [i for i, _ in hyps]
        dist = mm.distances.norm2squared_matrix(positions, hyp_pos, max_d2=gate * gate)
        acc.update(ids, hyp_ids, np.sqrt(dist), frameid=f)
        matches.append(FrameMatch(ids, hyp_ids, centroid_similarity(positions, hyp_pos, gate)))
    return TruthScores(MOT, len(frames), summary(acc, matches))


def score_masks(path: Path, truth: list[MotsObject], tracks: Masks, min_iou: float) -> TruthScores:
    """MOTS truth against track masks by mask IoU of at least `min_iou`."""
    objects: dict[int, list[tuple[int, Rle]]] = defaultdict(list)
    ignore: dict[int, list[Rle]] = defaultdict(list)
    for o in truth:
        if o.class_id == IGNORE_CLASS:
            ignore[o.frame].append(o.rle)
        else:
            objects[o.frame].append((o.id, o.rle))
    acc = mm.MOTAccumulator(auto_id=False)
    matches: list[FrameMatch] = []
    frames = _frames(objects, ignore, tracks)
    for f in frames:
        ids = [i for i, _ in objects.get(f, [])]
        _unique(path, f, ids)
        hyps = tracks.get(f, [])
        sim = mask_similarity([m for _, m in objects.get(f, [])], [m for _, m in hyps])
        if ignore.get(f) and hyps:
            region = coco_mask.merge(ignore[f], intersect=False)
            inside = mask_similarity([m for _, m in hyps], [region], ioa=True)[:, 0]
            matched = set()
            if ids:
                score = np.where(sim >= min_iou - np.finfo(float).eps, sim, -10000.0)
                rows, cols = linear_sum_assignment(-score)
                matched = {int(c) for r, c in zip(rows, cols, strict=True) if score[r, c] > 0}
            keep = [j for j in range(len(hyps)) if j in matched or inside[j] <= 0.5]
            hyps = [hyps[j] for j in keep]
            sim = sim[:, keep]
        hyp_ids = [i for i, _ in hyps]
        acc.update(ids, hyp_ids, np.where(sim >= min_iou, 1.0 - sim, np.nan), frameid=f)
        matches.append(FrameMatch(ids, hyp_ids, sim))
    return TruthScores(MOTS, len(frames), summary(acc, matches))
