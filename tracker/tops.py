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
MIN_SEAM = 6
"""Neighbour pairs two masks must meet along to be faces of one object."""
MIN_TOP = 20
"""Pixels facing up that make a top."""
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


def one_object(
    labels: npt.NDArray[np.uint16], xyz: F64, up: B | None, belt: BeltGeometry, joined_m: float
) -> list[tuple[int, int]]:
    """Pairs of labels (smaller first) whose masks meet along a seam where most neighbours
    across it are within `joined_m` in 3D (one surface going on, no step) and which do not
    hold tops at heights apart by `MIN_TOP_STEP_M` (`up`: the pixels facing up; None, as
    where the noise hides the slope, tells no tops): two tracks holding faces of one object."""
    pairs: dict[tuple[int, int], list[int]] = {}
    for first, second in ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :])):
        a, b = labels[first], labels[second]
        meet = (a != b) & (a > 0) & (b > 0)
        if not meet.any():
            continue
        gap = np.linalg.norm(xyz[first][meet] - xyz[second][meet], axis=-1)
        lo, hi = np.minimum(a[meet], b[meet]), np.maximum(a[meet], b[meet])
        for x, y, g in zip(lo.tolist(), hi.tolist(), (gap <= joined_m).tolist(), strict=True):
            counts = pairs.setdefault((x, y), [0, 0])
            counts[0] += 1
            counts[1] += int(g)
    out = []
    for (x, y), (meet_n, joined_n) in pairs.items():
        if meet_n < MIN_SEAM or joined_n * 2 < meet_n:
            continue
        if up is not None:
            hx, hy = (
                _top_height(labels == x, up, xyz, belt),
                _top_height(labels == y, up, xyz, belt),
            )
            if hx is not None and hy is not None and abs(hx - hy) >= MIN_TOP_STEP_M:
                continue
        out.append((x, y))
    return out


def _top_height(mask: B, up: B, xyz: F64, belt: BeltGeometry) -> float | None:
    """The median height of a mask's pixels facing up, if it has `MIN_TOP` of them."""
    top = mask & up
    if np.count_nonzero(top) < MIN_TOP:
        return None
    return float(np.median(belt.height(xyz[top])))
