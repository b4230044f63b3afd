"""Raw taps → phase, amplitude, intensity, range, validity and points (spec §7), vectorised.

`demodulate` is the fast path every caller uses; `demodulate_reference` transcribes spec §7
line by line and is what tests hold the fast path to. The fast path: integer tap arithmetic
(exact), the phase as π − atan2(s, −c) (already in [0, 2π), no wrapping pass), the phase
offset wrapped once per camera; the per-pixel arithmetic compiled in one pass either side
of numpy's `arctan2` (`tofcut.driver.demod_kernels`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from tofcut._types import F64
from tofcut.driver.calibration import Calibration, pixel_rays
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.protocol import MAX_COUNT, SPEED_OF_LIGHT, mod_freq_hz

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, eq=False)
class Optics:
    """What demodulation needs from the calibration, computed once per camera."""

    rays: F64
    """Unit ray per pixel, (H, W, 3)."""
    phase_offset: F64
    """Per-pixel phase offset, radians, (H, W)."""
    distance_offset_m: float
    ray_planes: F64 = field(init=False, repr=False)
    """The rays as three contiguous (H, W) planes x, y, z: (3, H, W)."""
    wrapped_offset: F64 = field(init=False, repr=False)
    """The phase offset taken into [0, 2π), so one conditional 2π wraps the corrected phase."""

    def __post_init__(self) -> None:
        planes = np.ascontiguousarray(np.moveaxis(self.rays, -1, 0), dtype=np.float64)
        object.__setattr__(self, "ray_planes", planes)
        wrapped = np.ascontiguousarray(np.mod(self.phase_offset, TWO_PI), dtype=np.float64)
        object.__setattr__(self, "wrapped_offset", wrapped)

    @classmethod
    def from_calibration(cls, calib: Calibration) -> Optics:
        return cls(pixel_rays(calib), calib.phase_offset, calib.distance_offset_m)


def _range_scale(raw: RawFrame) -> float:
    """Metres of range per radian of phase: c / (4π f)."""
    return SPEED_OF_LIGHT / (4.0 * math.pi * mod_freq_hz(raw.header.mod_code))


def demodulate(raw: RawFrame, optics: Optics, amplitude_threshold: float = 0.0) -> Frame:
    """Turn one raw frame into range, amplitude, intensity, a valid mask and points."""
    from tofcut.driver import demod_kernels  # numba: loaded with the first frame

    # a count above the sensor's 14 bits is not a reading (the pixel is invalid); held at
    # full scale, the squares stay exact in int32 instead of overflowing
    taps = np.ascontiguousarray(raw.taps, dtype=np.uint16)
    s, nc, amplitude, intensity, valid = demod_kernels.taps_to_signal(
        taps, float(amplitude_threshold)
    )
    phase: F64 = np.arctan2(s, nc, dtype=np.float64)  # π − this = atan2(s, c) in [0, 2π)
    rng, xyz = demod_kernels.phase_to_points(
        phase, s, nc, optics.wrapped_offset, _range_scale(raw), optics.distance_offset_m,
        optics.ray_planes,
    )  # fmt: skip
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


def demodulate_reference(raw: RawFrame, optics: Optics, amplitude_threshold: float = 0.0) -> Frame:
    """Spec §7 as written, in float64 numpy: the slow form `demodulate` is tested against."""
    taps = raw.taps.astype(np.float64)
    a0, a1, a2, a3 = taps
    s = a3 - a1
    c = a0 - a2
    phase = np.arctan2(s, c)
    phase[phase < 0.0] += TWO_PI
    amplitude = 0.5 * np.hypot(s, c)
    intensity = 0.25 * (a0 + a1 + a2 + a3)
    corrected = np.mod(phase - optics.phase_offset, TWO_PI)
    rng = corrected * _range_scale(raw) - optics.distance_offset_m
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
