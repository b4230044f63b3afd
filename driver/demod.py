"""Raw taps → phase, amplitude, intensity, range, validity and points (spec §7), vectorised."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tofcut.driver.calibration import Calibration, pixel_rays
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.protocol import MAX_COUNT, SPEED_OF_LIGHT, mod_freq_hz

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, eq=False)
class Optics:
    """What demodulation needs from the calibration, computed once per camera."""

    rays: npt.NDArray[np.float64]
    """Unit ray per pixel, (H, W, 3)."""
    phase_offset: npt.NDArray[np.float64]
    """Per-pixel phase offset, radians, (H, W)."""
    distance_offset_m: float

    @classmethod
    def from_calibration(cls, calib: Calibration) -> Optics:
        return cls(pixel_rays(calib), calib.phase_offset, calib.distance_offset_m)


def demodulate(raw: RawFrame, optics: Optics, amplitude_threshold: float = 0.0) -> Frame:
    """Turn one raw frame into range, amplitude, intensity, a valid mask and points."""
    taps = raw.taps.astype(np.float64)
    a0, a1, a2, a3 = taps
    s = a3 - a1
    c = a0 - a2
    phase = np.arctan2(s, c)
    phase[phase < 0.0] += TWO_PI
    amplitude = 0.5 * np.hypot(s, c)
    intensity = 0.25 * (a0 + a1 + a2 + a3)
    corrected = np.mod(phase - optics.phase_offset, TWO_PI)
    scale = SPEED_OF_LIGHT / (4.0 * math.pi * mod_freq_hz(raw.header.mod_code))
    rng = corrected * scale - optics.distance_offset_m
    valid: npt.NDArray[np.bool_] = np.all(raw.taps < MAX_COUNT, axis=0)
    if amplitude_threshold > 0.0:
        valid &= amplitude >= amplitude_threshold
    xyz = optics.rays * rng[..., None]
    return Frame(
        header=raw.header,
        host_time_ns=raw.host_time_ns,
        phase=phase,
        amplitude=amplitude,
        intensity=intensity,
        range=rng,
        valid=valid,
        xyz=xyz,
    )
