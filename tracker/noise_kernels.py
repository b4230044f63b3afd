"""The range noise's per-pixel arithmetic, compiled (see `tofcut.tracker.compiled`): its
shape from amplitude and intensity, the ratios its scale is fitted on, and the scaled noise
(`tofcut.tracker.noise`).
"""

from __future__ import annotations

import math

import numpy as np

from tofcut._types import F64, B
from tofcut.tracker.compiled import B_2D, F64_2D, kernel


@kernel((F64_2D, F64_2D, B_2D, F64_2D, 1))
def noise_fit(intensity: F64, amplitude: F64, valid: B, rng: F64, stride: int) -> tuple[F64, F64]:
    """`tofcut.tracker.noise.range_noise`'s per-pixel shape of the noise, √max(B, 0) / A
    (inf where invalid or not finite), and its fit's ratios: along every stride-th row,
    each second difference of the range over its spread from the shape, where that spread
    is finite and positive (in row-major order)."""
    h, w = valid.shape
    shape = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            b = intensity[v, u]
            b = b if (b >= 0.0 or b != b) else 0.0
            x = math.sqrt(b) / amplitude[v, u]
            shape[v, u] = x if valid[v, u] and np.isfinite(x) else np.inf
    ratios = np.empty(((h + stride - 1) // stride) * max(w - 2, 0))
    n = 0
    for v in range(0, h, stride):
        for u in range(w - 2):
            s0, s1, s2 = shape[v, u], shape[v, u + 1], shape[v, u + 2]
            spread = math.sqrt(s0**2 + 4.0 * s1**2 + s2**2)
            if np.isfinite(spread) and spread > 0:
                second = rng[v, u] - 2.0 * rng[v, u + 1] + rng[v, u + 2]
                ratios[n] = abs(second) / spread
                n += 1
    return shape, ratios[:n]


@kernel((F64_2D, 1.0, 1.0))
def noise_scaled(shape: F64, scale: float, floor: float) -> F64:
    """`np.maximum(scale * shape, floor)`."""
    h, w = shape.shape
    out = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            x = scale * shape[v, u]
            out[v, u] = x if (x >= floor or x != x) else floor
    return out
