"""Rigid poses and rotations: the maths that places scene objects in the camera frame.

World frame of the scene files: x along the belt, y across it, z up, metres. Camera frame
(spec §7): x right, y down, z forward. A `Pose` maps local coordinates into its parent frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tofcut._types import F64


@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid transform: parent = rotation @ local + translation."""

    rotation: F64
    translation: F64

    @staticmethod
    def identity() -> Pose:
        """The pose that changes nothing."""
        return Pose(np.eye(3), np.zeros(3))

    def compose(self, inner: Pose) -> Pose:
        """self ∘ inner: first `inner`, then `self`."""
        return Pose(
            self.rotation @ inner.rotation, self.rotation @ inner.translation + self.translation
        )

    def apply(self, points: F64) -> F64:
        """Map local points (..., 3) into the parent frame."""
        return points @ self.rotation.T + self.translation

    def inverse(self) -> Pose:
        """The transform from the parent frame back into the local one."""
        rt = self.rotation.T
        return Pose(rt, -(rt @ self.translation))

    def matrix(self) -> F64:
        """The 4×4 homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.translation
        return m


def axis_angle(axis: F64 | list[float], angle_rad: float) -> F64:
    """Rotation matrix about a (not necessarily unit) axis, Rodrigues' formula."""
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    rot: F64 = np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)
    return rot


def rotation_xyz_deg(angles: F64 | list[float]) -> F64:
    """Rotate about x, then y, then z (fixed axes), angles in degrees: Rz @ Ry @ Rx."""
    rx, ry, rz = (math.radians(float(a)) for a in angles)
    return axis_angle([0, 0, 1], rz) @ axis_angle([0, 1, 0], ry) @ axis_angle([1, 0, 0], rx)


def look_at(position: F64, target: F64, up: F64) -> Pose:
    """Camera-from-world pose of a camera at `position` looking at `target` (x right, y down)."""
    z = np.asarray(target, np.float64) - position
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("camera looks along its up vector")
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z])
    return Pose(rot, -(rot @ np.asarray(position, np.float64)))
