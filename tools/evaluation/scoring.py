"""Scoring tracks and masks against the emulator's ground truth, by two matchings.

What is scored, per frame: every object with at least `min_pixels` visible pixels that moves
during the run (static scenery is background by definition of the empty-scene model). An
object that leaves the field of view and comes back (the emulated scenes loop) is a new
object to score, as it is to any tracker: its centroid's leaving the view ends a visit.

Two matchings of tracks to objects, each scored with py-motmetrics (CLEAR MOT: MOTA, ID
switches; and IDF1) and with TrackEval (HOTA, DetA, AssA: `tofcut.tools.evaluation.hota`, on
the same objects and tracks; its similarity is the mask IoU, or for centroids 1 − d / (2 ·
gate)):

- **by centroid**: an object's position is the centroid of its visible surface (truth range
  along each of its pixels' rays), a track's the centroid it reports; they match within
  `gate` metres (Hungarian matching). Tracks within the gate of an object too small to score,
  or of static scenery, are ignored: neither hits nor false positives.
- **by mask IoU** (the MOTS convention): a track is the set of pixels its id holds in the
  label image, an object the pixels the truth gives it; they match when their IoU is at
  least `min_iou` (0.5: above it a match is unique, since a mask can overlap more than half
  of only one other). A track with more than half of its pixels on objects too small to
  score or on static scenery is ignored. Tracks are taken from the masks alone.

And, from the masks alone, the **mask IoU**: the mean over every scored (object, frame) of
the IoU of the object with the track that holds most of its pixels, 0 where no track holds
any of it. Unlike the IoU of matched pairs it counts a missed object as 0, so a tracker
cannot raise it by dropping what it segments badly.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import motmetrics as mm
import numpy as np
import numpy.typing as npt

from tofcut.driver.calibration import pixel_rays
from tofcut.driver.capture import CaptureReader
from tofcut.driver.errors import CaptureError
from tofcut.sim.truth import FrameTruth, load_truth, truth_path
from tofcut.tools.evaluation.hota import FrameMatch, Hota, centroid_similarity, hota
from tofcut.tools.pipeline.sources import SourceError

VISITS = 1000
"""Object ids in the scores are object × VISITS + visit (see the module's docstring)."""
STATIC_M = 0.01
"""An object whose centroid moves less than this over the run is scenery."""
GATE_M = 0.1
MIN_PIXELS = 50
MIN_IOU = 0.5

Labels = npt.NDArray[np.integer[Any]]


@dataclass(frozen=True)
class Matching:
    """The CLEAR-MOT scores of one matching of tracks to objects over a run."""

    mota: float
    """1 − (misses + false positives + ID switches) / object-frames."""
    idf1: float
    """F1 of the best one-to-one assignment of whole tracks to whole objects."""
    id_switches: int
    objects: int
    """Object-frames scored (the denominator of MOTA)."""
    misses: int
    false_positives: int
    hota: Hota
    """HOTA, DetA and AssA of the same objects and tracks (TrackEval's)."""

    def to_json(self) -> dict[str, float | int]:
        return {
            "mota": self.mota, "idf1": self.idf1, "id_switches": self.id_switches,
            "objects": self.objects, "misses": self.misses,
            "false_positives": self.false_positives, **self.hota.to_json(),
        }  # fmt: skip


@dataclass(frozen=True)
class Scores:
    """A run scored both ways, with its mask IoU."""

    frames: int
    by_centroid: Matching
    by_iou: Matching
    mask_iou: float
    """Mean IoU over every scored object-frame with the track holding most of it (0: none)."""
    matched_iou: float
    """Mean mask IoU of the centroid-matched pairs (the first "mean mask IoU" tofcut printed)."""

    def legacy(self) -> dict[str, float]:
        """The scores as `score()` always returned them: the centroid matching's."""
        c = self.by_centroid
        return {
            "mota": c.mota, "idf1": c.idf1, "id_switches": c.id_switches,
            "objects": c.objects, "false_positives": c.false_positives, "misses": c.misses,
            "mean_iou": self.matched_iou, "frames": self.frames,
        }  # fmt: skip

    def to_json(self) -> dict[str, Any]:
        """Every number: the legacy keys at the top, then both matchings and the mask IoU."""
        return {
            **self.legacy(),
            "by_centroid": self.by_centroid.to_json(),
            "by_iou": self.by_iou.to_json(),
            "mask_iou": self.mask_iou,
        }


@dataclass(frozen=True, eq=False)
class _FrameObjects:
    """The objects of one frame as scored: who counts, where, and who is ignored."""

    truth: FrameTruth
    scored: list[int]
    """Object ids scored in this frame."""
    keys: list[int]
    """Their ids in the scores (object × VISITS + visit)."""
    positions: list[npt.NDArray[np.float64]]
    """Centroids of their visible surfaces."""
    ignored: list[int]
    """Visible objects not scored (too small, or static scenery)."""
    ignored_positions: list[npt.NDArray[np.float64]]


def _frames(
    truths: list[FrameTruth], rays: npt.NDArray[np.float64], min_pixels: int
) -> Iterator[_FrameObjects]:
    """Each frame's scored and ignored objects, visits numbered (see the module docstring)."""
    centres = [o.centroid for t in truths for o in t.objects]
    ids = [o.id for t in truths for o in t.objects]
    moving = {
        i for i in set(ids)
        if np.ptp(np.array([c for c, j in zip(centres, ids, strict=True) if j == i]), axis=0).max()
        >= STATIC_M
    }  # fmt: skip
    corners = rays[[0, 0, -1, -1], [0, -1, 0, -1]]
    lo = (corners[:, :2] / corners[:, 2:]).min(axis=0)
    hi = (corners[:, :2] / corners[:, 2:]).max(axis=0)
    visits: dict[int, int] = {}
    left: dict[int, bool] = {}
    for truth in truths:
        for o in truth.objects:
            c = o.centroid
            inside = bool(c[2] > 0 and np.all((lo <= c[:2] / c[2]) & (c[:2] / c[2] <= hi)))
            if o.pixels > 0 and left.get(o.id, True):
                visits[o.id] = visits.get(o.id, 0) + 1
                left[o.id] = False
            if not inside and o.pixels == 0:
                left[o.id] = True
        counts = np.bincount(truth.labels.ravel(), minlength=max(ids, default=0) + 1)
        frame = _FrameObjects(truth, [], [], [], [], [])
        for oid in sorted(set(ids)):
            n = int(counts[oid]) if oid < len(counts) else 0
            if n == 0:
                continue
            mask = truth.labels == oid
            pos = (rays[mask] * truth.range[mask][:, None]).mean(axis=0)
            if oid in moving and n >= min_pixels:
                frame.scored.append(oid)
                frame.keys.append(oid * VISITS + visits.get(oid, 1))
                frame.positions.append(pos)
            else:
                frame.ignored.append(oid)
                frame.ignored_positions.append(pos)
        yield frame


def overlaps(truth: Labels, hyp: Labels) -> npt.NDArray[np.int64]:
    """Pixels shared by each truth id (rows) and each track id (columns), 0 included."""
    g = truth.astype(np.int64).ravel()
    h = hyp.astype(np.int64).ravel()
    cols = int(h.max(initial=0)) + 1
    rows = int(g.max(initial=0)) + 1
    return np.bincount(g * cols + h, minlength=rows * cols).reshape(rows, cols)


def summary(acc: mm.MOTAccumulator, frames: list[FrameMatch]) -> Matching:
    """A matching's CLEAR MOT scores and IDF1 (py-motmetrics) and its HOTA (TrackEval)."""
    mh = mm.metrics.create()
    table = mh.compute(
        acc, metrics=["mota", "idf1", "num_switches", "num_objects", "num_false_positives",
                      "num_misses"], name="run",
    )  # fmt: skip
    row = table.loc["run"]
    mota = float(row["mota"])
    return Matching(
        mota=mota if np.isfinite(mota) else 0.0,
        idf1=float(row["idf1"]) if np.isfinite(float(row["idf1"])) else 0.0,
        id_switches=int(row["num_switches"]),
        objects=int(row["num_objects"]),
        misses=int(row["num_misses"]),
        false_positives=int(row["num_false_positives"]),
        hota=hota(frames),
    )


def evaluate(
    truths: list[FrameTruth],
    tracks: dict[int, list[dict[str, Any]]],
    masks: dict[int, Labels],
    rays: npt.NDArray[np.float64],
    gate: float = GATE_M,
    min_pixels: int = MIN_PIXELS,
    min_iou: float = MIN_IOU,
) -> Scores:
    """Score the given frames both ways (see the module docstring).

    `tracks` and `masks` are by sequence number: a frame's tracks as `--tracks-out` writes
    them (`id`, `centroid`), and its label image (0 background, else the track's id). A
    frame without masks has no track by IoU.
    """
    by_centroid = mm.MOTAccumulator(auto_id=False)
    by_iou = mm.MOTAccumulator(auto_id=False)
    centroid_frames: list[FrameMatch] = []
    iou_frames: list[FrameMatch] = []
    held_ious: list[float] = []
    for frame in _frames(truths, rays, min_pixels):
        seq = frame.truth.sequence
        hyps = [
            h for h in tracks.get(seq, [])
            if all(np.linalg.norm(np.array(h["centroid"]) - p) >= gate
                   for p in frame.ignored_positions)
        ]  # fmt: skip
        hyp_pos = np.array([h["centroid"] for h in hyps]).reshape(-1, 3)
        dist = mm.distances.norm2squared_matrix(
            np.array(frame.positions).reshape(-1, 3), hyp_pos, max_d2=gate * gate
        )
        hyp_ids = [h["id"] for h in hyps]
        by_centroid.update(frame.keys, hyp_ids, np.sqrt(dist), frameid=seq)
        sim = centroid_similarity(np.array(frame.positions), hyp_pos, gate)
        centroid_frames.append(FrameMatch(frame.keys, hyp_ids, sim))

        hyp = masks.get(seq)
        if hyp is None:
            hyp = np.zeros_like(frame.truth.labels)
        shared = overlaps(frame.truth.labels, hyp)
        areas_t = shared.sum(axis=1)
        areas_h = shared.sum(axis=0)
        on_ignored = shared[[i for i in frame.ignored if i < shared.shape[0]]].sum(axis=0)
        track_ids = [
            int(h) for h in np.nonzero(areas_h)[0] if h > 0 and 2 * on_ignored[h] <= areas_h[h]
        ]
        iou = np.full((len(frame.scored), len(track_ids)), np.nan)
        for i, oid in enumerate(frame.scored):
            row = shared[oid] if oid < shared.shape[0] else np.zeros(shared.shape[1], np.int64)
            for j, h in enumerate(track_ids):
                if row[h]:
                    iou[i, j] = row[h] / (areas_t[oid] + areas_h[h] - row[h])
            best = int(np.argmax(row[1:])) + 1 if row[1:].any() else 0
            held_ious.append(
                float(row[best] / (areas_t[oid] + areas_h[best] - row[best])) if best else 0.0
            )
        dist_iou = np.where(iou >= min_iou, 1.0 - iou, np.nan)
        by_iou.update(frame.keys, track_ids, dist_iou, frameid=seq)
        iou_frames.append(FrameMatch(frame.keys, track_ids, np.nan_to_num(iou, nan=0.0)))
    # mask IoU of every centroid-matched pair (read once: mot_events is rebuilt on each access)
    by_seq = {t.sequence: t for t in truths}
    events = by_centroid.mot_events
    matched = events[events.Type.isin(["MATCH", "SWITCH"])]
    ious: list[float] = []
    for (seq, _), ev in matched.iterrows():
        labels = masks.get(int(seq))
        if labels is None:
            continue
        a = by_seq[int(seq)].labels == int(ev.OId) // VISITS
        b = labels == int(ev.HId)
        ious.append(float((a & b).sum() / max(1, (a | b).sum())))
    return Scores(
        frames=len(truths),
        by_centroid=summary(by_centroid, centroid_frames),
        by_iou=summary(by_iou, iou_frames),
        mask_iou=float(np.mean(held_ious)) if held_ious else 0.0,
        matched_iou=float(np.mean(ious)) if ious else 0.0,
    )


@dataclass(frozen=True, eq=False)
class RunFiles:
    """A run read from its files: the truth of the frames tracked, tracks, masks, rays."""

    truths: list[FrameTruth]
    tracks: dict[int, list[dict[str, Any]]]
    masks: dict[int, Labels]
    rays: npt.NDArray[np.float64]


def _is_zip(path: Path) -> bool:
    """An .npz file is a zip archive."""
    with path.open("rb") as f:
        return f.read(4) == b"PK\x03\x04"


def read_run(
    capture: Path, tracks: Path, masks: Path, truths: list[FrameTruth] | None = None
) -> RunFiles:
    """Read a capture's truth and calibration and a run's tracks and masks; one-line errors.

    `truths` saves reading the truth again when several runs of one capture are scored.
    """
    for p, what in ((capture, "capture"), (tracks, "tracks file"), (masks, "masks file")):
        if not p.is_file():
            there = "is a folder" if p.is_dir() else "does not exist"
            raise SourceError(f"{what} {p} {there}")
    if _is_zip(tracks):
        raise SourceError(f"{tracks} is an .npz file, not a tracks file: --tracks takes the "
                          "run's --tracks-out (JSONL), --masks its --masks-out (.npz)")  # fmt: skip
    if not _is_zip(masks):
        raise SourceError(f"{masks} is not an .npz file: --masks takes the run's --masks-out "
                          "(.npz), --tracks its --tracks-out (JSONL)")  # fmt: skip
    path = truth_path(capture)
    if truths is None:
        if not path.is_file():
            raise SourceError(
                f"no ground truth beside the capture ({path}): record from the emulator"
            )
        truths = load_truth(path)
    try:
        rays = pixel_rays(CaptureReader(capture).calibration)
    except CaptureError as exc:
        raise SourceError(f"{capture}: {exc}") from None
    by_seq: dict[int, list[dict[str, Any]]] = {}
    try:
        for line in tracks.read_text(encoding="utf-8").splitlines():
            rec = json.loads(line)
            by_seq[int(rec["seq"])] = list(rec["tracks"])
    except (ValueError, KeyError, TypeError) as exc:
        raise SourceError(
            f"{tracks} is not a tracks file (one JSON object a frame): {exc}"
        ) from None
    try:
        with np.load(masks) as z:
            labels, seqs = z["labels"], z["seq"]  # read once: each z[...] decompresses anew
    except (OSError, ValueError, KeyError) as exc:
        raise SourceError(f"{masks} is not a masks file (labels and seq): {exc}") from None
    if labels.ndim != 3 or len(labels) != len(seqs):
        raise SourceError(f"{masks}: labels are not one image per seq")
    label_maps = {int(s): labels[i] for i, s in enumerate(seqs)}
    scored = [t for t in truths if t.sequence in by_seq]
    if not scored:
        raise SourceError("the tracks and the ground truth share no frame")
    if scored[0].labels.shape != labels.shape[1:]:
        raise SourceError(f"{masks}: images of {labels.shape[1:]}, the truth's are "
                          f"{scored[0].labels.shape}")  # fmt: skip
    return RunFiles(scored, by_seq, label_maps, rays)
