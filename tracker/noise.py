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
import numpy.typing as npt

from tofcut.driver.frames import Frame

F64 = npt.NDArray[np.float64]

MAD_TO_SIGMA = 1.4826
"""A normal variable's σ over its median absolute value."""
FIT_STRIDE = 4


def range_noise(frame: Frame, floor_m: float) -> F64:
    """(H, W) range noise σ of every pixel, metres, at least `floor_m` (inf where invalid).
    The scale is fitted on every FIT_STRIDE-th row: plenty of pairs, a quarter of the work."""
    with np.errstate(divide="ignore", invalid="ignore"):
        shape = np.sqrt(np.maximum(frame.intensity, 0.0)) / frame.amplitude
    shape[~frame.valid | ~np.isfinite(shape)] = np.inf
    r, s = frame.range[::FIT_STRIDE], shape[::FIT_STRIDE]
    second = r[:, :-2] - 2.0 * r[:, 1:-1] + r[:, 2:]
    spread = np.sqrt(s[:, :-2] ** 2 + 4.0 * s[:, 1:-1] ** 2 + s[:, 2:] ** 2)
    usable = np.isfinite(spread) & (spread > 0)
    if not usable.any():
        return np.where(frame.valid, floor_m, np.inf)
    scale = MAD_TO_SIGMA * float(np.median(np.abs(second[usable]) / spread[usable]))
    return np.maximum(scale * shape, floor_m)
