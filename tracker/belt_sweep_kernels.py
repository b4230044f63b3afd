"""Scoring the layers a belt may be, compiled (see `tofcut.tracker.compiled`): how many
pixels each layer saw swept (`tofcut.tracker.belt_sweep`).
"""

from __future__ import annotations

import numpy as np

from tofcut._types import F32, F64, I64, B
from tofcut.tracker.compiled import B_2D, F32_2D, F64_1D, kernel


@kernel((F32_2D, B_2D, F32_2D, F32_2D, F64_1D, F64_1D, 1))
def sweep_scores(
    heights: F32, ok: B, reach: F32, band: F32, offsets: F64, tallest: F64, min_times: int
) -> tuple[I64, I64, F64, I64]:  # fmt: skip
    """For each layer (`offsets`, n·p) over (samples, pixels) heights: the pixels seen on it
    (within `band`), above it (by more than `reach`, by at most the layer's `tallest`) in at
    least `min_times` samples each and below it in fewer; the count and sum of squares of the
    heights seen on it; and, for each pair (k, j), how many of the pixels swept over layer k
    were seen on layer j as often."""
    samples, pixels = heights.shape
    layers = offsets.size
    swept = np.zeros(layers, np.int64)
    on = np.zeros(layers, np.int64)
    squares = np.zeros(layers)
    at = np.zeros(layers, np.int64)
    up = np.zeros(layers, np.int64)
    down = np.zeros(layers, np.int64)
    shared = np.zeros((layers, layers), np.int64)
    for i in range(pixels):
        at[:] = 0
        up[:] = 0
        down[:] = 0
        for t in range(samples):
            if not ok[t, i]:
                continue
            for k in range(layers):
                d = heights[t, i] - offsets[k]
                if abs(d) < band[t, i]:
                    at[k] += 1
                    squares[k] += d * d
                elif d > tallest[k]:
                    continue
                elif d > reach[t, i]:
                    up[k] += 1
                elif d < -reach[t, i]:
                    down[k] += 1
        for k in range(layers):
            on[k] += at[k]
            if at[k] >= min_times and up[k] >= min_times and down[k] < min_times:
                swept[k] += 1
                for j in range(layers):
                    if j != k and at[j] >= min_times:
                        shared[k, j] += 1
    return swept, on, squares, shared
