"""A small analytic scene for driver tests: a tilted plane with spheres, taps per spec §7.

The physically based scenes live in the renderer; this one is tiny, exact and fast, so
driver tests can check decoded range against a closed-form truth at any sensor size.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from tofcut.driver.calibration import Calibration, pixel_rays
from tofcut.driver.protocol import MAX_COUNT, SPEED_OF_LIGHT, TAPS, mod_freq_hz
from tofcut.sim.source import Exposure, Rendered


def pattern_calibration(width: int, height: int, seed: int = 0) -> Calibration:
    """SR4000-like optics scaled to the sensor size, with distortion and phase offsets."""
    rng = np.random.default_rng(seed)
    f = 1.42 * width
    offsets = rng.normal(0.0, 300.0, (height, width)).round().astype(np.int16)
    return Calibration(
        width, height, 1, f, f, (width - 1) / 2 + 0.3, (height - 1) / 2 - 0.2,
        -0.18, 0.04, 0.0008, -0.0006, 0.0, 0.011, offsets,
    )  # fmt: skip


class TestPattern:
    """A plane 1.5–2.5 m away, tilted, with spheres drifting across it."""

    __test__ = False  # not a pytest class

    def __init__(
        self,
        width: int = 32,
        height: int = 24,
        *,
        seed: int = 0,
        noise_counts: float = 4.0,
        amplitude_counts: float = 2000.0,
        offset_counts: float = 4000.0,
    ) -> None:
        self._calibration = pattern_calibration(width, height, seed)
        self._rays = pixel_rays(self._calibration)
        self.seed = seed
        self.noise_counts = noise_counts
        self.amplitude_counts = amplitude_counts
        self.offset_counts = offset_counts

    @property
    def calibration(self) -> Calibration:
        return self._calibration

    def true_range(self, t_s: float) -> npt.NDArray[np.float64]:
        """Radial distance of every pixel at time t: the nearest hit of plane and spheres."""
        rays = self._rays
        normal = np.array([0.0, -0.3, -1.0]) / math.hypot(0.3, 1.0)
        plane_point = np.array([0.0, 0.0, 2.0])
        r: npt.NDArray[np.float64] = (normal @ plane_point) / (rays @ normal)
        for centre, radius in self._spheres(t_s):
            b = rays @ centre
            disc = b * b - (centre @ centre - radius * radius)
            hit = disc > 0
            near = b - np.sqrt(np.where(hit, disc, 0.0))
            r = np.where(hit & (near > 0) & (near < r), near, r)
        return r

    @staticmethod
    def _spheres(t_s: float) -> list[tuple[npt.NDArray[np.float64], float]]:
        x = -0.6 + 0.4 * (t_s % 3.0)
        return [(np.array([x, 0.0, 1.6]), 0.2), (np.array([0.3, -0.3, 1.8]), 0.15)]

    def render(self, exposure: Exposure) -> Rendered:
        calib = self._calibration
        f = mod_freq_hz(exposure.mod_code)
        rng = np.random.default_rng([self.seed, exposure.sequence])
        taps = np.empty((TAPS, calib.height, calib.width))
        for k in range(TAPS):
            r = self.true_range(exposure.tap_time_s(k))
            phase = 4 * math.pi * f * (r + calib.distance_offset_m) / SPEED_OF_LIGHT
            phase += calib.phase_offset
            amp = self.amplitude_counts * (2.0 / r) ** 2 * exposure.integration_s / 3.3e-3
            taps[k] = self.offset_counts + amp * np.cos(phase + k * math.pi / 2)
        taps += rng.normal(0.0, self.noise_counts, taps.shape)
        counts = np.clip(np.rint(taps), 0, MAX_COUNT).astype(np.uint16)
        truth = self.true_range(exposure.tap_time_s(0) + 1.5 * exposure.tap_interval_s)
        return Rendered(counts, truth)
