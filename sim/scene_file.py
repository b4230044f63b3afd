"""Scene files: TOML → `Scene`. The format, by example (world: x along the belt, z up, metres)::

name = "my-line"
description = "what it shows"
duration_s = 16.0                 # the scene loops after this long

[camera]                          # pose, settings, and optional lens overrides
position = [0.0, -0.55, 1.25]
look_at = [0.0, 0.05, 0.0]
mod_freq_mhz = 30                 # or mod_code = 1
integration = 30                  # INTEGRATION register: 0.3 ms + n × 0.1 ms per tap
fps = 50
k1 = -0.2                         # any of width, height, fx, fy, cx, cy, k1, k2, p1,
                                  # p2, k3, distance_offset_m, phase_offset_sigma_rad
[sensor]                          # optional: any field of `SensorSpec`
ambient = 80.0

[belt]                            # optional: belt, rails, legs and floor, all label 0
width = 0.6
speed = 0.25                      # m/s along +x
loop = 4.0                        # objects wrap from loop_start + loop to loop_start
loop_start = -2.0
albedo = 0.45
floor_z = -0.8

[[surface]]                       # more background: plane (local z is its normal) or box
shape = "plane"
position = [0.0, 3.0, 0.0]
rotation_deg = [90, 0, 0]         # about x, then y, then z (fixed axes)
albedo = 0.6

[[object]]                        # one labelled object; a single shape ...
name = "box-1"
shape = "box"
size = [0.3, 0.2, 0.15]           # full sizes; sphere: radius; cylinder/capsule:
albedo = 0.44                     #   radius and length, or from/to end points
position = [-0.4, 0.0, 0.075]     # body origin at t = 0 (a box's centre)
rotation_deg = [0, 0, 10]
motion = "belt"                   # static | belt | linear (velocity, period_s) |
target = true                     #   path (waypoints = [[t, x, y, z, yaw_deg], ...])

[[object]]                        # ... or a body of parts, each optionally jointed
name = "arm"
albedo = 0.3
swing = { axis = [0, 0, 1], amplitude_deg = 30, period_s = 8 }
[[object.part]]
shape = "capsule"
radius = 0.05
from = [0.0, 0.0, 0.4]
to = [0.3, 0.0, 0.8]
swing = { axis = [0, 1, 0], amplitude_deg = 20, period_s = 4, pivot = [0, 0, 0.4] }
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from tofcut.driver.errors import TofcutError
from tofcut.driver.protocol import MOD_FREQ_MHZ
from tofcut.sim.geometry import Pose, axis_angle, look_at, rotation_xyz_deg
from tofcut.sim.lens import LensSpec
from tofcut.sim.scene import (
    Belt,
    CameraSettings,
    Motion,
    Part,
    Scene,
    SceneObject,
    Surface,
    Swing,
)
from tofcut.sim.sensor import SensorSpec
from tofcut.sim.shapes import Box, Capsule, Cylinder, Plane, Shape, Sphere

Table = dict[str, Any]

_PLACE = {"position", "rotation_deg", "from", "to"}
_SHAPE = {"shape", "size", "radius", "length"}
_PART_KEYS = _SHAPE | _PLACE | {"albedo", "swing", "name"}
_OBJECT_KEYS = _PART_KEYS | {"motion", "velocity", "period_s", "waypoints", "target", "part"}
_SURFACE_KEYS = _SHAPE | _PLACE | {"albedo", "name"}
_BELT_KEYS = {
    "width", "speed", "top_z", "loop", "loop_start", "albedo", "length", "floor_z",
    "floor_albedo", "stand_albedo",
}  # fmt: skip
_CAMERA_KEYS = {"position", "look_at", "up", "mod_code", "mod_freq_mhz", "integration", "fps"}


class SceneError(TofcutError, ValueError):
    """A scene file that cannot be understood."""


def _vec(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, np.float64)
    if arr.shape != (3,):
        raise SceneError(f"{what} must be three numbers, got {value!r}")
    return arr


def _check_keys(table: Table, allowed: set[str], where: str) -> None:
    unknown = set(table) - allowed
    if unknown:
        raise SceneError(f"{where}: unknown keys {sorted(unknown)}; allowed: {sorted(allowed)}")


def _z_to(direction: np.ndarray) -> np.ndarray:
    """A rotation taking local +z onto `direction` (unit)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, direction)
    s = float(np.linalg.norm(axis))
    c = float(z @ direction)
    if s < 1e-12:
        return np.eye(3) if c > 0 else axis_angle([1.0, 0.0, 0.0], math.pi)
    return axis_angle(axis, math.atan2(s, c))


def _shape_and_pose(t: Table, where: str) -> tuple[Shape, Pose]:
    """A shape and its pose in the parent frame from `shape`, sizes and placement keys."""
    kind = t.get("shape")
    rot = rotation_xyz_deg(t.get("rotation_deg", [0.0, 0.0, 0.0]))
    pos = _vec(t.get("position", [0.0, 0.0, 0.0]), f"{where}.position")
    length = float(t.get("length", 0.0))
    if "from" in t or "to" in t:
        if kind not in ("cylinder", "capsule"):
            raise SceneError(f"{where}: from/to only place cylinders and capsules")
        a, b = _vec(t["from"], f"{where}.from"), _vec(t["to"], f"{where}.to")
        length = float(np.linalg.norm(b - a))
        pos, rot = (a + b) / 2.0, _z_to((b - a) / length)
    shape: Shape
    if kind == "box":
        size = _vec(t.get("size"), f"{where}.size")
        shape = Box(*(float(x) / 2.0 for x in size))
    elif kind == "sphere":
        shape = Sphere(float(t["radius"]))
    elif kind == "cylinder":
        shape = Cylinder(float(t["radius"]), length / 2.0)
    elif kind == "capsule":
        shape = Capsule(float(t["radius"]), length / 2.0)
    elif kind == "plane":
        shape = Plane()
    else:
        raise SceneError(f"{where}: shape must be box, sphere, cylinder, capsule or plane")
    return shape, Pose(rot, pos)


def _swing(t: Table | None) -> Swing | None:
    if t is None:
        return None
    axis = _vec(t["axis"], "swing.axis")
    pivot = _vec(t.get("pivot", [0.0, 0.0, 0.0]), "swing.pivot")
    return Swing(
        (float(axis[0]), float(axis[1]), float(axis[2])),
        float(t["amplitude_deg"]),
        float(t["period_s"]),
        float(t.get("phase_deg", 0.0)),
        (float(pivot[0]), float(pivot[1]), float(pivot[2])),
    )


def _motion(t: Table, where: str) -> Motion:
    kind = t.get("motion", "static")
    if kind not in ("static", "belt", "linear", "path"):
        raise SceneError(f"{where}: motion must be static, belt, linear or path")
    vel = _vec(t.get("velocity", [0.0, 0.0, 0.0]), f"{where}.velocity")
    listed = [tuple(float(x) for x in w) for w in t.get("waypoints", [])]
    if kind == "path" and (len(listed) < 2 or any(len(w) != 5 for w in listed)):
        raise SceneError(f"{where}: a path needs two or more waypoints [t, x, y, z, yaw_deg]")
    return Motion(
        kind,
        (float(vel[0]), float(vel[1]), float(vel[2])),
        float(t.get("period_s", 0.0)),
        tuple((w[0], w[1], w[2], w[3], w[4]) for w in listed if len(w) == 5),
    )


def _object(t: Table, object_id: int) -> SceneObject:
    name = str(t.get("name", f"object-{object_id}"))
    where = f"object {name!r}"
    _check_keys(t, _OBJECT_KEYS, where)
    albedo = float(t.get("albedo", 0.45))
    start = Pose(
        rotation_xyz_deg(t.get("rotation_deg", [0.0, 0.0, 0.0])),
        _vec(t.get("position", [0.0, 0.0, 0.0]), f"{where}.position"),
    )
    parts: list[Part] = []
    if "shape" in t:
        shape, _ = _shape_and_pose({k: v for k, v in t.items() if k in _SHAPE}, where)
        parts.append(Part(shape, Pose.identity(), albedo))
    for i, p in enumerate(t.get("part", [])):
        pw = f"{where} part {i}"
        _check_keys(p, _PART_KEYS, pw)
        shape, pose = _shape_and_pose(p, pw)
        if isinstance(shape, Plane):
            raise SceneError(f"{pw}: objects are solids; planes are background surfaces")
        parts.append(Part(shape, pose, float(p.get("albedo", albedo)), _swing(p.get("swing"))))
    if not parts:
        raise SceneError(f"{where} has no shape and no parts")
    return SceneObject(
        object_id, name, tuple(parts), start, _motion(t, where), _swing(t.get("swing")),
        bool(t.get("target", False)),
    )  # fmt: skip


def _belt_surfaces(t: Table) -> tuple[Belt, list[Surface]]:
    """The belt and what stands around it: floor, belt slab, side rails, legs."""
    _check_keys(t, _BELT_KEYS, "belt")
    belt = Belt(
        float(t["width"]), float(t.get("speed", 0.0)), float(t.get("top_z", 0.0)),
        float(t.get("loop", 4.0)), float(t.get("loop_start", -2.0)), float(t.get("albedo", 0.45)),
    )  # fmt: skip
    length = float(t.get("length", 6.0))
    floor_z = float(t.get("floor_z", -0.8))
    stand = float(t.get("stand_albedo", 0.35))
    eye = np.eye(3)
    top, half_w = belt.top_z, belt.width_m / 2.0
    out = [
        Surface("floor", Plane(), Pose(eye, np.array([0.0, 0.0, floor_z])),
                float(t.get("floor_albedo", 0.3))),
        Surface("belt", Box(length / 2, half_w, 0.02), Pose(eye, np.array([0.0, 0.0, top - 0.02])),
                belt.albedo),
    ]  # fmt: skip
    for side in (-1.0, 1.0):
        y = side * (half_w + 0.025)
        out.append(
            Surface("rail", Box(length / 2, 0.025, 0.05), Pose(eye, np.array([0.0, y, top - 0.01])),
                    stand)
        )  # fmt: skip
        for x in np.arange(-length / 2 + 0.3, length / 2, 1.2):
            h = (top - 0.06 - floor_z) / 2.0
            out.append(
                Surface("leg", Box(0.025, 0.025, h), Pose(eye, np.array([x, y, floor_z + h])),
                        stand)
            )  # fmt: skip
    return belt, out


def _settings(cam: Table) -> CameraSettings:
    if "mod_code" in cam:
        code = int(cam["mod_code"])
    else:
        mhz = float(cam.get("mod_freq_mhz", 30.0))
        codes = [c for c, f in MOD_FREQ_MHZ.items() if abs(f - mhz) < 1e-6]
        if not codes:
            raise SceneError(
                f"camera.mod_freq_mhz {mhz} is not one of {sorted(MOD_FREQ_MHZ.values())}"
            )
        code = codes[0]
    if code not in MOD_FREQ_MHZ:
        raise SceneError(f"camera.mod_code {code} is not supported")
    integration = int(cam.get("integration", 30))
    if not 0 <= integration <= 255:
        raise SceneError("camera.integration must be 0..255")
    fps = float(cam.get("fps", 50.0))
    return CameraSettings(code, integration, round(1e4 / fps))


def parse_scene(doc: Table, name: str = "scene") -> Scene:
    """Build a scene from a parsed TOML document."""
    cam = dict(doc.get("camera", {}))
    lens_fields = {f.name for f in fields(LensSpec)}
    _check_keys(cam, _CAMERA_KEYS | lens_fields, "camera")
    lens = LensSpec(**{k: v for k, v in cam.items() if k in lens_fields})
    sensor_doc = doc.get("sensor", {})
    _check_keys(sensor_doc, {f.name for f in fields(SensorSpec)}, "sensor")
    sensor = SensorSpec(**sensor_doc)
    camera_from_world = look_at(
        _vec(cam.get("position", [0.0, -0.55, 1.25]), "camera.position"),
        _vec(cam.get("look_at", [0.0, 0.0, 0.0]), "camera.look_at"),
        _vec(cam.get("up", [0.0, 0.0, 1.0]), "camera.up"),
    )
    belt = None
    surfaces: list[Surface] = []
    if "belt" in doc:
        belt, surfaces = _belt_surfaces(doc["belt"])
    for i, s in enumerate(doc.get("surface", [])):
        where = f"surface {i}"
        _check_keys(s, _SURFACE_KEYS, where)
        shape, pose = _shape_and_pose(s, where)
        surfaces.append(
            Surface(str(s.get("name", f"surface-{i}")), shape, pose, float(s.get("albedo", 0.4)))
        )
    objects = tuple(_object(t, i + 1) for i, t in enumerate(doc.get("object", [])))
    if sum(o.target for o in objects) > 1:
        raise SceneError("at most one object can be the target")
    if any(o.motion.kind == "belt" for o in objects) and belt is None:
        raise SceneError("objects ride a belt, but there is no [belt]")
    duration = float(doc.get("duration_s", 10.0))
    if duration <= 0:
        raise SceneError("duration_s must be positive")
    return Scene(
        str(doc.get("name", name)), str(doc.get("description", "")), duration, lens,
        camera_from_world, _settings(cam), sensor, belt, tuple(surfaces), objects,
    )  # fmt: skip


def load_scene(path: str | Path) -> Scene:
    """Read and build a scene file."""
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
        return parse_scene(doc, p.stem)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{p}: {exc}") from None
    except (KeyError, TypeError) as exc:
        raise SceneError(f"{p}: missing or malformed {exc}") from None


def _toml_value(value: Any, where: str) -> str:
    """One TOML value: a string, number, boolean or array of them (floats by `repr`, which
    reads back as the same double)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v, where) for v in value) + "]"
    raise SceneError(f"{where}: cannot write {type(value).__name__} {value!r} to TOML")


def _toml_key(key: str) -> str:
    """A bare key where TOML allows one, else a quoted one."""
    bare = key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key)
    return key if bare else json.dumps(key)


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _toml_table(table: Table, path: str, out: list[str]) -> None:
    """The key/value lines of a table, then its sub-tables and arrays of tables."""
    for key, value in table.items():
        if not isinstance(value, dict) and not _is_table_array(value):
            out.append(f"{_toml_key(key)} = {_toml_value(value, f'{path}{key}')}")
    for key, value in table.items():
        name = f"{path}{_toml_key(key)}"
        if isinstance(value, dict):
            out.extend(["", f"[{name}]"])
            _toml_table(value, f"{name}.", out)
        elif _is_table_array(value):
            for item in value:
                out.extend(["", f"[[{name}]]"])
                _toml_table(item, f"{name}.", out)


def scene_toml(doc: Table, comment: str = "") -> str:
    """A scene document (what `tomllib` reads from a scene file) as TOML text: `tomllib.loads`
    gives `doc` back exactly, so `parse_scene` builds the same scene. `comment` goes first,
    each line as a `#` comment."""
    out = [f"# {line}".rstrip() for line in comment.splitlines()]
    _toml_table(doc, "", out)
    return "\n".join(out) + "\n"
