"""An object's outline given back to its mask: mixed pixels to the surface they read nearer,
and notches to the track around them.

A pixel that straddles an object's rim and the scenery behind it reads a range between the
two (its returns are averaged over the pixel). It is near neither surface, so the cut gives
it to neither track nor scenery with any confidence, and the background wins: every mask
loses its rim. Which surface covers most of such a pixel shows in which of the two ranges
its own lies nearer to, so a background pixel beside a track whose range lies past the
midpoint toward the track's is the track's. A background pixel then left with five of its
eight neighbours in one track (a hole, or a notch in the outline where a pixel read wide of
both surfaces) is that track's. Only the output masks take these pixels: their points lie
between the object and what is behind it, so the track's point cloud, centroid and shape
leave them out.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tofcut._types import F64, I64, U16, B
from tofcut.tracker import rims_kernels
from tofcut.tracker.tracks import Track


@dataclass(frozen=True, eq=False)
class Rimmed:
    """A frame's labels and tracks with the outlines given back to their tracks."""

    labels: U16
    tracks: tuple[Track, ...]


def add_rims(
    labels: U16, tracks: tuple[Track, ...], seen: F64, valid: B, scenery: F64, known: B
) -> Rimmed:
    """`labels` with the outlines given back (`rims_kernels.rims`: `seen`, the frame's ranges
    as the scenery `scenery` is compared with, where `known`), and `tracks` with their masks'
    pixel counts and image boxes as that grows them."""
    ids = np.array([t.id for t in tracks], np.int64)
    boxes = np.array([t.bbox for t in tracks], np.int64).reshape(-1, 4)
    pixels = np.array([t.pixels for t in tracks], np.int64)
    out, grown_boxes, counts = rims_kernels.rims(
        labels, seen, valid, scenery, known, ids, boxes, pixels
    )
    grown = (_grown(t, grown_boxes[k], int(counts[k])) for k, t in enumerate(tracks))
    return Rimmed(out, tuple(grown))


def _grown(track: Track, box: I64, pixels: int) -> Track:
    """`track` with its mask's image box and pixel count as the outline grew them."""
    if pixels == track.pixels:
        return track
    u0, v0, u1, v1 = box.tolist()
    return dataclasses.replace(track, bbox=(u0, v0, u1, v1), pixels=pixels)
