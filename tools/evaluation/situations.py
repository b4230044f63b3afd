"""Two situations the tracker's bars name, scored from the masks alone: objects in view from
the first frame (a line that is already running), and touching objects of different heights.

An object is *held* in a frame by the track whose mask has an IoU of at least 0.5 with it (at
most one can). Counted:

- **from the start**: each object in view in the first frame (`MIN_PIXELS` or more) is held
  by frame `FIRST_FRAMES`, and from then on by that one track in every frame in which it shows
  at least half of its largest view, until it leaves (its first visit);
- **touching**: each time a pair of objects that touch (side by side or nose to tail) and
  whose heights differ by `MIN_STEP_M` or more are in view together (a passage: breaks of
  fewer than `BRIDGE_FRAMES` frames do not end it), `APART_FRAMES` frames
  after both have come wholly into view (each showing 90% of its largest view of that
  passage), each is held by a track of its own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tofcut.sim.truth import FrameTruth
from tofcut.tools.evaluation.counts import Counts
from tofcut.tools.evaluation.holding import holds
from tofcut.tools.evaluation.scoring import MIN_IOU, MIN_PIXELS, Labels

FIRST_FRAMES = 10
APART_FRAMES = 5
MIN_STEP_M = 0.04
WHOLE = 0.9
"""An object is wholly in view when it shows this share of its largest view of a passage."""
BRIDGE_FRAMES = 10
"""Frames out of view that do not end a pair's passage."""


@dataclass(frozen=True)
class Situations(Counts):
    """How a run did in the two situations (see the module's docstring)."""

    from_start: int
    """Objects in view in the first frame."""
    from_start_held: int
    """Of them, held by frame `FIRST_FRAMES` and kept by one track."""
    touching: int
    """Passages of touching pairs of different heights wholly in view together."""
    touching_apart: int
    """Of them, held by two tracks `APART_FRAMES` frames after."""


NONE = Situations(0, 0, 0, 0)


def holders(truths: Sequence[FrameTruth], masks: Sequence[Labels | None]) -> tuple[
    dict[int, np.ndarray], dict[int, np.ndarray]
]:  # fmt: skip
    """Per object id, its visible pixels in every frame and the track that holds it (0: none),
    from each frame's truth and label image (None: no masks for that frame)."""
    n = len(truths)
    ids = sorted({o.id for t in truths for o in t.objects})
    pixels = {i: np.zeros(n, np.int64) for i in ids}
    held = {i: np.zeros(n, np.int64) for i in ids}
    for k, (truth, hyp) in enumerate(zip(truths, masks, strict=True)):
        for h in holds(truth, hyp):
            pixels[h.obj][k] = h.pixels
            if h.track and h.iou >= MIN_IOU:
                held[h.obj][k] = h.track
    return pixels, held


def from_start(pixels: np.ndarray, held: np.ndarray) -> bool:
    """Whether an object in view in the first frame is held by frame `FIRST_FRAMES` and then
    kept by that one track wherever it shows half its largest view, to its first visit's end."""
    seen = pixels >= MIN_PIXELS
    end = int(np.argmin(seen)) if not seen.all() else len(seen)
    first = np.nonzero(held[: min(FIRST_FRAMES + 1, end)])[0]
    if not first.size:
        return False
    start = int(first[0])
    track = held[start]
    shown = pixels[start:end] * 2 >= pixels[:end].max()
    return bool(np.all(held[start:end][shown] == track))


def passages(a: np.ndarray, b: np.ndarray) -> list[tuple[int, int]]:
    """The runs of frames [start, stop) in which both objects are in view, a break of fewer
    than `BRIDGE_FRAMES` frames bridged: one partly hidden behind the other, showing about
    `MIN_PIXELS`, is one passage, not one each time it crosses that."""
    both = np.concatenate([[False], (a >= MIN_PIXELS) & (b >= MIN_PIXELS), [False]])
    edges = np.nonzero(np.diff(both.astype(np.int8)))[0]
    runs: list[tuple[int, int]] = []
    for start, stop in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
        if runs and start - runs[-1][1] < BRIDGE_FRAMES:
            start = runs.pop()[0]
        runs.append((start, stop))
    return runs


def kept_apart(pa: np.ndarray, pb: np.ndarray, ha: np.ndarray, hb: np.ndarray) -> list[bool]:
    """For each passage of a touching pair that comes wholly into view, whether the two are
    held by two tracks `APART_FRAMES` frames after (or at the passage's last frame)."""
    out = []
    for start, stop in passages(pa, pb):
        whole = (pa[start:stop] >= WHOLE * pa[start:stop].max()) & (
            pb[start:stop] >= WHOLE * pb[start:stop].max()
        )
        if not whole.any():
            continue
        k = min(start + int(np.argmax(whole)) + APART_FRAMES, stop - 1)
        out.append(bool(ha[k] and hb[k] and ha[k] != hb[k]))
    return out


def situations(
    truths: Sequence[FrameTruth],
    masks: Sequence[Labels | None],
    touching: Sequence[tuple[str, str]] = (),
) -> Situations:
    """The run's situations; `touching` names the pairs of objects that touch with heights
    `MIN_STEP_M` or more apart (from the line's drawing: the truth has no contacts)."""
    if not truths:
        return NONE
    pixels, held = holders(truths, masks)
    start = [o.id for o in truths[0].objects if o.pixels >= MIN_PIXELS]
    names = {o.name: o.id for t in truths for o in t.objects}
    apart = [
        ok
        for a, b in touching
        if a in names and b in names
        for ok in kept_apart(pixels[names[a]], pixels[names[b]], held[names[a]], held[names[b]])
    ]
    return Situations(
        from_start=len(start),
        from_start_held=sum(from_start(pixels[i], held[i]) for i in start),
        touching=len(apart),
        touching_apart=sum(apart),
    )
