"""How loud a line is: the range noise its belt shows in the first frame, as the tracker
estimates it (`tofcut.tracker.noise`), for splitting a family's scores by it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tofcut.driver.belt import BeltGeometry
from tofcut.driver.capture import CaptureReader
from tofcut.sim.truth import FrameTruth
from tofcut.tracker.background import BackgroundParams
from tofcut.tracker.noise import range_noise

ON_BELT_M = 0.01
"""A pixel shows the belt where its true range is within this of the belt's surface."""
BANDS = (("under 2 cm", 0.0, 0.02), ("2–5 cm", 0.02, 0.05), ("5 cm or more", 0.05, np.inf))
"""The bands of belt noise a family's scores are split by."""


def belt_noise(capture: Path, truth: FrameTruth, belt: BeltGeometry) -> float | None:
    """The median estimated range noise over the pixels of the capture's first frame that
    show the bare belt (from the truth: no object, true range on the belt's surface); None
    where no pixel does."""
    frame = next(iter(CaptureReader(capture).frames()))
    surface = belt.range_along(frame.rays)
    on = (
        frame.valid
        & np.isfinite(surface)
        & (np.abs(truth.range - surface) < ON_BELT_M)
        & (truth.labels == 0)
    )
    if not on.any():
        return None
    noise = range_noise(frame, BackgroundParams().min_sigma_m)
    return float(np.median(noise[on]))


def band(noise: float | None) -> str | None:
    """The name of the band a line's belt noise falls in."""
    if noise is None:
        return None
    return next(name for name, lo, hi in BANDS if lo <= noise < hi)
