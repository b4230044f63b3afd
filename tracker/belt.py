"""Where the conveyor belt is, as the installation knows it: its plane and direction of travel."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class BeltGeometry:
    """The belt's top surface in camera coordinates (metres): measured once per installation."""

    point: F64
    """A point on the middle line of the belt's top surface."""
    direction: F64
    """Unit vector of travel."""
    normal: F64
    """Unit normal of the top surface, pointing up (away from the belt)."""
    width_m: float

    def __post_init__(self) -> None:
        for name in ("point", "direction", "normal"):
            v = np.asarray(getattr(self, name), float)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ValueError(f"BeltGeometry.{name} must be three finite numbers")
            object.__setattr__(self, name, v)
        if self.width_m <= 0:
            raise ValueError(f"belt width must be positive, got {self.width_m}")
        for name in ("direction", "normal"):
            v = getattr(self, name)
            object.__setattr__(self, name, v / np.linalg.norm(v))

    def over_belt(self, points: F64) -> npt.NDArray[np.bool_]:
        """Whether points (..., 3) lie within the belt's width, seen along its normal."""
        across = np.cross(self.normal, self.direction)
        with np.errstate(invalid="ignore"):
            return np.abs((points - self.point) @ across) <= self.width_m / 2

    def range_along(self, rays: F64) -> F64:
        """Distance along each unit ray (..., 3) to the belt's top surface; inf where the ray
        misses the belt's width or runs away from it."""
        across = np.cross(self.normal, self.direction)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.point @ self.normal) / (rays @ self.normal)
            hit = rays * t[..., None]
            lateral = np.abs((hit - self.point) @ across)
            return np.where((t > 0) & (lateral <= self.width_m / 2), t, np.inf)
