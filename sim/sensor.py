"""The sensor model of spec §7: returned light → four tap counts, with noise and 14-bit limits.

Per sample, the active return is s = responsivity · T · albedo · cos(incidence) / r² ·
falloff (counts); a pixel integrates the phasors s·e^{iφ} of its sub-pixel samples, so a
pixel on a depth edge mixes two ranges (a "flying pixel"), as a real sensor does. Tap k's
mean count is

    A_k = dark + ambient · T · albedo + S + contrast · Re(Q · e^{i k π/2}),

S the mean of s, Q the mean phasor turned by the pixel's phase offset. Each tap then gets
shot noise (variance gain · A_k) and read noise, is rounded, and clipped to 0..16383.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tofcut._types import F64
from tofcut.driver.protocol import MAX_COUNT, SPEED_OF_LIGHT


@dataclass(frozen=True)
class SensorSpec:
    """Radiometric and noise constants of the emulated sensor (a scene file can override them)."""

    responsivity: float = 5500.0
    """Active-light counts per ms of integration from albedo 1, facing the camera, at 1 m."""
    contrast: float = 0.5
    """Demodulation contrast: amplitude A over the active part of the offset."""
    ambient: float = 60.0
    """Background-light counts per ms from albedo 1 (adds to the offset only)."""
    dark: float = 150.0
    """Dark offset of every tap, counts."""
    gain: float = 0.12
    """Counts per photo-electron: shot-noise variance is gain × mean count."""
    read_noise: float = 5.0
    """Read noise, counts rms."""
    falloff_exponent: float = 3.0
    """Illumination and lens fall-off: cos(field angle) to this power."""
    supersample: int = 3
    """Sub-pixel samples per side where depth edges are (mixed pixels)."""
    edge_jump_m: float = 0.05
    """A range step between neighbours larger than this marks a depth edge."""


def phase_of(range_m: F64, distance_offset_m: float, freq_hz: float) -> F64:
    """Phase of the return (before the pixel's offset): 4πf(r + offset)/c, not yet wrapped."""
    return (4.0 * math.pi * freq_hz / SPEED_OF_LIGHT) * (range_m + distance_offset_m)


def active_signal(
    sensor: SensorSpec, integration_ms: float, albedo: F64, cos: F64, range_m: F64, falloff: F64
) -> F64:
    """Active-light counts s of each sample (0 where nothing was hit)."""
    hit = np.isfinite(range_m)
    safe = np.where(hit, range_m, 1.0)
    s = (sensor.responsivity * integration_ms) * albedo * cos * falloff / (safe * safe)
    return np.where(hit, s, 0.0)


def tap_means(
    sensor: SensorSpec,
    integration_ms: float,
    k: int,
    signal: F64,
    albedo: F64,
    q_re: F64,
    q_im: F64,
) -> F64:
    """Expected count of tap k from mean signal S, mean albedo and offset-turned phasor Q."""
    base = sensor.dark + sensor.ambient * integration_ms * albedo + signal
    turn = (q_re, -q_im, -q_re, q_im)[k]  # Re(Q · e^{ikπ/2})
    return base + sensor.contrast * turn


def expose(
    sensor: SensorSpec, means: F64, normals: npt.NDArray[np.floating]
) -> npt.NDArray[np.uint16]:
    """Add shot and read noise to mean counts, round, clip to 14 bits (16383 = saturated)."""
    sigma = np.sqrt(sensor.gain * np.maximum(means, 0.0) + sensor.read_noise**2)
    counts = np.rint(means + sigma * normals)
    out: npt.NDArray[np.uint16] = np.clip(counts, 0, MAX_COUNT).astype(np.uint16)
    return out


def predicted_range_sigma(
    sensor: SensorSpec, intensity: F64, amplitude: F64, freq_hz: float
) -> F64:
    """Standard deviation of decoded range this model predicts, from the mean B and A.

    s = A₃−A₁ and c = A₀−A₂ each have variance 2σ² (σ² = gain·B + read² + 1/12, the cosines
    cancel in pairs), so the phase error is σ/(√2·A) and the range error c/(4πf) times that.
    """
    tap_var = sensor.gain * intensity + sensor.read_noise**2 + 1.0 / 12.0
    return (
        SPEED_OF_LIGHT / (4.0 * math.pi * freq_hz) * np.sqrt(tap_var) / (math.sqrt(2.0) * amplitude)
    )
