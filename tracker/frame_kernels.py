"""Checking a frame before the tracker takes it, compiled (see `tofcut.tracker.compiled`)."""

from __future__ import annotations

import numpy as np

from tofcut._types import F64
from tofcut.tracker.compiled import F64_2D, F64_3D, kernel


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
