"""Objects on a belt told apart by their tops: what faces up, at one height, is one object.

Seen from above and to one side, a tall box's side face runs on into the top of a lower box
pressed against it with no step in range, so a cut at 3D steps keeps the two as one piece.
Their tops do not touch: between them stands the side face, which does not face up. A piece
holding two tops of its own at different heights is two objects; its pixels are dealt out to
the tops, each to the nearest not below it (`split_by_tops`). The other way round, two tracks
that meet with no step and hold no two tops at different heights are faces of one object
(`one_object`), and so are two where one lies over the other's footprint and rises to its
top (`sides_of`): a side seen at a slant, across a step that foreshortening makes. Range
cannot part two objects of one height pressed flush together: they stay one.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from tofcut._types import F64, I32, I64, U16, B
from tofcut.driver.belt import BeltGeometry
from tofcut.tracker import components_kernels, stats_kernels, tops_kernels
from tofcut.tracker.neighbours import DU, DV

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
SEAM_SAMPLES = 24
"""Pairs along a seam whose surfaces are compared (evenly spread)."""
CONCAVE = 0.2
"""A seam bends inwards where the convexity criterion is below minus this (about 0.7 across a
right-angled crease, near 0 on a flat surface read in noise)."""
MIN_TOP = 20
"""Pixels facing up that make a top."""
MAX_SLOPE_NOISE = 0.2
"""Where the noise of the measured slope is more than this (a flat top would read steep
one time in a hundred), the slope is taken over a longer span."""
MAX_BASELINE = 12
"""The longest span the slope is taken over: where even that leaves the slope's noise above
`MAX_SLOPE_NOISE`, no surface is told facing up (a top narrower than the span is lost to
the steep faces round it)."""


def facing_up(body: B, xyz: F64, noise: F64, belt: BeltGeometry) -> B | None:
    """The pixels of `body` on surfaces facing up from the belt (their slope below
    `MAX_SLOPE`), over `BASELINE` pixels or, where the range noise makes that slope
    meaningless, over the shortest span up to `MAX_BASELINE` that makes it mean something
    (the slope's noise falls as the span grows); None where none does."""
    up, *ratios = tops_kernels.facing_pixels(body, xyz, noise, belt.normal, BASELINE, MAX_SLOPE)
    if not any(stats_kernels.median_above(r, MAX_SLOPE_NOISE) for r in ratios):
        return up
    worst = max(float(np.median(r)) if r.size else 0.0 for r in ratios)
    span = BASELINE * worst / MAX_SLOPE_NOISE
    if not span <= MAX_BASELINE:  # also a nan
        return None
    up, *ratios = tops_kernels.facing_pixels(
        body, xyz, noise, belt.normal, math.ceil(span), MAX_SLOPE
    )
    if any(stats_kernels.median_above(r, MAX_SLOPE_NOISE) for r in ratios):
        return None
    return up


def split_by_tops(
    pieces: I32, up: B, xyz: F64, noise: F64, belt: BeltGeometry, min_pixels: int
) -> I32:
    """`pieces` (labelled 1..n), where a piece holds two tops or more of `min_pixels`
    (connected parts of `up`) at heights apart by `MIN_TOP_STEP_M` or more, dealt out to
    those tops: each pixel to the nearest in the image not below it (a side face to the top
    it rises to or falls from, `_nearest_under`). Pieces with one top, or tops at one height
    (one object's top broken up by noise), are kept whole."""
    tops = components_kernels.label_pieces(up & (pieces > 0))
    n = int(tops.max())
    if n < 2:
        return pieces
    size, height, noise2, home = tops_kernels.top_stats(
        tops, n, pieces, xyz, noise, belt.origin, belt.normal
    )
    big = size >= min_pixels
    big[0] = False
    if big.sum() < 2:
        return pieces
    spread = np.sqrt(noise2 / np.maximum(size, 1))
    parted = []
    for piece in np.nonzero(np.bincount(home[big]) >= 2)[0].tolist():  # two big tops or more
        mine = np.nonzero(big & (home == piece))[0]
        h, s = height[mine], spread[mine]
        if heights_apart(h[:, None], s[:, None], h[None, :], s[None, :]).any():
            parted.append((piece, mine))
    if not parted:
        return pieces
    out = pieces.astype(np.int64)
    label = int(pieces.max())
    for piece, own in parted:
        region = pieces == piece
        out[region] = label + 1 + _nearest_under(region, tops, own, height[own], xyz, noise, belt)
        label += own.size
    # number the pieces 1..m in order of first appearance, as `label_pieces` does; what is
    # no piece stays 0 wherever it first appears (a piece may hold the frame's first pixel)
    ids, first, inverse = np.unique(out.ravel(), return_index=True, return_inverse=True)
    first[ids == 0] = -1
    rank = np.empty(first.size, np.int64)
    rank[np.argsort(first)] = np.arange(first.size)
    if ids[0] > 0:
        rank += 1
    return rank[inverse].reshape(pieces.shape).astype(np.int32)


def _nearest_under(
    region: B, tops: I32, own: I64, heights: F64, xyz: F64, noise: F64, belt: BeltGeometry
) -> I64:
    """For each pixel of `region`, which of the tops `own` (their labels in `tops`, at
    `heights`) it goes to (0, 1, ...): the nearest in the image of those not below it. No
    pixel of an object stands higher than its top, so the face of a tall box rising from a
    low one's top goes to the tall one, however near the low top it is; a pixel above every
    top (within three times its noise, or `MIN_TOP_STEP_M`) goes to the nearest."""
    rows, cols = np.nonzero(region)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    box = tops[r0:r1, c0:c1]
    far = np.stack([
        ndimage.distance_transform_edt(box != k)[rows - r0, cols - c0] for k in own.tolist()
    ])  # fmt: skip
    h = belt.height(xyz[rows, cols])
    slack = np.maximum(MIN_TOP_STEP_M, 3.0 * noise[rows, cols])
    not_below = heights[:, None] >= h[None, :] - slack[None, :]
    some = not_below.any(axis=0)
    nearest: I64 = np.where(some, np.where(not_below, far, np.inf), far).argmin(axis=0)
    return nearest


def heights_apart(h1: F64 | float, s1: F64 | float, h2: F64 | float, s2: F64 | float) -> B:
    """Whether tops at heights `h1` and `h2` (the noise of each height: `s1`, `s2`) are at
    two heights: `MIN_TOP_STEP_M` apart, or three times the noise of their difference where
    that is more (elementwise)."""
    return np.asarray(np.abs(h1 - h2) >= np.maximum(MIN_TOP_STEP_M, 3.0 * np.hypot(s1, s2)))


def one_object(
    labels: U16, xyz: F64, up: B | None, belt: BeltGeometry, joined_m: float
) -> list[tuple[int, int]]:
    """Pairs of labels (smaller first) whose masks meet along a seam where most neighbours
    across it are within `joined_m` in 3D (one surface going on, no step: `seamless`) and
    which do not hold tops at heights apart by `MIN_TOP_STEP_M` (`level`; `up`: the pixels
    facing up; None, as where the noise hides the slope, tells no tops): two tracks
    holding faces of one object."""
    return level(seamless(labels, xyz, joined_m), labels, up, xyz, belt)


@dataclass(frozen=True, eq=False)
class Meetings:
    """Where two labels of a label image meet (`tops_kernels.meetings`): the first pixel of
    each neighbouring pair held by two labels, the pair's direction, and its two labels as
    one key, the smaller times `base` plus the larger."""

    base: int
    rows: I64
    cols: I64
    ks: I64
    keys: I64


def meetings(labels: U16) -> Meetings:
    """Where the labels of `labels` meet, found once for `seamless` and `sides_of`."""
    base = int(labels.max()) + 1
    return Meetings(base, *tops_kernels.meetings(labels, base))


def seamless(
    labels: U16, xyz: F64, joined_m: float, met: Meetings | None = None
) -> list[tuple[int, int]]:
    """Pairs of labels (smaller first) whose masks meet along a seam of `MIN_SEAM` pairs or
    more, most of them within `joined_m` in 3D, at a convex edge (`_convex`); `met`: where
    they meet, if already found."""
    met = met or meetings(labels)
    base, rows, cols, ks, keys = met.base, met.rows, met.cols, met.ks, met.keys
    if not keys.size:
        return []
    ends = np.stack([rows, cols, rows + DV[ks], cols + DU[ks]], axis=1)
    joined = np.linalg.norm(xyz[rows, cols] - xyz[ends[:, 2], ends[:, 3]], axis=-1) <= joined_m
    pairs, first_at, inverse, meet_n = np.unique(
        keys, return_index=True, return_inverse=True, return_counts=True
    )
    joined_n = np.bincount(inverse[joined], minlength=pairs.size)
    out = []
    for r in np.argsort(first_at).tolist():  # in the order the scan first meets them
        if (
            meet_n[r] >= MIN_SEAM
            and joined_n[r] * 2 >= meet_n[r]
            and _convex(labels, xyz, ends[(inverse == r) & joined].tolist())
        ):  # not convex: a crease, two objects pressed together
            out.append(divmod(int(pairs[r]), base))
    return out


def level(
    pairs: list[tuple[int, int]], labels: U16, up: B | None, xyz: F64, belt: BeltGeometry
) -> list[tuple[int, int]]:
    """Those of `pairs` of labels whose masks do not hold tops (`MIN_TOP` pixels of `up`)
    at heights apart by `MIN_TOP_STEP_M`; all of them where `up` is None."""
    if up is None:
        return pairs
    out = []
    for x, y in pairs:
        hx, hy = (
            top_height((labels == x) & up, xyz, belt),
            top_height((labels == y) & up, xyz, belt),
        )
        if hx is None or hy is None or not abs(hx - hy) >= MIN_TOP_STEP_M:
            out.append((x, y))
    return out


def top_height(top: B, xyz: F64, belt: BeltGeometry) -> float | None:
    """The median height of a top's pixels (facing up), if it has `MIN_TOP` of them."""
    if np.count_nonzero(top) < MIN_TOP:
        return None
    return float(np.median(belt.height(xyz[top])))


def _convex(labels: U16, xyz: F64, seam: list[list[int]]) -> bool:
    """Whether two masks meet at a convex edge along `seam` (pairs of neighbouring pixels,
    one in each): the convexity criterion of locally convex connected patches (Stein et al.,
    in PCL), (n₁ − n₂)·(c₁ − c₂) ≥ 0 for the normals and centroids of each side's surface
    round the pair, in most of the pairs looked at. A box's faces meet at convex edges, two
    objects pressed together at a concave crease."""
    step = max(1, len(seam) // SEAM_SAMPLES)
    votes = []
    for v1, u1, v2, u2 in seam[::step]:
        sides = []
        for v, u in ((v1, u1), (v2, u2)):
            win = np.s_[max(v - 2, 0) : v + 3, max(u - 2, 0) : u + 3]
            pts = xyz[win][labels[win] == labels[v, u]]
            pts = pts[np.isfinite(pts).all(axis=1)]
            if len(pts) < 4:
                break
            centre = pts.mean(axis=0)
            normal = np.linalg.svd(pts - centre, full_matrices=False)[2][2]
            if normal @ centre > 0:
                normal = -normal  # towards the camera
            sides.append((centre, normal))
        if len(sides) == 2:
            (c1, n1), (c2, n2) = sides
            gap = float(np.linalg.norm(c1 - c2))
            if gap > 0:
                votes.append(float((n1 - n2) @ (c1 - c2)) / gap)
    if not votes:
        return True
    return float(np.median(votes)) >= -CONCAVE


SIDE_SHARE = 0.8
"""Share of a track's points that must lie over another's footprint for it to be a side."""


def sides_of(
    labels: U16,
    xyz: F64,
    noise: F64,
    belt: BeltGeometry,
    known: Collection[tuple[int, int]] = (),
    met: Meetings | None = None,
) -> list[tuple[int, int]]:
    """Pairs of labels (smaller first), other than the `known` ones, whose masks meet, where
    the one with fewer pixels lies, as seen along the belt's normal, over the other's
    footprint (`SIDE_SHARE` of its points within the noise of it) and rises to the other's
    top: a side face of the other, seen at a slant across a step that foreshortening makes.
    An object beside another, even one pressed against it, stands on its own footprint, and
    a lower one stops short of the other's top. `met`: where the labels meet, if already
    found."""
    met = met or meetings(labels)
    base = met.base
    pairs, seam = np.unique(met.keys, return_counts=True)
    out = []
    boxes = ndimage.find_objects(labels) if (seam >= MIN_SEAM).any() else []
    for key in pairs[seam >= MIN_SEAM].tolist():
        x, y = divmod(key, base)
        if (x, y) in known:
            continue
        rows, cols = _union(boxes[x - 1], boxes[y - 1])
        win = labels[rows, cols]
        side, of = _smaller_first(win == x, win == y)
        if _side(side, of, xyz[rows, cols], noise[rows, cols], belt):
            out.append((x, y))
    return out


def _union(a: tuple[slice, slice] | None, b: tuple[slice, slice] | None) -> tuple[slice, slice]:
    """The smallest box holding two labels' boxes (both labels are present)."""
    assert a is not None
    assert b is not None
    return (
        slice(min(a[0].start, b[0].start), max(a[0].stop, b[0].stop)),
        slice(min(a[1].start, b[1].start), max(a[1].stop, b[1].stop)),
    )


def _smaller_first(a: B, b: B) -> tuple[B, B]:
    """The two masks, the one with fewer pixels first."""
    return (a, b) if np.count_nonzero(a) < np.count_nonzero(b) else (b, a)


def _side(side: B, of: B, xyz: F64, noise: F64, belt: BeltGeometry) -> bool:
    """Whether the mask `side` is a side face of the object in `of` (`sides_of`)."""
    reach = max(0.02, float(np.median(noise[side])))
    ps, po = xyz[side], xyz[of]
    feet = np.column_stack((belt.along(ps), belt.across(ps)))
    under = np.column_stack((belt.along(po), belt.across(po)))
    # what lies within reach of the footprint lies within reach of its box: most pairs, side by
    # side, are told here
    near = (feet >= under.min(axis=0) - reach) & (feet <= under.max(axis=0) + reach)
    if near.all(axis=1).mean() < SIDE_SHARE:
        return False
    # a side rises to the other's top, where it meets it: a lower object beside stops short
    rise = np.percentile(belt.height(ps), 95) - np.percentile(belt.height(po), 90)
    if rise < -2.0 * reach:
        return False
    gap, _ = cKDTree(under).query(feet, distance_upper_bound=reach)
    return bool(np.isfinite(gap).mean() >= SIDE_SHARE)
