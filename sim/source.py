"""What the emulated camera asks of a scene: the taps of one exposure, and its ground truth."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from tofcut.driver.calibration import Calibration


@dataclass(frozen=True)
class Exposure:
    """When and how the sensor takes one frame; times are device time in seconds."""

    sequence: int
    t0_s: float
    """Start of tap 0."""
    tap_interval_s: float
    """From the start of one tap to the start of the next."""
    integration_s: float
    """Exposure time of each tap."""
    mod_code: int

    def tap_time_s(self, k: int) -> float:
        """Middle of tap k's exposure: where a moving scene is sampled for that tap."""
        return self.t0_s + k * self.tap_interval_s + 0.5 * self.integration_s


@dataclass(frozen=True, eq=False)
class Rendered:
    """One exposure as the sensor saw it."""

    taps: npt.NDArray[np.uint16]
    """(4, H, W) raw counts, 14-bit, 16383 = saturated."""
    truth: Any = None
    """The scene's ground truth for this exposure (see `tofcut.sim` scenes), or None."""


class TapSource(Protocol):
    """A scene the emulated camera can look at."""

    @property
    def calibration(self) -> Calibration:
        """The true lens, phase offsets and distance offset; the camera's flash holds this."""
        ...

    def render(self, exposure: Exposure) -> Rendered:
        """Taps for one exposure; deterministic for a given source seed and sequence number."""
        ...
