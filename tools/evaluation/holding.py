"""Where a run loses its objects, from the masks alone: each frame of each object in view
(`MIN_PIXELS` or more) counted once, as

- **held**: a track's mask has an IoU of at least `MIN_IOU` with it;
- **merged**: not held, and the track holding most of it has `MERGED_SHARE` or more of its
  mask on other objects (two objects taken as one);
- **partly held**: not held, though a track holds some of it (too little of it, or too much
  else: a split object, an edge lost, the scenery taken in);
- **missed**: no track's mask touches it.

The shares say which part of the tracker to work on: merges are the cut and the splitting of
touching objects, partial holds the cut's edges, misses the finding of objects.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from tofcut.sim.truth import FrameTruth
from tofcut.tools.evaluation.counts import Counts
from tofcut.tools.evaluation.scoring import MIN_IOU, MIN_PIXELS, Labels, overlaps

MERGED_SHARE = 0.3
"""Share of a track's mask on other objects that makes it a merge, not a loose edge."""


@dataclass(frozen=True)
class Holding(Counts):
    """Object-frames counted by how they were held (see the module's docstring)."""

    held: int = 0
    merged: int = 0
    partly: int = 0
    missed: int = 0

    @property
    def total(self) -> int:
        return self.held + self.merged + self.partly + self.missed


@dataclass(frozen=True)
class Hold:
    """One object in one frame, and the track that holds the most of it."""

    obj: int
    pixels: int
    """Its visible pixels."""
    track: int
    """The track whose mask holds the most of them (ties: the lowest id); 0: none holds any."""
    iou: float
    """That track's mask's IoU with it (0 where none)."""
    elsewhere: float
    """The share of that track's mask on other objects (0 where none)."""


def holds(truth: FrameTruth, hyp: Labels | None) -> Iterator[Hold]:
    """Each object in view in a frame (`truth`) and the track of the label image `hyp` (None:
    no masks for that frame) that holds the most of it."""
    if hyp is None:
        hyp = np.zeros_like(truth.labels)
    shared = overlaps(truth.labels, hyp)
    areas_t, areas_h = shared.sum(axis=1), shared.sum(axis=0)
    for obj in truth.objects:
        if obj.id >= shared.shape[0] or not areas_t[obj.id]:
            continue
        row = shared[obj.id]
        area = int(areas_t[obj.id])
        if not row[1:].any():
            yield Hold(obj.id, area, 0, 0.0, 0.0)
            continue
        best = int(np.argmax(row[1:])) + 1
        iou = row[best] / (area + areas_h[best] - row[best])
        others = areas_h[best] - shared[0, best] - row[best]
        yield Hold(obj.id, area, best, float(iou), float(others / areas_h[best]))


def holding(truths: Sequence[FrameTruth], masks: Sequence[Labels | None]) -> Holding:
    """How each object-frame of a run was held, from each frame's truth and label image
    (None: no masks for that frame, so every object in it is missed)."""
    counts = {"held": 0, "merged": 0, "partly": 0, "missed": 0}
    for truth, hyp in zip(truths, masks, strict=True):
        for h in holds(truth, hyp):
            if h.pixels < MIN_PIXELS:
                continue
            if not h.track:
                counts["missed"] += 1
            elif h.iou >= MIN_IOU:
                counts["held"] += 1
            elif h.elsewhere >= MERGED_SHARE:
                counts["merged"] += 1
            else:
                counts["partly"] += 1
    return Holding(**counts)
