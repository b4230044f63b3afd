"""Primitive solids and their ray intersections, vectorised over rays.

Every shape is centred on its local origin (cylinders and capsules along local z), so its
bounding sphere is centred there too. `hit(o, d)` takes the ray origin `o` (3,) and unit
directions `d` (3, N) (one row per axis, for speed) in the shape's local frame and returns
the distance to the first surface (inf where missed) and |cos| of the angle between ray
and surface normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tofcut._types import F64
from tofcut.sim.geometry import Pose

Hit = tuple[F64, F64]


class Shape(Protocol):
    """What the ray caster needs of a solid."""

    def hit(self, o: F64, d: F64) -> Hit: ...

    @property
    def bound_radius(self) -> float: ...

    @property
    def thickness(self) -> float: ...

    @property
    def volume(self) -> float: ...

    def aabb(self, pose: Pose) -> tuple[F64, F64]: ...


def _sphere_hit(o: F64, d: F64, radius: float) -> Hit:
    """First hit of rays with a sphere of `radius` at the local origin."""
    b = o @ d
    disc = b * b - (float(o @ o) - radius * radius)
    root = np.sqrt(np.maximum(disc, 0.0))
    t = -b - root
    t = np.where((disc > 0.0) & (t > 0.0), t, np.inf)
    return t, root / radius


def _side_hit(o: F64, d: F64, radius: float, half: float) -> Hit:
    """First hit with the side of a z-axis cylinder of `radius`, |z| ≤ `half`."""
    dx, dy, dz = d
    a = dx * dx + dy * dy
    b = o[0] * dx + o[1] * dy
    c = o[0] * o[0] + o[1] * o[1] - radius * radius
    disc = b * b - a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-b - root) / a
    z = o[2] + t * dz
    ok = (disc > 0.0) & (a > 1e-18) & (t > 0.0) & (np.abs(z) <= half)
    return np.where(ok, t, np.inf), root / radius


def _nearer(first: Hit, second: Hit) -> Hit:
    """Per ray, the nearer of two hits."""
    take = second[0] < first[0]
    return np.where(take, second[0], first[0]), np.where(take, second[1], first[1])


@dataclass(frozen=True)
class Box:
    """A cuboid with half-sizes (hx, hy, hz) along its local axes."""

    hx: float
    hy: float
    hz: float

    def hit(self, o: F64, d: F64) -> Hit:
        dx, dy, dz = d
        with np.errstate(divide="ignore", invalid="ignore"):
            near = []
            far = []
            for h, oc, dc in ((self.hx, o[0], dx), (self.hy, o[1], dy), (self.hz, o[2], dz)):
                inv = 1.0 / dc
                t1 = (-h - oc) * inv
                t2 = (h - oc) * inv
                near.append(np.minimum(t1, t2))
                far.append(np.maximum(t1, t2))
        t_near = np.maximum(np.maximum(near[0], near[1]), near[2])
        t_far = np.minimum(np.minimum(far[0], far[1]), far[2])
        ok = (t_near <= t_far) & (t_near > 0.0)
        cos = np.where(
            t_near == near[0], np.abs(dx), np.where(t_near == near[1], np.abs(dy), np.abs(dz))
        )
        return np.where(ok, t_near, np.inf), cos

    @property
    def bound_radius(self) -> float:
        return math.sqrt(self.hx**2 + self.hy**2 + self.hz**2)

    @property
    def thickness(self) -> float:
        return 2.0 * min(self.hx, self.hy, self.hz)

    @property
    def volume(self) -> float:
        return 8.0 * self.hx * self.hy * self.hz

    def aabb(self, pose: Pose) -> tuple[F64, F64]:
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        corners = pose.apply(signs * np.array([self.hx, self.hy, self.hz]))
        return corners.min(axis=0), corners.max(axis=0)


@dataclass(frozen=True)
class Sphere:
    """A ball of `radius`."""

    radius: float

    def hit(self, o: F64, d: F64) -> Hit:
        return _sphere_hit(o, d, self.radius)

    @property
    def bound_radius(self) -> float:
        return self.radius

    @property
    def thickness(self) -> float:
        return 2.0 * self.radius

    @property
    def volume(self) -> float:
        return 4.0 / 3.0 * math.pi * self.radius**3

    def aabb(self, pose: Pose) -> tuple[F64, F64]:
        return pose.translation - self.radius, pose.translation + self.radius


def _axis_aabb(pose: Pose, half: float, radius: float, capsule: bool) -> tuple[F64, F64]:
    """Exact AABB of a cylinder (or capsule) of `radius` along local z, |z| ≤ half."""
    axis = pose.rotation[:, 2]
    ends = np.stack([pose.translation - half * axis, pose.translation + half * axis])
    spread = radius * (np.ones(3) if capsule else np.sqrt(np.maximum(1.0 - axis * axis, 0.0)))
    return ends.min(axis=0) - spread, ends.max(axis=0) + spread


@dataclass(frozen=True)
class Cylinder:
    """A solid cylinder along local z: `radius`, length 2·`half_height`, with flat caps."""

    radius: float
    half_height: float

    def hit(self, o: F64, d: F64) -> Hit:
        best = _side_hit(o, d, self.radius, self.half_height)
        dx, dy, dz = d
        for sign in (-1.0, 1.0):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (sign * self.half_height - o[2]) / dz
            px = o[0] + t * dx
            py = o[1] + t * dy
            ok = (t > 0.0) & (px * px + py * py <= self.radius * self.radius)
            best = _nearer(best, (np.where(ok, t, np.inf), np.abs(dz)))
        return best

    @property
    def bound_radius(self) -> float:
        return math.hypot(self.radius, self.half_height)

    @property
    def thickness(self) -> float:
        return 2.0 * min(self.radius, self.half_height)

    @property
    def volume(self) -> float:
        return math.pi * self.radius**2 * 2.0 * self.half_height

    def aabb(self, pose: Pose) -> tuple[F64, F64]:
        return _axis_aabb(pose, self.half_height, self.radius, capsule=False)


@dataclass(frozen=True)
class Capsule:
    """A cylinder of `radius` along local z, |z| ≤ `half_height`, with hemispherical ends."""

    radius: float
    half_height: float

    def hit(self, o: F64, d: F64) -> Hit:
        best = _side_hit(o, d, self.radius, self.half_height)
        for sign in (-1.0, 1.0):
            centre = np.array([0.0, 0.0, sign * self.half_height])
            best = _nearer(best, _sphere_hit(o - centre, d, self.radius))
        return best

    @property
    def bound_radius(self) -> float:
        return self.half_height + self.radius

    @property
    def thickness(self) -> float:
        return 2.0 * self.radius

    @property
    def volume(self) -> float:
        r = self.radius
        return math.pi * r * r * 2.0 * self.half_height + 4.0 / 3.0 * math.pi * r**3

    def aabb(self, pose: Pose) -> tuple[F64, F64]:
        return _axis_aabb(pose, self.half_height, self.radius, capsule=True)


@dataclass(frozen=True)
class Plane:
    """The infinite plane z = 0 of its local frame (background only: floors and walls)."""

    def hit(self, o: F64, d: F64) -> Hit:
        dz = d[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[2] / dz
        return np.where(t > 0.0, t, np.inf), np.abs(dz)

    @property
    def bound_radius(self) -> float:
        return math.inf

    @property
    def thickness(self) -> float:
        return math.inf

    @property
    def volume(self) -> float:
        return math.inf

    def aabb(self, pose: Pose) -> tuple[F64, F64]:
        return np.full(3, -np.inf), np.full(3, np.inf)
