"""A constant-velocity Kalman filter in 3D, with the belt's velocity as an optional prior.

State: position and velocity in camera coordinates (metres, m/s). Measurements: the 3D
centroid of the object's points. Where the conveyor's speed is known, the velocity is also
"measured" as the belt velocity, with the uncertainty of the belt reading: objects ride
the belt, so they keep the belt's pace through occlusion.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from tofcut._types import F64
from tofcut.tracker.belt_prior import VelocityPrior
from tofcut.tracker.errors import SegmentError


@dataclass(frozen=True)
class MotionParams:
    """Noise levels of the constant-velocity model."""

    accel_sigma: float = 0.5
    """Random acceleration, m/s²: how fast an object may change its velocity."""
    measure_sigma_m: float = 0.01
    """Noise of a measured centroid, metres."""
    initial_speed_sigma: float = 0.5
    """Velocity uncertainty of a new track, m/s."""

    def __post_init__(self) -> None:
        if min(self.accel_sigma, self.measure_sigma_m, self.initial_speed_sigma) <= 0:
            raise SegmentError("motion noise levels must be positive")


_POSITION = slice(0, 3)
_VELOCITY = slice(3, 6)


@functools.lru_cache(maxsize=8)
def _transition(dt: float, accel_sigma: float) -> tuple[F64, F64]:
    """The state transition over dt seconds and its process noise (frames come at a steady
    rate, so the few recent ones are kept)."""
    f = np.eye(6)
    f[:3, 3:] = np.eye(3) * dt
    q = accel_sigma**2
    block = np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]]) * q
    f.flags.writeable = False
    qm = np.asarray(np.kron(block, np.eye(3)), np.float64)
    qm.flags.writeable = False
    return f, qm


_EYE6 = np.eye(6)
_EYE6.flags.writeable = False


@functools.lru_cache(maxsize=8)
def _isotropic(sigma: float) -> F64:
    """`np.eye(3) * sigma**2`, made once for each of the few noise levels (read-only)."""
    out = np.eye(3) * sigma**2
    out.flags.writeable = False
    return out


class ConstantVelocity:
    """One object's 3D position and velocity."""

    def __init__(self, position: F64, params: MotionParams, velocity: F64 | None = None) -> None:
        self.params = params
        self.x = np.concatenate([np.asarray(position, float), np.zeros(3)])
        if velocity is not None:
            self.x[3:] = velocity
        self.P = np.diag([params.measure_sigma_m**2] * 3 + [params.initial_speed_sigma**2] * 3)

    @property
    def position(self) -> F64:
        return self.x[:3].copy()

    @property
    def velocity(self) -> F64:
        return self.x[3:].copy()

    def predict(self, dt: float) -> None:
        """Move the state on by dt seconds."""
        if dt <= 0:
            return
        f, qm = _transition(dt, self.params.accel_sigma)
        self.x = f @ self.x
        self.P = f @ self.P @ f.T + qm

    def correct(self, centroid: F64, sigma_m: float | None = None) -> None:
        """Take a measured centroid into the state."""
        s = self.params.measure_sigma_m if sigma_m is None else sigma_m
        self._update(_POSITION, np.asarray(centroid), s)

    def follow_belt(self, prior: VelocityPrior) -> None:
        """Take the belt's velocity as a measurement of the object's velocity."""
        if prior.informed:
            self._update(_VELOCITY, prior.mean, prior.cov)

    def _update(self, part: slice, z: F64, sigma: float | F64) -> None:
        """Kalman update from a measurement of `part` of the state (position or velocity):
        with H that part's selection, H·x, H·P·Hᵀ, P·Hᵀ and K·H are those entries of x, P
        and K themselves, exactly, so they are taken rather than multiplied out."""
        r = _isotropic(sigma) if isinstance(sigma, float) else sigma
        innovation = z - self.x[part]
        s = self.P[part, part] + r
        k = np.ascontiguousarray(self.P[:, part]) @ np.linalg.inv(s)
        self.x = self.x + k @ innovation
        kh = np.zeros((6, 6))
        kh[:, part] = k
        self.P = (_EYE6 - kh) @ self.P
