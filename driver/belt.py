"""The belt as values: one reading of the conveyor controller, the belt's geometry in camera
coordinates, and a short history of readings that answers "where was the belt at time t".

Times are host times in ns since the Unix epoch (`time.time_ns()`), the clock that stamps
camera frames (`Frame.host_time_ns`), so frames and belt readings can be matched directly.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from tofcut._types import F64
from tofcut.driver.errors import ConfigError

MAX_BELT_SPEED_MPS = 10.0
"""No conveyor runs faster than this; a larger speed is damage, not a reading."""
MAX_BELT_RANGE_M = 100.0
"""A belt read back from a file lies within this distance of the camera (and is no wider)."""


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
    """The belt's top surface in camera coordinates (metres): the one belt type of the package.

    The tracker puts the empty belt under objects with it, the rejects measure positions along
    it. `origin` is the zero of along-belt positions: the point of the top surface on the
    camera's optical axis, so "the diverter is 1.5 m downstream of the camera" means 1.5 m
    along `direction` from there.
    """

    point: F64
    """(3,) a point of the top surface: on the belt's centre line where `width_m` is known."""
    direction: F64
    """(3,) unit vector of travel, in the belt plane."""
    normal: F64
    """(3,) unit normal of the top surface, pointing up (towards the camera)."""
    width_m: float | None = None
    """The belt's width; None where it is not known (the belt then has no sides)."""

    def __post_init__(self) -> None:
        for name in ("point", "direction", "normal"):
            v = np.array(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ConfigError(f"the belt's {name} must be three finite numbers")
            object.__setattr__(self, name, v)
        n_len = float(np.linalg.norm(self.normal))
        if not n_len > 1e-9:
            raise ConfigError("the belt's normal must not be zero")
        n = self.normal / n_len
        if float(n @ self.point) > 0:
            n = -n  # up is towards the camera, which sees the surface from its front
        d = self.direction - float(self.direction @ n) * n
        d_len = float(np.linalg.norm(d))
        if not d_len > 1e-6 * max(1.0, float(np.linalg.norm(self.direction))):
            raise ConfigError(
                "the belt's direction of travel must not be along its normal, nor zero"
            )
        if abs(n[2]) < 1e-6:
            raise ConfigError("the camera's optical axis is parallel to the belt")
        if self.width_m is not None and not (math.isfinite(self.width_m) and self.width_m > 0):
            raise ConfigError(f"the belt's width must be a positive number, not {self.width_m}")
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "direction", d / d_len)
        object.__setattr__(self, "origin", np.array([0.0, 0.0, float(n @ self.point) / n[2]]))
        object.__setattr__(self, "side", np.cross(self.normal, self.direction))

    origin: F64 = field(init=False, repr=False)
    """(3,) the top surface on the optical axis."""
    side: F64 = field(init=False, repr=False)
    """(3,) normal × direction: across the belt (made once, not on every `across`)."""

    @classmethod
    def from_plane(
        cls, direction: F64, normal: F64, point: F64, width_m: float | None = None
    ) -> BeltGeometry:
        """From any point of the top surface (its centre line, when a width is given);
        `direction` is projected into the plane."""
        return cls(point, direction, normal, width_m)

    def along(self, points: F64) -> F64:
        """Position along the belt (m downstream of the origin) of (..., 3) points."""
        return np.asarray((points - self.origin) @ self.direction, dtype=np.float64)

    def across(self, points: F64) -> F64:
        """Position across the belt (m, along normal × direction) of (..., 3) points."""
        return np.asarray((points - self.origin) @ self.side, dtype=np.float64)

    def height(self, points: F64) -> F64:
        """Height above the belt's top surface (m) of (..., 3) points."""
        return np.asarray((points - self.origin) @ self.normal, dtype=np.float64)

    def over_belt(self, points: F64) -> npt.NDArray[np.bool_]:
        """Whether points (..., 3) lie within the belt's width, seen along its normal (all
        do where the width is not known)."""
        if self.width_m is None:
            return np.ones(np.shape(points)[:-1], bool)
        with np.errstate(invalid="ignore"):
            return np.abs((points - self.point) @ self.side) <= self.width_m / 2

    def range_along(self, rays: F64) -> F64:
        """Distance along each unit ray (..., 3) to the belt's top surface; inf where the ray
        misses the belt's width or runs away from it."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.point @ self.normal) / (rays @ self.normal)
            hit = self.over_belt(rays * t[..., None])
            return np.where((t > 0) & hit, t, np.inf)

    def to_dict(self) -> dict[str, Any]:
        """The geometry as plain numbers (capture metadata, a conveyor map's `[belt]`)."""
        out: dict[str, Any] = {
            "point": self.point.tolist(),
            "direction": self.direction.tolist(),
            "normal": self.normal.tolist(),
        }
        if self.width_m is not None:
            out["width_m"] = self.width_m
        return out


@dataclass(frozen=True, eq=False)
class KnownBelt:
    """What a run knows of its belt: where it is, its speed when that is known, and from where."""

    geometry: BeltGeometry
    speed_mps: float | None = None
    """Belt speed along `geometry.direction`; None where only the geometry is known."""
    source: str = "given"
    """Where it came from: "map", "scene", "capture", "found", "given" (the Python API)."""

    def __post_init__(self) -> None:
        if self.speed_mps is not None and not (
            math.isfinite(self.speed_mps) and abs(self.speed_mps) <= MAX_BELT_SPEED_MPS
        ):
            raise ConfigError(
                f"the belt's speed must be a number within ±{MAX_BELT_SPEED_MPS} m/s, "
                f"not {self.speed_mps}"
            )

    def to_dict(self) -> dict[str, Any]:
        """As capture metadata carries it: the geometry's numbers and `speed_mps`."""
        out = self.geometry.to_dict()
        if self.speed_mps is not None:
            out["speed_mps"] = self.speed_mps
        return out

    @classmethod
    def from_dict(cls, doc: object, source: str) -> KnownBelt:
        """From capture metadata or a map's `[belt]` table; ConfigError if any value is off."""
        if not isinstance(doc, dict):
            raise ConfigError("the belt must be a table of point, direction, normal")
        unknown = set(doc) - {"point", "direction", "normal", "width_m", "speed_mps"}
        if unknown:
            raise ConfigError(f"the belt has unknown keys: {', '.join(sorted(unknown))}")
        point, direction, normal = (_vector(doc, k) for k in ("point", "direction", "normal"))
        if float(np.abs(point).max()) > MAX_BELT_RANGE_M:
            raise ConfigError(f"the belt's point is more than {MAX_BELT_RANGE_M:g} m away")
        for name, v in (("direction", direction), ("normal", normal)):
            if not 1e-9 < float(np.abs(v).max()) < 1e9:
                raise ConfigError(f"the belt's {name} must not be zero (nor absurdly long)")
        width, speed = doc.get("width_m"), doc.get("speed_mps")
        for name, value in (("width_m", width), ("speed_mps", speed)):
            if value is not None and (
                isinstance(value, bool) or not isinstance(value, int | float)
            ):
                raise ConfigError(f"the belt's {name} must be a number, not {_short(value)}")
        if width is not None and not width <= MAX_BELT_RANGE_M:
            raise ConfigError(
                f"the belt's width must be a positive number up to {MAX_BELT_RANGE_M:g} m, "
                f"not {width}"
            )
        geometry = BeltGeometry(point, direction, normal, None if width is None else float(width))
        return cls(geometry, None if speed is None else float(speed), source)


def _vector(doc: dict[str, Any], key: str) -> F64:
    """Three finite real numbers (JSON or TOML: no booleans, no strings) from a belt table."""
    if key not in doc:
        raise ConfigError(f"the belt has no {key}")
    value = doc[key]
    if not (
        isinstance(value, list | tuple)
        and len(value) == 3
        and all(isinstance(x, int | float) and not isinstance(x, bool) for x in value)
    ):
        raise ConfigError(f"the belt's {key} must be a list of three numbers, not {_short(value)}")
    v = np.array(value, dtype=np.float64)
    if not np.isfinite(v).all():
        raise ConfigError(f"the belt's {key} must be three finite numbers, not {_short(value)}")
    return v


def _short(value: object, limit: int = 60) -> str:
    """A value for a one-line message: its repr, cut short."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


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

    def before(self, time_ns: int) -> BeltReading | None:
        """The last reading taken at or before `time_ns`, as read (None if there is none)."""
        i = bisect.bisect_right(self._readings, time_ns, key=lambda r: r.time_ns)
        return self._readings[i - 1] if i else None

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
