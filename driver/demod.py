"""Raw taps → phase, amplitude, intensity, range, validity and points (spec §7), vectorised.

`demodulate` is the fast path every caller uses; `demodulate_reference` transcribes spec §7
line by line and is what tests hold the fast path to. The fast path gets its speed from
numpy alone: integer tap arithmetic (exact), the phase as π − atan2(s, −c) (already in
[0, 2π), no wrapping pass), the phase offset wrapped once per camera, and the points written
plane by plane into their (H, W, 3) array.
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
        object.__setattr__(self, "wrapped_offset", np.mod(self.phase_offset, TWO_PI))

    @classmethod
    def from_calibration(cls, calib: Calibration) -> Optics:
        return cls(pixel_rays(calib), calib.phase_offset, calib.distance_offset_m)


def _range_scale(raw: RawFrame) -> float:
    """Metres of range per radian of phase: c / (4π f)."""
    return SPEED_OF_LIGHT / (4.0 * math.pi * mod_freq_hz(raw.header.mod_code))


def demodulate(raw: RawFrame, optics: Optics, amplitude_threshold: float = 0.0) -> Frame:
    """Turn one raw frame into range, amplitude, intensity, a valid mask and points."""
    # a count above the sensor's 14 bits is not a reading (the pixel is invalid below); held
    # at full scale, the squares stay exact in int32 instead of overflowing
    a0, a1, a2, a3 = np.minimum(raw.taps, MAX_COUNT).astype(np.int32)
    s = a3 - a1  # s and −c, exact in int32
    nc = a2 - a0
    phase: F64 = np.arctan2(s, nc, dtype=np.float64)
    np.subtract(math.pi, phase, out=phase)  # π − atan2(s, −c) = atan2(s, c) in [0, 2π)
    squares = s * s  # at most 2 · 16383², exact in int32
    squares += nc * nc
    phase[squares == 0] = 0.0  # no signal: atan2(0, 0) = 0, as the reference has it
    amplitude: F64 = np.sqrt(squares, dtype=np.float64)
    amplitude *= 0.5
    total = a0 + a1
    total += a2
    total += a3
    intensity: F64 = np.multiply(total, 0.25, dtype=np.float64)
    rng = phase - optics.wrapped_offset
    rng += TWO_PI * (rng < 0.0)
    rng *= _range_scale(raw)
    rng -= optics.distance_offset_m
    valid: npt.NDArray[np.bool_] = raw.taps.max(axis=0) < MAX_COUNT
    if amplitude_threshold > 0.0:
        valid &= amplitude >= amplitude_threshold
    xyz: F64 = np.empty((*rng.shape, 3))
    np.multiply(optics.ray_planes, rng, out=np.moveaxis(xyz, -1, 0))
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
