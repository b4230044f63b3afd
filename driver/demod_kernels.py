"""Demodulation's per-pixel arithmetic, compiled with numba (one pass each side of numpy's
`arctan2`, which numba would round differently: numpy's is its own vectorised one).

Each kernel does the operations of `tofcut.driver.demod`'s former numpy expressions in the
same order, in float64 and exact int32, so a frame comes out bit for bit as before (a test
holds it to them). Compiled for the arrays the driver passes (uint16 taps, read-only as
parsed off the wire or not), cached on disk; imported on the first frame (`demodulate`), or
ahead of it by the tracker's warm-up.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np

from tofcut._types import F64, B
from tofcut.driver.protocol import MAX_COUNT

F = TypeVar("F", bound=Callable[..., Any])
OPTIONS: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}
"""As the tracker's kernels (`tofcut.tracker.compiled.OPTIONS`)."""

_TAPS = [numba.types.Array(numba.uint16, 3, "C", readonly=r) for r in (False, True)]
_F64_2D = numba.types.Array(numba.float64, 2, "C")
_F64_3D = numba.types.Array(numba.float64, 3, "C")
_I32_2D = numba.types.Array(numba.int32, 2, "C")


def _compiled(*signatures: Any) -> Callable[[F], F]:
    """Compiled for these argument types when the module is imported (from the disk cache
    after the first time)."""

    def compile_(f: F) -> F:
        return cast(F, numba.njit(list(signatures), **OPTIONS)(f))

    return compile_


@_compiled(*[(t, numba.float64) for t in _TAPS])
def taps_to_signal(
    taps: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, F64, F64, B]:
    """From (4, H, W) taps, each held at MAX_COUNT: s = a3 − a1 and −c = a2 − a0 (exact in
    int32, for `arctan2`), the amplitude √(s² + c²) / 2, the intensity (a0 + a1 + a2 + a3) / 4
    and which pixels are valid (no tap at MAX_COUNT or above, and the amplitude at least
    `threshold` where that is above 0)."""
    _, h, w = taps.shape
    s = np.empty((h, w), np.int32)
    nc = np.empty((h, w), np.int32)
    amplitude = np.empty((h, w))
    intensity = np.empty((h, w))
    valid = np.empty((h, w), np.bool_)
    for v in range(h):
        for u in range(w):
            t0, t1, t2, t3 = taps[0, v, u], taps[1, v, u], taps[2, v, u], taps[3, v, u]
            valid[v, u] = max(max(t0, t1), max(t2, t3)) < MAX_COUNT
            a0 = np.int32(min(t0, MAX_COUNT))
            a1 = np.int32(min(t1, MAX_COUNT))
            a2 = np.int32(min(t2, MAX_COUNT))
            a3 = np.int32(min(t3, MAX_COUNT))
            sv, ncv = a3 - a1, a2 - a0
            s[v, u], nc[v, u] = sv, ncv
            amplitude[v, u] = math.sqrt(np.float64(sv * sv + ncv * ncv)) * 0.5
            intensity[v, u] = np.float64(a0 + a1 + a2 + a3) * 0.25
            if threshold > 0.0:
                valid[v, u] = valid[v, u] and amplitude[v, u] >= threshold
    return s, nc, amplitude, intensity, valid


@_compiled((_F64_2D, _I32_2D, _I32_2D, _F64_2D, numba.float64, numba.float64, _F64_3D))
def phase_to_points(
    phase: F64, s: np.ndarray, nc: np.ndarray, offset: F64, scale: float, distance_offset: float,
    planes: F64,
) -> tuple[F64, F64]:  # fmt: skip
    """Given `phase` = atan2(s, −c): the phase as π − that (0 where s = c = 0), in place;
    the range, (phase − `offset`, plus 2π below 0) × `scale` − `distance_offset`; and the
    points, each ray of `planes` (3, H, W) times its range, (H, W, 3)."""
    h, w = phase.shape
    rng = np.empty((h, w))
    xyz = np.empty((h, w, 3))
    two_pi = 2.0 * math.pi
    for v in range(h):
        for u in range(w):
            p = math.pi - phase[v, u]
            if s[v, u] == 0 and nc[v, u] == 0:
                p = 0.0
            phase[v, u] = p
            r = p - offset[v, u]
            r += two_pi if r < 0.0 else 0.0
            r *= scale
            r -= distance_offset
            rng[v, u] = r
            xyz[v, u, 0] = planes[0, v, u] * r
            xyz[v, u, 1] = planes[1, v, u] * r
            xyz[v, u, 2] = planes[2, v, u] * r
    return rng, xyz
