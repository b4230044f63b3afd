"""HOTA, with its detection and association parts, computed by TrackEval.

HOTA (Luiten et al., *HOTA: A Higher Order Metric for Evaluating Multi-Object Tracking*,
IJCV 2021) scores detection and association at once: at each localisation threshold α
(0.05, 0.10, ... 0.95) a truth and a track match where their similarity is at least α
(the assignment in each frame favours pairs that stay together over the run), and

    DetA_α = TP / (TP + FN + FP),  AssA_α = mean over the TPs of TPA / (TPA + FNA + FPA),
    HOTA_α = √(DetA_α · AssA_α);  HOTA, DetA and AssA are their means over α.

TrackEval's own `HOTA` metric computes them here (`eval_sequence`), from the per-frame ids
and similarities this module hands it, and TrackEval's own similarity functions give the
similarities: mask IoU, as its MOTS datasets do, and for 3D centroids
`max(0, 1 − d / (2 · gate))`, as it scores MOT15's 3D benchmark, so that a distance of
`gate` is similarity 0.5, where CLEAR MOT's matching (MOTA) stops.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tofcut._types import F64, I64


@dataclass(frozen=True, eq=False)
class FrameMatch:
    """One frame as HOTA sees it: truth ids, track ids, and their similarities in [0, 1]."""

    truth_ids: Sequence[int]
    track_ids: Sequence[int]
    similarity: F64
    """(len(truth_ids), len(track_ids))."""


@dataclass(frozen=True)
class Hota:
    """HOTA and its parts, each the mean over the localisation thresholds α."""

    hota: float
    deta: float
    """Detection accuracy."""
    assa: float
    """Association accuracy."""
    loca: float
    """Localisation accuracy: mean similarity of the matched pairs."""

    def to_json(self) -> dict[str, float]:
        return {"hota": self.hota, "deta": self.deta, "assa": self.assa, "loca": self.loca}


def _dense(ids: Sequence[Sequence[int]]) -> tuple[list[I64], int]:
    """Ids renumbered 0..n-1 in order of first sight (TrackEval indexes arrays by them)."""
    index: dict[int, int] = {}
    out = [np.array([index.setdefault(int(i), len(index)) for i in f], np.int64) for f in ids]
    return out, len(index)


def hota(frames: Sequence[FrameMatch]) -> Hota:
    """HOTA, DetA, AssA and LocA of a run, by TrackEval's `HOTA.eval_sequence`."""
    from trackeval.metrics import HOTA

    for f in frames:
        if f.similarity.shape != (len(f.truth_ids), len(f.track_ids)):
            raise ValueError(
                f"similarity of shape {f.similarity.shape} for "
                f"{len(f.truth_ids)} truths and {len(f.track_ids)} tracks"
            )
    truth_ids, n_truth = _dense([f.truth_ids for f in frames])
    track_ids, n_tracks = _dense([f.track_ids for f in frames])
    data: dict[str, Any] = {
        "num_timesteps": len(frames),
        "num_gt_ids": n_truth,
        "num_tracker_ids": n_tracks,
        "num_gt_dets": sum(len(f.truth_ids) for f in frames),
        "num_tracker_dets": sum(len(f.track_ids) for f in frames),
        "gt_ids": truth_ids,
        "tracker_ids": track_ids,
        "similarity_scores": [np.asarray(f.similarity, np.float64) for f in frames],
    }
    res = HOTA().eval_sequence(data)
    if data["num_gt_dets"] == 0 or data["num_tracker_dets"] == 0:
        return Hota(0.0, 0.0, 0.0, 1.0)  # TrackEval's early return leaves HOTA's fields at 0
    return Hota(
        hota=float(np.mean(res["HOTA"])),
        deta=float(np.mean(res["DetA"])),
        assa=float(np.mean(res["AssA"])),
        loca=float(np.mean(res["LocA"])),
    )


def centroid_similarity(truths: F64, tracks: F64, gate: float) -> F64:
    """max(0, 1 − d / (2 · gate)) for every truth (rows) and track (columns), by TrackEval."""
    from trackeval.datasets._base_dataset import _BaseDataset

    a = np.asarray(truths, np.float64).reshape(-1, 3)
    b = np.asarray(tracks, np.float64).reshape(-1, 3)
    if not len(a) or not len(b):
        return np.zeros((len(a), len(b)))
    sim: F64 = _BaseDataset._calculate_euclidean_similarity(a, b, zero_distance=2.0 * gate)
    return sim


def mask_similarity(
    truths: Sequence[dict[str, object]], tracks: Sequence[dict[str, object]], *, ioa: bool = False
) -> F64:
    """Mask IoU of COCO RLE masks, `truths` as rows, by TrackEval (through pycocotools);
    with `ioa`, the share of each row's mask that lies in each column's."""
    from trackeval.datasets._base_dataset import _BaseDataset

    if not len(truths) or not len(tracks):
        return np.zeros((len(truths), len(tracks)))
    sim: F64 = _BaseDataset._calculate_mask_ious(
        list(truths), list(tracks), is_encoded=True, do_ioa=ioa
    )
    return sim
