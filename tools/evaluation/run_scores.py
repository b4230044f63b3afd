"""One run's scores as `tofcut evaluate` and the tests read them: the dict of the centroid
matching's numbers it has always returned, and the per-object view from the masks alone."""

from __future__ import annotations

from typing import Any

import numpy as np

from tofcut.sim.truth import FrameTruth
from tofcut.tools.evaluation.scoring import GATE_M, MIN_PIXELS, evaluate


def score(
    truths: list[FrameTruth],
    tracks: dict[int, list[dict[str, Any]]],
    masks: dict[int, np.ndarray],
    rays: np.ndarray,
    gate: float = GATE_M,
    min_pixels: int = MIN_PIXELS,
) -> dict[str, float]:
    """MOTA, IDF1, ID switches (centroid matching) and mean mask IoU of matched objects.

    The dict this has always returned; `tofcut.tools.evaluation.scoring.evaluate` gives
    every number.
    """
    return evaluate(truths, tracks, masks, rays, gate, min_pixels).legacy()


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
