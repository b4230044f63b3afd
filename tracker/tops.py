"""Objects on a belt told apart by their tops: what faces up, at one height, is one object.

Seen from above and to one side, a tall box's side face runs on into the top of a lower box
pressed against it with no step in range, so a cut at 3D steps keeps the two as one piece.
Their tops do not touch: between them stands the side face, which does not face up. A piece
holding two tops of its own at different heights is two objects; its pixels are dealt out to
the tops.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from tofcut.driver.belt import BeltGeometry
from tofcut.tracker import kernels

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]
I32 = npt.NDArray[np.int32]

BASELINE = 4
"""Pixels between the two points whose height and spacing give the slope: over one pixel the
range noise swamps the slope of a top."""
MAX_SLOPE = 0.5
"""A surface rising less than this per metre across the belt faces up (about 27°)."""
MIN_TOP_STEP_M = 0.02
"""Two tops of one piece nearer in height than this (or than three times the noise of their
mean heights) are one object's top broken up by noise."""
MAX_SLOPE_NOISE = 0.2
"""Where the noise of the measured slope is more than this (a flat top would read steep
one time in a hundred), no surface is told facing up."""


def facing_up(body: B, xyz: F64, noise: F64, belt: BeltGeometry) -> B | None:
    """The pixels of `body` on surfaces facing up from the belt (their slope over `BASELINE`
    pixels below `MAX_SLOPE`); None where the range noise makes the slope meaningless."""
    where = body & np.isfinite(xyz[..., 2])
    if not where.any():
        return where
    steep, *ratios = kernels.steep_pixels(where, xyz, noise, belt.normal, BASELINE, MAX_SLOPE)
    if any(r.size and kernels.median(r) > MAX_SLOPE_NOISE for r in ratios):
        return None
    up: B = where & ~steep
    return up


def split_by_tops(
    pieces: I32, up: B, xyz: F64, noise: F64, belt: BeltGeometry, min_pixels: int
) -> I32:
    """`pieces` (labelled 1..n), where a piece holds two tops or more of `min_pixels`
    (connected parts of `up`) at heights apart by `MIN_TOP_STEP_M` or more, dealt out to
    those tops: each pixel to the nearest in the image (a side face to the top it rises to
    or falls from). Pieces with one top, or tops at one height (one object's top broken up
    by noise), are kept whole."""
    tops = kernels.label_pieces(up & (pieces > 0))
    n = int(tops.max())
    if n < 2:
        return pieces
    size, height, noise2, home = kernels.top_stats(
        tops, n, pieces, xyz, noise, belt.origin, belt.normal
    )
    big = size >= min_pixels
    big[0] = False
    if big.sum() < 2:
        return pieces
    spread = np.sqrt(noise2 / np.maximum(size, 1))
    parted = []
    for piece in np.unique(home[big]).tolist():
        mine = np.nonzero(big & (home == piece))[0]
        if mine.size < 2:
            continue
        h, s = height[mine], spread[mine]
        apart = np.abs(h[:, None] - h[None, :]) >= np.maximum(
            MIN_TOP_STEP_M, 3.0 * np.hypot(s[:, None], s[None, :])
        )
        if apart.any():
            parted.append((piece, mine))
    if not parted:
        return pieces
    out = pieces.astype(np.int64)
    label = int(pieces.max())
    for piece, own in parted:
        region = pieces == piece
        _, (rows, cols) = ndimage.distance_transform_edt(~np.isin(tops, own), return_indices=True)
        relabel = np.zeros(n + 1, np.int64)
        relabel[own] = label + 1 + np.arange(own.size)
        label += own.size
        out[region] = relabel[tops[rows, cols][region]]
    # number the pieces 1..m in order of first appearance, as `kernels.label_pieces` does
    _, first, inverse = np.unique(out.ravel(), return_index=True, return_inverse=True)
    rank = np.empty(first.size, np.int64)
    rank[np.argsort(first)] = np.arange(first.size)
    if out.min() > 0:
        rank += 1
    return rank[inverse].reshape(pieces.shape).astype(np.int32)
