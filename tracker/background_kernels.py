"""The empty-scene model's per-pixel arithmetic, compiled (see `tofcut.tracker.compiled`):
following the scene, and what stands out of it pixel by pixel or by neighbourhood
(`tofcut.tracker.background`).
"""

from __future__ import annotations

import math

import numpy as np

from tofcut._types import F64, I32, U16, B
from tofcut.tracker.compiled import B_2D, F64_2D, F64_3D, I32_2D, U16_2D, kernel


@kernel(
    (
        F64_2D, F64_2D, B_2D, I32_2D, F64_2D, I32_2D, F64_3D, F64_2D, B_2D, B_2D, B_2D, F64_2D,
        1.0, 1.0, 1.0, 1, 1.0, 1.0,
    )
)  # fmt: skip
def follow_scene(
    model: F64, sigma: F64, known: B, farther: I32, farther_min: F64,
    unknown_seen: I32, unknown_reads: F64, seen: F64, valid: B, usable: B,
    hold: B, noise: F64, noise_factor: float, rate: float, min_sigma: float,
    reveal_frames: int, blend_sigmas: float, variance_share: float,
) -> None:  # fmt: skip
    """`BackgroundModel.update`'s per-pixel arithmetic, in place, in one pass (see there):
    `valid` marks the pixels read, `usable` those free to follow, `hold` those not to be
    learned yet, `noise` the frame's range noise; `unknown_reads` (reveal_frames, H, W)
    the last free readings of each pixel not known yet."""
    h, w = model.shape
    run = np.empty(reveal_frames)
    for v in range(h):
        for u in range(w):
            deviation = seen[v, u] - model[v, u]
            use = usable[v, u]
            if valid[v, u] and deviation > noise_factor * sigma[v, u]:
                farther[v, u] += 1
                farther_min[v, u] = min(farther_min[v, u], seen[v, u])
            else:
                farther[v, u] = 0
                farther_min[v, u] = np.inf
            if use and not known[v, u]:
                unknown_reads[unknown_seen[v, u] % reveal_frames, v, u] = seen[v, u]
                unknown_seen[v, u] += 1
            else:
                unknown_seen[v, u] = 0
            newly = unknown_seen[v, u] >= reveal_frames and not hold[v, u]
            revealed = farther[v, u] >= reveal_frames
            # follow only what looks like the same scenery; anything farther off than
            # blend_sigmas is an object's edge or a flying pixel and would widen the noise
            # estimate until real objects no longer stand out of it
            if use and known[v, u] and abs(deviation) <= blend_sigmas * sigma[v, u]:
                model[v, u] += rate * deviation
                var = sigma[v, u] ** 2
                # the spread of a normal cut at ±2.5σ is 0.91 of the whole: undo that bias
                var += rate * (deviation**2 / variance_share - var)
                spread = math.sqrt(var)
                sigma[v, u] = min_sigma if spread < min_sigma else spread
            # back to the nearest of the farther readings: flying pixels only ever read too far
            if revealed:
                model[v, u] = farther_min[v, u]
            if newly:
                # the median of its last free readings: one may be a flying pixel
                for k in range(reveal_frames):
                    run[k] = unknown_reads[k, v, u]
                run.sort()
                half = reveal_frames // 2
                middle = run[half] if reveal_frames % 2 else (run[half - 1] + run[half]) / 2
                model[v, u] = middle
                sigma[v, u] = noise[v, u]
            if revealed or newly:
                farther[v, u] = 0
                farther_min[v, u] = np.inf
            if newly:
                unknown_seen[v, u] = 0
                known[v, u] = True


@kernel((F64_2D, F64_2D, B_2D, F64_2D, B_2D, U16_2D, 1.0, 1.0))
def standing_out(
    model: F64, sigma: F64, known: B, seen: F64, valid: B, labels: U16,
    noise_factor: float, min_height: float,
) -> B:  # fmt: skip
    """`BackgroundModel.standing_out` where `labels` is 0 (what no track took)."""
    h, w = model.shape
    out = np.zeros((h, w), np.bool_)
    for v in range(h):
        for u in range(w):
            if labels[v, u] == 0 and valid[v, u] and known[v, u]:
                nearer = model[v, u] - seen[v, u]
                out[v, u] = nearer > noise_factor * sigma[v, u] and nearer > min_height
    return out


@kernel((F64_2D, F64_2D, B_2D, F64_2D, 1, 1.0, 1.0, 1.0))
def standing_regions(
    model: F64, sigma: F64, usable: B, seen: F64, side: int, sigmas: float, low_share: float,
    min_height: float,
) -> B:  # fmt: skip
    """`tofcut.tracker.background.standing_regions`: the `usable` pixels whose side × side
    neighbourhood (its usable pixels, at least half of it) stands nearer than the scenery
    on average by `sigmas` times that mean's noise, by `low_share` of its pixels' mean noise
    and by `min_height`; summed over the window by running sums (integral images)."""
    h, w = model.shape
    s_n = np.zeros((h + 1, w + 1))
    s_v = np.zeros((h + 1, w + 1))
    s_c = np.zeros((h + 1, w + 1))
    for v in range(h):
        rn = rv = rc = 0.0
        for u in range(w):
            if usable[v, u]:
                rn += model[v, u] - seen[v, u]
                rv += sigma[v, u] * sigma[v, u]
                rc += 1.0
            s_n[v + 1, u + 1] = s_n[v, u + 1] + rn
            s_v[v + 1, u + 1] = s_v[v, u + 1] + rv
            s_c[v + 1, u + 1] = s_c[v, u + 1] + rc
    out = np.zeros((h, w), np.bool_)
    r = side // 2
    for v in range(h):
        v0, v1 = max(v - r, 0), min(v + r + 1, h)
        for u in range(w):
            if not usable[v, u]:
                continue
            u0, u1 = max(u - r, 0), min(u + r + 1, w)
            count = s_c[v1, u1] - s_c[v0, u1] - s_c[v1, u0] + s_c[v0, u0]
            if count < side * side / 2:
                continue
            mean = (s_n[v1, u1] - s_n[v0, u1] - s_n[v1, u0] + s_n[v0, u0]) / count
            if not mean > min_height:
                continue  # the cheap test first: most of a frame is scenery, mean near 0
            mean_var = (s_v[v1, u1] - s_v[v0, u1] - s_v[v1, u0] + s_v[v0, u0]) / count
            beyond_noise = mean > sigmas * math.sqrt(mean_var / count)
            out[v, u] = beyond_noise and mean > low_share * math.sqrt(mean_var)
    return out


@kernel((F64_2D, F64_2D, B_2D, F64_2D, F64_2D, F64_2D, 1.0, 1.0))
def hold_belt(
    model: F64, sigma: F64, known: B, surface: F64, cleared: F64, noise: F64,
    min_sigma: float, min_height: float,
) -> None:  # fmt: skip
    """`BackgroundModel.hold_belt`'s arithmetic, in place, over the known pixels where the
    belt's `surface` is finite: the noise `sigma` at most max(`noise`, `min_sigma`), then the
    range `model` back to what it was (`cleared`, or the belt's surface where that is nan)
    where it came nearer than that by more than max(3 `sigma`, `min_height`) (numpy's
    maximum: nan where either is)."""
    h, w = model.shape
    for v in range(h):
        for u in range(w):
            then = surface[v, u]
            if not (known[v, u] and np.isfinite(then)):
                continue
            if not np.isnan(cleared[v, u]):
                then = cleared[v, u]
            n = noise[v, u]
            cap = n if (np.isnan(n) or n > min_sigma) else min_sigma
            if sigma[v, u] > cap:
                sigma[v, u] = cap
            reach = 3.0 * sigma[v, u]
            if not (np.isnan(reach) or reach > min_height):
                reach = min_height
            if then - model[v, u] > reach:
                model[v, u] = then
