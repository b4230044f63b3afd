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


def _smoothed(xyz: F64, where: B) -> F64:
    """`where`'s points averaged over 3×3 (nan elsewhere)."""
    w = ndimage.uniform_filter(where.astype(np.float64), 3, mode="constant")
    pts = np.where(where[..., None], xyz, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (
            np.stack(
                [ndimage.uniform_filter(pts[..., k], 3, mode="constant") for k in range(3)], axis=-1
            )
            / w[..., None]
        )
    out[~where] = np.nan
    return out


def facing_up(body: B, xyz: F64, noise: F64, belt: BeltGeometry) -> B | None:
    """The pixels of `body` on surfaces facing up from the belt (their slope over `BASELINE`
    pixels below `MAX_SLOPE`); None where the range noise makes the slope meaningless."""
    where = body & np.isfinite(xyz).all(axis=-1)
    if not where.any():
        return where
    # only the body's box (and a margin for the filters) is looked at
    rows, cols = np.nonzero(where.any(axis=1))[0], np.nonzero(where.any(axis=0))[0]
    box = (
        slice(max(int(rows[0]) - 2, 0), int(rows[-1]) + 3),
        slice(max(int(cols[0]) - 2, 0), int(cols[-1]) + 3),
    )
    out = np.zeros(body.shape, bool)
    up = _facing_up(where[box], xyz[box], noise[box], belt)
    if up is None:
        return None
    out[box] = up
    return out


def _facing_up(where: B, xyz: F64, noise: F64, belt: BeltGeometry) -> B | None:
    """`facing_up` within a box round the body."""
    pts = _smoothed(xyz, where)
    n = belt.normal
    steep = np.zeros(where.shape, bool)
    slope_noise = []
    b = BASELINE
    for axis in (0, 1):
        first, second = [slice(None)] * 2, [slice(None)] * 2
        first[axis], second[axis] = slice(0, -b), slice(b, None)
        d = pts[tuple(second)] - pts[tuple(first)]
        both = where[tuple(first)] & where[tuple(second)]
        dh = d @ n
        lateral = np.linalg.norm(d - dh[..., None] * n, axis=-1)
        with np.errstate(invalid="ignore"):
            pair = both & (np.abs(dh) > MAX_SLOPE * lateral)
        if both.any():
            # a 3×3 mean's noise, twice (the difference), over the spacing
            sigma = noise[tuple(first)][both] * (np.sqrt(2.0) / 3.0)
            slope_noise.append(float(np.median(sigma / np.maximum(lateral[both], 1e-6))))
        for offset in range(b + 1):
            span = [slice(None)] * 2
            span[axis] = slice(offset, offset + pair.shape[axis])
            steep[tuple(span)] |= pair
    if slope_noise and max(slope_noise) > MAX_SLOPE_NOISE:
        return None
    return where & ~steep


def split_by_tops(
    pieces: I32, up: B, xyz: F64, noise: F64, belt: BeltGeometry, min_pixels: int
) -> I32:
    """`pieces` (labelled 1..n), where a piece holds two tops or more of `min_pixels`
    (connected parts of `up`) at heights apart by `MIN_TOP_STEP_M` or more, dealt out to
    those tops: each pixel to the nearest in the image (a side face to the top it rises to
    or falls from). Pieces with one top, or tops at one height (one object's top broken up
    by noise), are kept whole."""
    tops, n = ndimage.label(up & (pieces > 0))
    if n < 2:
        return pieces
    index = np.arange(1, n + 1)
    sizes = ndimage.sum_labels(np.ones(pieces.shape), tops, index)
    height = ndimage.mean(belt.height(np.nan_to_num(xyz)), tops, index)
    spread = np.sqrt(ndimage.mean(noise * noise, tops, index) / np.maximum(sizes, 1))
    big = sizes >= min_pixels
    if big.sum() < 2:
        return pieces
    home = np.array(ndimage.maximum(pieces, tops, index), np.int64)
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
            parted.append((piece, mine + 1))
    if not parted:
        return pieces
    out = pieces.astype(np.int64)
    label = int(pieces.max())
    for piece, own in parted:
        region = pieces == piece
        seeds = np.isin(tops, own)
        _, (rows, cols) = ndimage.distance_transform_edt(~seeds, return_indices=True)
        nearest = tops[rows, cols]
        relabel = np.zeros(n + 1, np.int64)
        relabel[own] = label + 1 + np.arange(own.size)
        label += own.size
        out[region] = relabel[nearest[region]]
    # number the pieces 1..m in order of first appearance, as `kernels.label_pieces` does
    _, first, inverse = np.unique(out.ravel(), return_index=True, return_inverse=True)
    rank = np.empty(first.size, np.int64)
    rank[np.argsort(first)] = np.arange(first.size)
    if out.min() > 0:
        rank += 1
    return rank[inverse].reshape(pieces.shape).astype(np.int32)
