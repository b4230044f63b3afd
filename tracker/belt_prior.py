"""The belt's velocity as a prior for the tracker: objects on a belt move with it.

`belt_velocity_prior(reading, direction)` turns the conveyor's latest (or interpolated)
reading into a 3D velocity in camera coordinates with its covariance: tight along the belt
(the encoder knows the speed), looser across it (objects slide and turn a little), and
wide open when there is no reading, it is too old, or the controller reports a fault.
Without an encoder, `known_speed_prior(belt)` gives the belt's nominal speed, less tightly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofcut._types import F64
from tofcut.driver.belt import BeltReading, KnownBelt

KNOWN_SPEED_SIGMA_MPS = 0.02
"""How sure the tracker is of a belt's speed as a scene, a capture or a finder gives it, m/s."""


@dataclass(frozen=True, eq=False)
class VelocityPrior:
    """A Gaussian prior on a track's velocity, camera coordinates."""

    mean: F64
    """(3,) m/s."""
    cov: F64
    """(3, 3) (m/s)²."""
    informed: bool
    """False when there was no usable belt reading (the prior is then only a bound)."""


def belt_velocity_prior(
    reading: BeltReading | None,
    direction: F64,
    *,
    time_ns: int | None = None,
    speed_sigma_mps: float = 0.005,
    cross_sigma_mps: float = 0.02,
    accel_mps2: float = 0.5,
    max_age_s: float = 1.0,
    unknown_sigma_mps: float = 1.0,
) -> VelocityPrior:
    """The velocity prior at `time_ns` (default: the reading's time) from a belt reading.

    Along the belt the standard deviation grows from `speed_sigma_mps` by `accel_mps2` per
    second of the reading's age: the belt can have sped up or slowed down since.
    """
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    age_s = 0.0 if reading is None or time_ns is None else (time_ns - reading.time_ns) * 1e-9
    if reading is None or reading.fault or abs(age_s) > max_age_s:
        return VelocityPrior(np.zeros(3), np.eye(3) * unknown_sigma_mps**2, informed=False)
    along = speed_sigma_mps + accel_mps2 * abs(age_s)
    dd = np.outer(d, d)
    cov = along**2 * dd + cross_sigma_mps**2 * (np.eye(3) - dd)
    return VelocityPrior(reading.speed_mps * d, cov, informed=True)


def known_speed_prior(
    belt: KnownBelt, sigma_mps: float = KNOWN_SPEED_SIGMA_MPS
) -> VelocityPrior | None:
    """The prior from a belt's known speed, where there is no encoder: the belt's velocity,
    `sigma_mps` either way (the speed is a nominal one, not a reading); None without a speed."""
    if belt.speed_mps is None:
        return None
    return VelocityPrior(
        belt.geometry.direction * belt.speed_mps, np.eye(3) * sigma_mps**2, informed=True
    )
