"""Each pixel's range noise in a frame, from its amplitude and intensity.

Shot noise in the four taps scatters the phase by about √B / A (B the intensity, A the
amplitude, spec §7), so a pixel's range noise is k·√B / A. The scale k (the sensor's
gain, the modulation frequency) is fitted on the frame itself, from second differences
along rows: they cancel a surface's slope, and their median is not moved by the few that
straddle an edge. Far, dark or grazing surfaces are noisy and close bright ones are not:
a single threshold in metres cannot serve both.
"""

from __future__ import annotations

import numpy as np

from tofcut._types import F64
from tofcut.driver.frames import Frame
from tofcut.tracker import noise_kernels, stats_kernels
from tofcut.tracker.stats import MAD_TO_SIGMA

FIT_STRIDE = 4


def range_noise(frame: Frame, floor_m: float) -> F64:
    """(H, W) range noise σ of every pixel, metres, at least `floor_m` (inf where invalid).
    The scale is fitted on every FIT_STRIDE-th row: plenty of pairs, a quarter of the work.
    The per-pixel arithmetic is compiled (`noise_kernels`; `tofcut.tracker.reference` holds
    the numpy it replaces)."""
    shape, ratios = noise_kernels.noise_fit(
        frame.intensity, frame.amplitude, frame.valid, frame.range, FIT_STRIDE
    )
    if not ratios.size:
        return np.where(frame.valid, floor_m, np.inf)
    scale = MAD_TO_SIGMA * float(stats_kernels.median(ratios))
    noise: F64 = noise_kernels.noise_scaled(shape, scale, floor_m)
    return noise
