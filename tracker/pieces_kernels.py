"""What stands out, in pieces: its loud ranges quietened and the cut at 3D steps between
neighbours, compiled (see `tofcut.tracker.compiled`).
"""

from __future__ import annotations

import numpy as np

from tofcut._types import F64, B
from tofcut.tracker.box_kernels import pixels_of
from tofcut.tracker.compiled import B_2D, F64_1D, F64_2D, F64_3D, kernel
from tofcut.tracker.stats_kernels import median_in


@kernel((B_2D, F64_3D, F64_2D, 1.0, F64_2D, True))
def cut_at_steps(body: B, xyz: F64, rng: F64, step2: float, noise: F64, step_noise: bool) -> B:
    """`body` less every pixel on the far side of a 3D step to its right or lower neighbour
    of more than √step2 and, given `step_noise`, more than three times the noise of their
    difference, √(9·noise² of the one + 9·noise² of the other) (of a step, the pixel with
    the larger range is the far one)."""
    h, w = body.shape
    out = body.copy()
    count, at_v, at_u = pixels_of(body)
    for i in range(count):  # only pairs with an end in the body can leave something out
        v0, u0 = at_v[i], at_u[i]
        # its pairs right, down, left and up, each with its upper-left pixel first (the
        # one left out on a tie); a pair left or up from the body is met from there
        for v, u, v2, u2 in (
            (v0, u0, v0, u0 + 1), (v0, u0, v0 + 1, u0),
            (v0, u0 - 1, v0, u0), (v0 - 1, u0, v0, u0),
        ):  # fmt: skip
            if v < 0 or u < 0 or v2 >= h or u2 >= w or (v2 == v0 and u2 == u0 and body[v, u]):
                continue
            a = xyz[v, u, 0] - xyz[v2, u2, 0]
            b = xyz[v, u, 1] - xyz[v2, u2, 1]
            c = xyz[v, u, 2] - xyz[v2, u2, 2]
            if step_noise:  # 9.0 * noise**2 each, as numpy squares: n * n
                n1, n2 = noise[v, u], noise[v2, u2]
                allowed = max(step2, 9.0 * (n1 * n1) + 9.0 * (n2 * n2))
            else:
                allowed = max(step2, 0.0)
            if a**2 + b**2 + c**2 > allowed:
                if rng[v, u] > rng[v2, u2]:
                    out[v, u] = False
                else:
                    out[v2, u2] = False
    return out


@kernel((F64_3D, F64_2D, F64_2D, B_2D, 1.0, F64_1D, 1.0))
def quieten(
    xyz: F64, rng: F64, noise: F64, body: B, step_m: float, shares: F64, apart: float
) -> tuple[F64, F64, F64]:
    """`tofcut.tracker.pieces.quietened`'s arithmetic: where `body`'s pixels are loud (their
    noise a third of `step_m` or more), each one's range is the median of its neighbours in
    `body` within the smallest radius r (1 to len(shares) − 1) that brings its noise times
    `shares[r]` below `step_m` / `apart` (the largest where none does), its point moved along
    its ray from the range it had to that one (not at range 0), and its noise so shared;
    copies of `xyz`, `rng` and `noise` so changed (the arrays themselves where none is loud).
    The loud pixels are listed as they are found, and only they are gone over again."""
    top = shares.size - 1
    count, at_v, at_u = pixels_of(body)
    loud = np.empty(count, np.int64)  # which of them, in row-major order
    radius = np.empty(count, np.int64)
    n = 0
    for i in range(count):
        v, u = at_v[i], at_u[i]
        if noise[v, u] * 3.0 >= step_m:
            r = 1
            while r < top and noise[v, u] * shares[r] * apart >= step_m:
                r += 1
            loud[n], radius[n] = i, r
            n += 1
    if n == 0:
        return xyz, rng, noise
    window = np.empty((2 * top + 1) ** 2)
    medians = np.empty(n)
    for k in range(n):  # from the ranges as read, before any is changed
        medians[k] = median_in(rng, body, at_v[loud[k]], at_u[loud[k]], radius[k], window)
    out = xyz.copy()
    median = rng.copy()
    quiet = noise.copy()
    for k in range(n):
        v, u = at_v[loud[k]], at_u[loud[k]]
        median[v, u] = medians[k]
        quiet[v, u] *= shares[radius[k]]
        if rng[v, u] != 0:
            ratio = medians[k] / rng[v, u]
            out[v, u, 0] *= ratio
            out[v, u, 1] *= ratio
            out[v, u, 2] *= ratio
    return out, median, quiet
