"""A scene as values: camera, sensor, belt, background surfaces and moving objects.

Time: a scene loops. Scene time is device time modulo `duration_s`; the built-in scenes
are made so the loop is seamless (belt objects travel exactly one belt loop). Objects on
the belt ride at belt speed along world +x and wrap from the end of the belt loop
(`loop_start_m + loop_m`) back to its start, out of view, so they keep entering and
leaving the picture. Object ids are 1, 2, … in file order; 0 is the background.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tofcut.driver.protocol import Register
from tofcut.sim.geometry import Pose, axis_angle, rotation_xyz_deg
from tofcut.sim.lens import LensSpec
from tofcut.sim.sensor import SensorSpec
from tofcut.sim.shapes import Shape


@dataclass(frozen=True)
class Swing:
    """A rocking joint: angle = amplitude · sin(2π t / period + phase) about `axis` at `pivot`."""

    axis: tuple[float, float, float]
    amplitude_deg: float
    period_s: float
    phase_deg: float = 0.0
    pivot: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def pose(self, t_s: float) -> Pose:
        """The joint's transform at time t, in its parent's frame."""
        angle = math.radians(self.amplitude_deg) * math.sin(
            2.0 * math.pi * t_s / self.period_s + math.radians(self.phase_deg)
        )
        rot = axis_angle(np.array(self.axis), angle)
        pivot = np.array(self.pivot)
        return Pose(rot, pivot - rot @ pivot)


@dataclass(frozen=True)
class Motion:
    """How an object's body frame moves in the world.

    kinds: `static`; `belt` (rides the belt); `linear` (constant `velocity`, restarting
    every `period_s` if given); `path` (piecewise-linear `waypoints` of (t, x, y, z,
    yaw_deg), repeating after the last one's time).
    """

    kind: str = "static"
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    period_s: float = 0.0
    waypoints: tuple[tuple[float, float, float, float, float], ...] = ()


@dataclass(frozen=True, eq=False)
class Part:
    """One solid of a body, placed in the body frame, optionally on a rocking joint."""

    shape: Shape
    pose: Pose
    albedo: float
    swing: Swing | None = None


@dataclass(frozen=True, eq=False)
class SceneObject:
    """A labelled object: a rigid or jointed body of parts with a start pose and a motion."""

    id: int
    name: str
    parts: tuple[Part, ...]
    start: Pose
    """World-from-body at t = 0."""
    motion: Motion = field(default_factory=Motion)
    swing: Swing | None = None
    """A joint between the moving frame and the body (e.g. a robot's waist)."""
    target: bool = False


@dataclass(frozen=True, eq=False)
class Surface:
    """A static background solid (label 0): floor, wall, belt, stand."""

    name: str
    shape: Shape
    pose: Pose
    """World-from-local."""
    albedo: float


@dataclass(frozen=True)
class Belt:
    """A conveyor belt along world +x, its top surface at z = `top_z`, centred on y = 0."""

    width_m: float
    speed_mps: float
    top_z: float = 0.0
    loop_m: float = 4.0
    loop_start_m: float = -2.0
    albedo: float = 0.45


@dataclass(frozen=True)
class CameraSettings:
    """The register values the emulated camera starts with for this scene."""

    mod_code: int = 1
    integration: int = 30
    frame_period: int = 200
    """Units of 100 µs (200 = 50 fps)."""

    @property
    def fps(self) -> float:
        """Frames per second the frame period asks for."""
        return 1e4 / self.frame_period if self.frame_period else math.inf

    @property
    def registers(self) -> dict[Register, int]:
        """Initial register values for `EmulatedCamera(registers=...)`."""
        return {
            Register.MOD_FREQ: self.mod_code,
            Register.INTEGRATION: self.integration,
            Register.FRAME_PERIOD: self.frame_period,
        }


@dataclass(frozen=True, eq=False)
class Scene:
    """Everything a scene file says."""

    name: str
    description: str
    duration_s: float
    lens: LensSpec
    camera_from_world: Pose
    settings: CameraSettings
    sensor: SensorSpec
    belt: Belt | None
    surfaces: tuple[Surface, ...]
    objects: tuple[SceneObject, ...]


def body_pose(obj: SceneObject, t_s: float, belt: Belt | None) -> Pose:
    """World-from-body of an object at scene time t (before its parts' joints)."""
    m = obj.motion
    start = obj.start
    if m.kind == "belt":
        if belt is None:
            raise ValueError(f"object {obj.name!r} rides a belt, but the scene has none")
        x = start.translation[0] + belt.speed_mps * t_s
        x = belt.loop_start_m + (x - belt.loop_start_m) % belt.loop_m
        pose = Pose(start.rotation, np.array([x, start.translation[1], start.translation[2]]))
    elif m.kind == "linear":
        tt = t_s % m.period_s if m.period_s > 0 else t_s
        pose = Pose(start.rotation, start.translation + np.array(m.velocity) * tt)
    elif m.kind == "path":
        way = np.array(m.waypoints)
        tt = t_s % way[-1, 0]
        xyz = np.array([np.interp(tt, way[:, 0], way[:, i]) for i in (1, 2, 3)])
        yaw = float(np.interp(tt, way[:, 0], way[:, 4]))
        pose = Pose(rotation_xyz_deg([0.0, 0.0, yaw]) @ start.rotation, xyz)
    else:
        pose = start
    if obj.swing is not None:
        pose = pose.compose(obj.swing.pose(t_s))
    return pose


def body_part_poses(obj: SceneObject, t_s: float) -> list[Pose]:
    """Body-from-part of every part of an object at scene time t (its joints swung)."""
    return [
        part.pose if part.swing is None else part.swing.pose(t_s).compose(part.pose)
        for part in obj.parts
    ]


def part_poses(obj: SceneObject, t_s: float, belt: Belt | None, camera: Pose) -> list[Pose]:
    """Camera-from-part of every part of an object at scene time t."""
    body = camera.compose(body_pose(obj, t_s, belt))
    return [body.compose(local) for local in body_part_poses(obj, t_s)]
