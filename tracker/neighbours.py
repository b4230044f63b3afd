"""A pixel's 8 neighbours, defined once for the tracker and the paper's segmentation, and
the sides of the image a region reaches (`sides_reached`).

Each undirected pair of 8-neighbours is met once along one of the four forward directions,
`OFFSETS` (east, south, south-east, south-west): a (4, H, W) array of pair weights holds at
[k, v, u] the pair of (v, u) and (v, u) + OFFSETS[k]. A diagonal pair's centres are √2
apart.
"""

from __future__ import annotations

import math

import numpy as np

OFFSETS: tuple[tuple[int, int], ...] = ((0, 1), (1, 0), (1, 1), (1, -1))
"""(dv, du) of the four forward 8-neighbour directions: east, south, south-east, south-west."""
DIRECTIONS: tuple[tuple[int, int], ...] = OFFSETS + tuple((-dv, -du) for dv, du in OFFSETS)
"""All 8 neighbour directions: OFFSETS (forward), then their opposites (backward)."""
DV = np.array([dv for dv, _ in DIRECTIONS], dtype=np.int64)
DU = np.array([du for _, du in DIRECTIONS], dtype=np.int64)
"""DIRECTIONS' rows and columns, as compiled loops index them (forward ones first)."""
DIAGONAL = (False, False, True, True)
"""Which of OFFSETS are diagonal."""
FACTORS = np.array([1 / math.sqrt(2) if diagonal else 1.0 for diagonal in DIAGONAL])
"""The tracker's weight factor of a pair along each of OFFSETS: a diagonal counts 1/√2."""
EIGHT = np.ones((3, 3), bool)
"""The 8-connected structuring element, for `scipy.ndimage` (labelling, dilation, erosion)."""

Region = tuple[slice, slice]


def pair_slices(shape: tuple[int, int], k: int) -> tuple[Region, Region]:
    """Slices (p, q) selecting every pixel p whose neighbour q = p + OFFSETS[k] is in frame."""
    h, w = shape
    dv, du = OFFSETS[k]
    rows_p, rows_q = slice(0, h - dv), slice(dv, h)
    if du >= 0:
        cols_p, cols_q = slice(0, w - du), slice(du, w)
    else:
        cols_p, cols_q = slice(-du, w), slice(0, w + du)
    return (rows_p, cols_p), (rows_q, cols_q)


def sides_reached(region: Region, shape: tuple[int, int], margin: int = 0) -> int:
    """How many of the image's four sides a region (bounding slices) comes within `margin`
    pixels of: one or more, something coming into view; two, something running across it."""
    rows, cols = region
    return (
        int(rows.start <= margin) + int(cols.start <= margin)
        + int(rows.stop >= shape[0] - margin) + int(cols.stop >= shape[1] - margin)
    )  # fmt: skip
