"""A pinhole camera's intrinsics: what any depth camera's driver gives, in one value.

The fields are those Open3D's `PinholeCameraIntrinsic` (width, height, fx, fy, cx, cy) and
ROS's `camera_info` (its K) hold, in pixels, with pixel centres at whole numbers as in
OpenCV. `to_json` is what `tofcut convert` writes to `intrinsics.json`; `from_json` reads
that file, Open3D's own (`{"width", "height", "intrinsic_matrix"}`, column-major) or any
mapping with fx, fy, cx, cy.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tofcut._types import F64
from tofcut.driver.calibration import Calibration, pixel_rays
from tofcut.driver.errors import FrameInputError
from tofcut.driver.protocol import MAX_SENSOR_SIDE


def is_whole_number(x: object) -> bool:
    """An int (numpy's too), not a bool."""
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def is_real_number(x: object) -> bool:
    """An int or float (numpy's too), not a bool."""
    return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)


@dataclass(frozen=True, kw_only=True)
class Intrinsics:
    """A pinhole camera (pixels): image size, focal lengths and principal point, checked."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            side = getattr(self, name)
            if not is_whole_number(side) or not 0 < side <= MAX_SENSOR_SIDE:
                raise FrameInputError(
                    f"intrinsics: {name} must be a whole number of pixels in "
                    f"1..{MAX_SENSOR_SIDE}, not {side!r:.40}"
                )
            object.__setattr__(self, name, int(side))
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not is_real_number(value) or not math.isfinite(value):
                raise FrameInputError(
                    f"intrinsics: {name} must be a finite number, not {value!r:.40}"
                )
            object.__setattr__(self, name, float(value))
        if self.fx <= 0 or self.fy <= 0:
            raise FrameInputError(
                f"intrinsics: fx and fy must be positive (pixels), not {self.fx:g}, {self.fy:g}"
            )

    @classmethod
    def from_matrix(cls, k: Any, *, width: int, height: int) -> Intrinsics:
        """From a 3×3 camera matrix K ([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]: OpenCV's,
        pyk4a's `get_camera_matrix`, ROS's K as 9 numbers row by row)."""
        try:
            m = np.asarray(k, dtype=np.float64)
        except (TypeError, ValueError):
            raise FrameInputError("intrinsics: K is not a matrix of numbers") from None
        if m.size != 9:
            raise FrameInputError(f"intrinsics: K must be 3x3 (or 9 numbers), not {m.shape}")
        m = m.reshape(3, 3)
        if not np.isfinite(m).all():
            raise FrameInputError("intrinsics: K holds a value that is not finite")
        if m[0, 1] != 0 or m[1, 0] != 0 or not np.array_equal(m[2], [0.0, 0.0, 1.0]):
            raise FrameInputError(
                "intrinsics: K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)"
            )
        return cls(
            width=width, height=height, fx=m[0, 0], fy=m[1, 1], cx=m[0, 2], cy=m[1, 2]
        )  # fmt: skip

    @classmethod
    def from_json(cls, data: str | bytes | Mapping[str, Any]) -> Intrinsics:
        """From `intrinsics.json` (text or parsed): tofcut's, Open3D's, or fx/fy/cx/cy keys."""
        if isinstance(data, str | bytes):
            try:
                data = json.loads(data)
            except (ValueError, RecursionError) as exc:
                raise FrameInputError(f"intrinsics: not JSON ({exc})") from None
        if not isinstance(data, Mapping):
            raise FrameInputError("intrinsics: the JSON must be an object")
        if "width" not in data or "height" not in data:
            raise FrameInputError("intrinsics: the JSON needs width and height")
        width, height = data["width"], data["height"]
        if all(key in data for key in ("fx", "fy", "cx", "cy")):
            return cls(
                width=width, height=height, fx=data["fx"], fy=data["fy"], cx=data["cx"],
                cy=data["cy"],
            )  # fmt: skip
        if "intrinsic_matrix" in data:
            try:  # Open3D writes K column by column
                k = np.asarray(data["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T
            except (TypeError, ValueError):
                raise FrameInputError("intrinsics: intrinsic_matrix must be 9 numbers") from None
            return cls.from_matrix(k, width=width, height=height)
        raise FrameInputError("intrinsics: the JSON needs fx, fy, cx, cy or intrinsic_matrix")

    @classmethod
    def fitted(cls, calib: Calibration) -> Intrinsics:
        """The pinhole nearest a tofcut camera's lens: least squares of u = fx·x/z + cx
        (and v = fy·y/z + cy) over every pixel centre's ray; exact without distortion."""
        rays = pixel_rays(calib)
        xn, yn = rays[..., 0] / rays[..., 2], rays[..., 1] / rays[..., 2]
        v, u = np.mgrid[0 : calib.height, 0 : calib.width].astype(np.float64)
        fx, cx = np.polyfit(xn.ravel(), u.ravel(), 1)
        fy, cy = np.polyfit(yn.ravel(), v.ravel(), 1)
        return cls(width=calib.width, height=calib.height, fx=fx, fy=fy, cx=cx, cy=cy)

    @property
    def matrix(self) -> F64:
        """K, 3×3."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_json(self) -> dict[str, Any]:
        """Open3D's fields (its `intrinsic_matrix` column-major) and fx, fy, cx, cy."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "intrinsic_matrix": [float(x) for x in self.matrix.T.ravel()],
        }

    def rays(self) -> F64:
        """(H, W, 3) unit rays through the pixel centres (x right, y down, z forward)."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        rays = np.stack(
            [(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], axis=-1
        )
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        return rays
