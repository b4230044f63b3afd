"""Telling tops apart, compiled (see `tofcut.tracker.compiled`): which pixels lie on steep
surfaces, and each top's size, height, noise and piece (`tofcut.tracker.tops`).
"""

from __future__ import annotations

import math

import numpy as np

from tofcut._types import F64, I32, I64, U16, B
from tofcut.tracker.box_kernels import box_of, pixels_of
from tofcut.tracker.compiled import B_2D, F64_1D, F64_2D, F64_3D, I32_2D, U16_2D, kernel


@kernel((B_2D, F64_3D, F64_2D, F64_1D, 1, 1.0))
def facing_pixels(
    body: B, xyz: F64, noise: F64, normal: F64, baseline: int, max_slope: float
) -> tuple[B, F64, F64]:
    """`tofcut.tracker.tops.facing_up`'s arithmetic: the pixels of `body` with a finite depth
    (`where`) less those on steep surfaces: of `where`'s points averaged over 3×3, the
    pixels on a span of `baseline` pixels (along a row or a column) whose rise along
    `normal` is more than `max_slope` times their spacing across it; and, per direction,
    each pair's slope noise (a 3×3 mean's noise twice, over the spacing). Only the box of
    `body` is gone over: every pixel and pair it weighs lies in it."""
    h, w = body.shape
    r0, r1, c0, c1 = box_of(body)
    up = np.zeros((h, w), np.bool_)
    if r1 <= r0:
        return up, np.empty(0), np.empty(0)
    where = np.zeros((r1 - r0, c1 - c0), np.bool_)  # within the box
    for v in range(r0, r1):
        for u in range(c0, c1):
            where[v - r0, u - c0] = body[v, u] and np.isfinite(xyz[v, u, 2])
    # the 3×3 means, at `where`'s pixels only: from a padded copy of its points and 1s,
    # 0 elsewhere (a sum begun at +0 is not changed by adding 0: the same sums, in the same
    # order, without a test for each neighbour)
    padded = np.zeros((r1 - r0 + 2, c1 - c0 + 2, 4))
    for v in range(r1 - r0):
        for u in range(c1 - c0):
            if where[v, u]:
                for a in range(3):
                    padded[v + 1, u + 1, a] = xyz[v + r0, u + c0, a]
                padded[v + 1, u + 1, 3] = 1.0
    pts = np.empty((r1 - r0, c1 - c0, 3))
    for v in range(r1 - r0):
        for u in range(c1 - c0):
            if not where[v, u]:
                continue
            n = sx = sy = sz = 0.0
            for v2 in range(v, v + 3):
                for u2 in range(u, u + 3):
                    sx += padded[v2, u2, 0]
                    sy += padded[v2, u2, 1]
                    sz += padded[v2, u2, 2]
                    n += padded[v2, u2, 3]
            pts[v, u, 0], pts[v, u, 1], pts[v, u, 2] = sx / n, sy / n, sz / n
    steep = np.zeros((r1 - r0, c1 - c0), np.bool_)
    ratios = np.empty((2, (r1 - r0) * (c1 - c0)))
    counts = np.zeros(2, np.int64)
    share = math.sqrt(2.0) / 3.0
    for axis in range(2):
        dv, du = (baseline, 0) if axis == 0 else (0, baseline)
        for v in range(r1 - r0 - dv):
            for u in range(c1 - c0 - du):
                if not (where[v, u] and where[v + dv, u + du]):
                    continue
                d0 = pts[v + dv, u + du, 0] - pts[v, u, 0]  # far end less near end
                d1 = pts[v + dv, u + du, 1] - pts[v, u, 1]
                d2 = pts[v + dv, u + du, 2] - pts[v, u, 2]
                rise = d0 * normal[0] + d1 * normal[1] + d2 * normal[2]
                a0, a1, a2 = d0 - rise * normal[0], d1 - rise * normal[1], d2 - rise * normal[2]
                spacing = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
                ratios[axis, counts[axis]] = noise[v + r0, u + c0] * share / max(spacing, 1e-6)
                counts[axis] += 1
                if abs(rise) > max_slope * spacing:
                    for k in range(baseline + 1):
                        steep[v + k * dv // baseline, u + k * du // baseline] = True
    for v in range(r1 - r0):
        for u in range(c1 - c0):
            up[v + r0, u + c0] = where[v, u] and not steep[v, u]
    return up, ratios[0, : counts[0]].copy(), ratios[1, : counts[1]].copy()


@kernel((I32_2D, 1, I32_2D, F64_3D, F64_2D, F64_1D, F64_1D))
def top_stats(
    tops: I32, n: int, pieces: I32, xyz: F64,
    noise: F64, origin: F64, normal: F64,
) -> tuple[I64, F64, F64, I64]:  # fmt: skip
    """Per top 1..n (index 0 unused): its pixels, mean height along `normal` above `origin`,
    the mean of its pixels' noise², and the piece it lies in."""
    size = np.zeros(n + 1, np.int64)
    height = np.zeros(n + 1)
    noise2 = np.zeros(n + 1)
    home = np.zeros(n + 1, np.int64)
    h, w = tops.shape
    for v in range(h):
        for u in range(w):
            t = tops[v, u]
            if t == 0:
                continue
            size[t] += 1
            height[t] += (
                (xyz[v, u, 0] - origin[0]) * normal[0] + (xyz[v, u, 1] - origin[1]) * normal[1]
                + (xyz[v, u, 2] - origin[2]) * normal[2]
            )  # fmt: skip
            noise2[t] += noise[v, u] ** 2
            home[t] = pieces[v, u]
    for t in range(1, n + 1):
        if size[t]:
            height[t] /= size[t]
            noise2[t] /= size[t]
    return size, height, noise2, home


@kernel((U16_2D, 1))
def meetings(labels: U16, base: int) -> tuple[I64, I64, I64, I64]:
    """Where two labels meet: every pair of a pixel and its right neighbour, then every pair
    of a pixel and the one below (`neighbours.OFFSETS` 0 and 1), held by two different
    labels other than 0, each direction's in row-major order (`np.nonzero`'s) of its first
    pixel: that pixel's row and column, the pair's direction, and its two labels as one
    key, the smaller times `base` (more than any label) plus the larger. Only the labelled
    pixels are gone over (`pixels_of`)."""
    h, w = labels.shape
    count, at_v, at_u = pixels_of(labels)
    rows = np.empty(2 * count, np.int64)
    cols = np.empty(2 * count, np.int64)
    ks = np.empty(2 * count, np.int64)
    keys = np.empty(2 * count, np.int64)
    m = 0
    for k in range(2):
        dv, du = (0, 1) if k == 0 else (1, 0)
        for i in range(count):
            v, u = at_v[i], at_u[i]
            if v + dv < h and u + du < w:
                a, b = np.int64(labels[v, u]), np.int64(labels[v + dv, u + du])
                if a != b and b > 0:
                    rows[m], cols[m], ks[m] = v, u, k
                    keys[m] = min(a, b) * base + max(a, b)
                    m += 1
    return rows[:m], cols[:m], ks[:m], keys[:m]
