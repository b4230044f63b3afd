"""The belt as values: one reading of the conveyor controller, the belt's geometry in camera
coordinates, and a short history of readings that answers "where was the belt at time t".

Times are host times in ns since the Unix epoch (`time.time_ns()`), the clock that stamps
camera frames (`Frame.host_time_ns`), so frames and belt readings can be matched directly.
"""

from __future__ import annotations

import bisect
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from tofcut.driver.errors import ConfigError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class BeltReading:
    """What the conveyor controller said at one moment."""

    time_ns: int
    """Host time of the reading: the middle of the request's round trip."""
    count: int
    """The encoder register as read (unsigned, wraps at 2³²)."""
    distance_m: float
    """Belt travel since the client's first reading (unwrapped encoder counts / counts per m)."""
    speed_mps: float
    """The speed register, m/s (positive: the belt's direction of travel)."""
    running: bool
    fault: bool


@dataclass(frozen=True, eq=False)
class BeltGeometry:
    """Where the belt is in camera coordinates (metres): the frame rejects are measured in.

    `origin` is the zero of along-belt positions: the point of the belt's top surface on the
    camera's optical axis, so "the diverter is 1.5 m downstream of the camera" means 1.5 m
    along `direction` from there.
    """

    direction: F64
    """(3,) unit vector of travel, in the belt plane."""
    normal: F64
    """(3,) unit normal of the belt's top surface, pointing up (away from the belt)."""
    origin: F64
    """(3,) the belt's top surface on the optical axis."""

    @classmethod
    def from_plane(cls, direction: F64, normal: F64, point: F64) -> BeltGeometry:
        """From any point of the belt's top surface; `direction` is projected into the plane."""
        n = np.asarray(normal, dtype=np.float64)
        d = np.asarray(direction, dtype=np.float64)
        p = np.asarray(point, dtype=np.float64)
        if n.shape != (3,) or d.shape != (3,) or p.shape != (3,):
            raise ConfigError("belt direction, normal and point must each have 3 components")
        n_len = float(np.linalg.norm(n))
        if not n_len > 0:
            raise ConfigError("the belt's normal must not be zero")
        n = n / n_len
        d = d - float(d @ n) * n
        d_len = float(np.linalg.norm(d))
        if not d_len > 1e-6:
            raise ConfigError("the belt's direction of travel must not be along its normal")
        d = d / d_len
        if abs(n[2]) < 1e-6:
            raise ConfigError("the camera's optical axis is parallel to the belt")
        origin = np.array([0.0, 0.0, float(n @ p) / n[2]])
        return cls(d, n, origin)

    def along(self, points: F64) -> F64:
        """Position along the belt (m downstream of the origin) of (..., 3) points."""
        return np.asarray((points - self.origin) @ self.direction, dtype=np.float64)

    def across(self, points: F64) -> F64:
        """Position across the belt (m, along normal × direction) of (..., 3) points."""
        side = np.cross(self.normal, self.direction)
        return np.asarray((points - self.origin) @ side, dtype=np.float64)

    def height(self, points: F64) -> F64:
        """Height above the belt's top surface (m) of (..., 3) points."""
        return np.asarray((points - self.origin) @ self.normal, dtype=np.float64)


def unwrap_count(previous: int | None, previous_raw: int | None, raw: int, bits: int = 32) -> int:
    """The unwrapped encoder count after `raw`, taking the shortest way round from the last one.

    An encoder register wraps at 2^bits; between two polls the belt moves far less than half
    of that, so the signed difference modulo 2^bits is the true step (forward or backward).
    """
    if previous is None or previous_raw is None:
        return raw
    span = 1 << bits
    step = (raw - previous_raw) % span
    if step >= span // 2:
        step -= span
    return previous + step


class BeltHistory:
    """The last readings, oldest first; answers the belt's state at any recent host time.

    Not thread-safe: its owner (the conveyor client) locks around it.
    """

    def __init__(self, capacity: int, max_extrapolation_s: float = 0.5) -> None:
        if capacity < 2:
            raise ConfigError(f"a belt history needs room for 2 readings or more, not {capacity}")
        self._readings: deque[BeltReading] = deque(maxlen=capacity)
        self._max_extrapolation_ns = round(max_extrapolation_s * 1e9)

    def __len__(self) -> int:
        return len(self._readings)

    def append(self, reading: BeltReading) -> None:
        """Add a reading; readings must come in time order."""
        if self._readings and reading.time_ns < self._readings[-1].time_ns:
            raise ValueError("belt readings must be appended in time order")
        self._readings.append(reading)

    def latest(self) -> BeltReading | None:
        return self._readings[-1] if self._readings else None

    def at(self, time_ns: int) -> BeltReading | None:
        """The belt's state at a host time: None before the first reading or too long after
        the last one (the link is down: better no answer than a stale one).

        Between readings the distance is interpolated linearly in time (the encoder is the
        truth); past the last one it is extrapolated with the last speed, for at most
        `max_extrapolation_s`. Count, speed and flags are those of the reading before `time_ns`.
        """
        readings = self._readings
        if not readings or time_ns < readings[0].time_ns:
            return None
        last = readings[-1]
        if time_ns >= last.time_ns:
            dt_ns = time_ns - last.time_ns
            if dt_ns > self._max_extrapolation_ns:
                return None
            moved = last.speed_mps * dt_ns * 1e-9
            return replace(last, time_ns=time_ns, distance_m=last.distance_m + moved)
        i = bisect.bisect_right(readings, time_ns, key=lambda r: r.time_ns)
        before, after = readings[i - 1], readings[i]
        span = after.time_ns - before.time_ns
        w = (time_ns - before.time_ns) / span if span > 0 else 0.0
        distance = before.distance_m + w * (after.distance_m - before.distance_m)
        return replace(before, time_ns=time_ns, distance_m=distance)
