"""Checking a frame before the tracker takes it, and taking the points of a mask, compiled
(see `tofcut.tracker.compiled`)."""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, B
from tofcut.tracker.compiled import B_2D, F64_2D, F64_3D, kernel


@kernel((F64_2D, F64_3D))
def all_finite(rng: F64, xyz: F64) -> bool:
    """Whether every range and every coordinate of every point is finite, as
    `np.isfinite(rng).all() and np.isfinite(xyz).all()`, in one pass that stops at the
    first that is not."""
    h, w = rng.shape
    for v in range(h):
        for u in range(w):
            if not (
                np.isfinite(rng[v, u])
                and np.isfinite(xyz[v, u, 0])
                and np.isfinite(xyz[v, u, 1])
                and np.isfinite(xyz[v, u, 2])
            ):
                return False
    return True


@kernel((F64_3D, B_2D, 1, 1))
def points_in(xyz: F64, mask: B, top: int, left: int) -> F64:
    """(N, 3) the points of `mask`, a mask of the window of `xyz` whose first pixel is
    (top, left), in row-major order: `xyz[top:top + h, left:left + w][mask]` (numpy's
    boolean indexing of the (H, W, 3) points by an (H, W) mask is five times slower)."""
    h, w = mask.shape
    n = 0
    for v in range(h):
        for u in range(w):
            n += mask[v, u]
    out = np.empty((n, 3))
    k = 0
    for v in range(h):
        for u in range(w):
            if mask[v, u]:
                out[k, 0] = xyz[top + v, left + u, 0]
                out[k, 1] = xyz[top + v, left + u, 1]
                out[k, 2] = xyz[top + v, left + u, 2]
                k += 1
    return out
