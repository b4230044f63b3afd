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

import itertools
import math
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from tofcut.driver.config_file import as_float, load_toml, unknown_keys
from tofcut.driver.config_file import show as _show
from tofcut.driver.errors import TofcutError
from tofcut.driver.protocol import MOD_FREQ_MHZ, check_sensor_size
from tofcut.driver.toml_writer import dumps
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

MAX_FILE_BYTES = 1 << 20
"""A scene file larger than this is refused unread (the built-in ones are about 2 KB)."""
MAX_COORD_M = 1000.0
"""Positions, sizes, lengths and velocities are at most this large (m, m/s)."""
MAX_BELT_LENGTH_M = 100.0
"""The belt's stand has a pair of legs every 1.2 m: a longer belt is refused."""
MAX_TIME_S = 1e6
"""Durations, periods and waypoint times are at most this (s)."""
MAX_ANGLE_DEG = 1e4
MAX_COUNT = 1000
"""The most objects, surfaces, parts of one object or waypoints of one path."""
MIN_PERIOD_100US, MAX_PERIOD_100US = 1, 0xFFFF
"""`fps` must give a FRAME_PERIOD register value (100 µs units, u16) in this range."""

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
_SWING_KEYS = {"axis", "amplitude_deg", "period_s", "phase_deg", "pivot"}
_TOP_FORMS = {
    "name": "name", "description": "description", "duration_s": "duration_s",
    "camera": "[camera]", "sensor": "[sensor]", "belt": "[belt]", "surface": "[[surface]]",
    "object": "[[object]]",
}  # fmt: skip
_LENS_INTS = {"width", "height"}
_SENSOR_RANGES: dict[str, tuple[float, float]] = {
    "responsivity": (0.0, 1e7),
    "contrast": (0.0, 1.0),
    "ambient": (0.0, 1e7),
    "dark": (0.0, 65535.0),
    "gain": (1e-6, 1e3),
    "read_noise": (0.0, 65535.0),
    "falloff_exponent": (0.0, 20.0),
    "supersample": (1, 8),
    "edge_jump_m": (1e-6, MAX_COORD_M),
}
"""What each `[sensor]` field may be (`supersample`, an integer, sets memory per edge pixel)."""


class SceneError(TofcutError, ValueError):
    """A scene file that cannot be understood."""


class UnknownScene(SceneError):
    """No built-in scene, family or scene file by that name."""


def _is_number(value: Any) -> bool:
    return as_float(value) is not None


def _number(
    value: Any, what: str, lo: float = -MAX_COORD_M, hi: float = MAX_COORD_M, *,
    above: bool = False, integer: bool = False,
) -> float:  # fmt: skip
    """A finite number (an integer if `integer`) in lo..hi (above lo if `above`)."""
    kind = "an integer" if integer else "a number"
    x = as_float(value)
    if x is None or (integer and not isinstance(value, int)):
        raise SceneError(f"{what} must be {kind}, not {_show(value)}")
    if not math.isfinite(x):
        raise SceneError(f"{what} must be a finite number, not {_show(value)}")
    if not (lo < x <= hi if above else lo <= x <= hi):
        bound = f"above {lo:g} and at most {hi:g}" if above else f"in {lo:g}..{hi:g}"
        raise SceneError(f"{what} must be {bound}, not {_show(value)}")
    return x


def _get(
    t: Table, key: str, where: str, default: float, lo: float = -MAX_COORD_M,
    hi: float = MAX_COORD_M, *, above: bool = False,
) -> float:  # fmt: skip
    return _number(t.get(key, default), f"{where}.{key}", lo, hi, above=above)


def _albedo(t: Table, key: str, where: str, default: float) -> float:
    return _get(t, key, where, default, 0.0, 1.0)


def _vec(value: Any, what: str, limit: float = MAX_COORD_M) -> np.ndarray:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise SceneError(f"{what} must be three numbers, got {_show(value)}")
    return np.array([_number(v, what, -limit, limit) for v in value], np.float64)


def _rotation(t: Table, where: str) -> np.ndarray:
    angles = _vec(t.get("rotation_deg", [0.0, 0.0, 0.0]), f"{where}.rotation_deg", MAX_ANGLE_DEG)
    return rotation_xyz_deg(list(angles))


def _text(t: Table, key: str, where: str, default: str) -> str:
    value = t.get(key, default)
    if not isinstance(value, str):
        raise SceneError(f"{where}.{key} must be a string, not {_show(value)}")
    return value


def _table(value: Any, what: str) -> Table:
    if not isinstance(value, dict):
        raise SceneError(f"{what} must be a table, not {_show(value)}")
    return value


def _tables(value: Any, what: str) -> list[Table]:
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise SceneError(f"{what} must be an array of tables ([[{what}]]), not {_show(value)}")
    if len(value) > MAX_COUNT:
        raise SceneError(f"more than {MAX_COUNT} [[{what}]]")
    return value


def _check_keys(
    table: Table, allowed: set[str], where: str, forms: dict[str, str] | None = None
) -> None:
    if message := unknown_keys(table, allowed, forms):
        raise SceneError(f"{where}: {message}")


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
    rot = _rotation(t, where)
    pos = _vec(t.get("position", [0.0, 0.0, 0.0]), f"{where}.position")
    length = _get(t, "length", where, 0.0, 0.0, MAX_COORD_M)
    if "from" in t or "to" in t:
        if kind not in ("cylinder", "capsule"):
            raise SceneError(f"{where}: from/to only place cylinders and capsules")
        if "from" not in t or "to" not in t:
            raise SceneError(f"{where}: give both from and to")
        a, b = _vec(t["from"], f"{where}.from"), _vec(t["to"], f"{where}.to")
        length = float(np.linalg.norm(b - a))
        if length < 1e-9:
            raise SceneError(f"{where}: from and to are the same point")
        pos, rot = (a + b) / 2.0, _z_to((b - a) / length)
    shape: Shape
    radius = 0.0
    if kind in ("sphere", "cylinder", "capsule"):
        if "radius" not in t:
            raise SceneError(f"{where}: a {kind} needs a radius")
        radius = _get(t, "radius", where, 0.0, 0.0, MAX_COORD_M, above=True)
    if kind == "box":
        if "size" not in t:
            raise SceneError(f"{where}: a box needs a size [x, y, z]")
        size = _vec(t["size"], f"{where}.size")
        if (size <= 0).any():
            raise SceneError(f"{where}.size must be three positive numbers, not {_show(t['size'])}")
        shape = Box(*(float(x) / 2.0 for x in size))
    elif kind == "sphere":
        shape = Sphere(radius)
    elif kind == "cylinder":
        if length <= 0:
            raise SceneError(f"{where}: a cylinder needs a positive length (or from and to)")
        shape = Cylinder(radius, length / 2.0)
    elif kind == "capsule":
        shape = Capsule(radius, length / 2.0)
    elif kind == "plane":
        shape = Plane()
    else:
        raise SceneError(
            f"{where}: shape must be box, sphere, cylinder, capsule or plane, not {_show(kind)}"
        )
    return shape, Pose(rot, pos)


def _swing(value: Any, where: str) -> Swing | None:
    if value is None:
        return None
    where = f"{where}.swing"
    t = _table(value, where)
    _check_keys(t, _SWING_KEYS, where)
    if "axis" not in t or "amplitude_deg" not in t or "period_s" not in t:
        raise SceneError(f"{where} needs axis, amplitude_deg and period_s")
    axis = _vec(t["axis"], f"{where}.axis")
    if float(np.linalg.norm(axis)) < 1e-9:
        raise SceneError(f"{where}.axis must not be zero")
    pivot = _vec(t.get("pivot", [0.0, 0.0, 0.0]), f"{where}.pivot")
    return Swing(
        (float(axis[0]), float(axis[1]), float(axis[2])),
        _get(t, "amplitude_deg", where, 0.0, -MAX_ANGLE_DEG, MAX_ANGLE_DEG),
        _get(t, "period_s", where, 0.0, 0.0, MAX_TIME_S, above=True),
        _get(t, "phase_deg", where, 0.0, -MAX_ANGLE_DEG, MAX_ANGLE_DEG),
        (float(pivot[0]), float(pivot[1]), float(pivot[2])),
    )


def _waypoints(value: Any, where: str) -> tuple[tuple[float, float, float, float, float], ...]:
    what = f"{where}.waypoints"
    if not isinstance(value, list) or len(value) > MAX_COUNT:
        raise SceneError(f"{what} must be a list of at most {MAX_COUNT} [t, x, y, z, yaw_deg]")
    out = []
    for w in value:
        if not isinstance(w, list) or len(w) != 5:
            raise SceneError(f"{what}: each waypoint is [t, x, y, z, yaw_deg], not {_show(w)}")
        t = _number(w[0], what, 0.0, MAX_TIME_S)
        x, y, z = (_number(v, what) for v in w[1:4])
        yaw = _number(w[4], what, -MAX_ANGLE_DEG, MAX_ANGLE_DEG)
        out.append((t, x, y, z, yaw))
    if any(b[0] <= a[0] for a, b in itertools.pairwise(out)):
        raise SceneError(f"{what}: the times must increase")
    return tuple(out)


def _motion(t: Table, where: str) -> Motion:
    kind = t.get("motion", "static")
    if kind not in ("static", "belt", "linear", "path"):
        raise SceneError(f"{where}: motion must be static, belt, linear or path, not {_show(kind)}")
    vel = _vec(t.get("velocity", [0.0, 0.0, 0.0]), f"{where}.velocity")
    listed = _waypoints(t.get("waypoints", []), where)
    if kind == "path" and len(listed) < 2:
        raise SceneError(f"{where}: a path needs two or more waypoints [t, x, y, z, yaw_deg]")
    return Motion(
        kind,
        (float(vel[0]), float(vel[1]), float(vel[2])),
        _get(t, "period_s", where, 0.0, 0.0, MAX_TIME_S),
        listed,
    )


def _object(t: Table, object_id: int) -> SceneObject:
    name = _text(t, "name", f"object {object_id}", f"object-{object_id}")
    where = f"object {_show(name)}"
    _check_keys(t, _OBJECT_KEYS, where, {"part": "[[object.part]]"})
    albedo = _albedo(t, "albedo", where, 0.45)
    start = Pose(_rotation(t, where), _vec(t.get("position", [0.0, 0.0, 0.0]), f"{where}.position"))
    target = t.get("target", False)
    if not isinstance(target, bool):
        raise SceneError(f"{where}.target must be true or false, not {_show(target)}")
    parts: list[Part] = []
    if "shape" in t:
        shape, _ = _shape_and_pose({k: v for k, v in t.items() if k in _SHAPE}, where)
        parts.append(Part(shape, Pose.identity(), albedo))
    for i, p in enumerate(_tables(t.get("part", []), "object.part")):
        pw = f"{where} part {i}"
        _check_keys(p, _PART_KEYS, pw)
        shape, pose = _shape_and_pose(p, pw)
        if isinstance(shape, Plane):
            raise SceneError(f"{pw}: objects are solids; planes are background surfaces")
        parts.append(
            Part(shape, pose, _albedo(p, "albedo", pw, albedo), _swing(p.get("swing"), pw))
        )
    if not parts:
        raise SceneError(f"{where} has no shape and no parts")
    return SceneObject(
        object_id, name, tuple(parts), start, _motion(t, where), _swing(t.get("swing"), where),
        target,
    )  # fmt: skip


def _belt_surfaces(t: Table) -> tuple[Belt, list[Surface]]:
    """The belt and what stands around it: floor, belt slab, side rails, legs."""
    _check_keys(t, _BELT_KEYS, "belt")
    if "width" not in t:
        raise SceneError("belt: width is required")
    belt = Belt(
        _get(t, "width", "belt", 0.0, 0.0, MAX_COORD_M, above=True),
        _get(t, "speed", "belt", 0.0),
        _get(t, "top_z", "belt", 0.0),
        _get(t, "loop", "belt", 4.0, 0.0, MAX_COORD_M, above=True),
        _get(t, "loop_start", "belt", -2.0),
        _albedo(t, "albedo", "belt", 0.45),
    )  # fmt: skip
    length = _get(t, "length", "belt", 6.0, 0.0, MAX_BELT_LENGTH_M, above=True)
    floor_z = _get(t, "floor_z", "belt", -0.8)
    if floor_z >= belt.top_z - 0.1:
        raise SceneError(f"belt.floor_z ({floor_z:g}) must be at least 0.1 m below top_z")
    stand = _albedo(t, "stand_albedo", "belt", 0.35)
    eye = np.eye(3)
    top, half_w = belt.top_z, belt.width_m / 2.0
    out = [
        Surface("floor", Plane(), Pose(eye, np.array([0.0, 0.0, floor_z])),
                _albedo(t, "floor_albedo", "belt", 0.3)),
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
        code = int(_number(cam["mod_code"], "camera.mod_code", 0, 255, integer=True))
    else:
        mhz = _get(cam, "mod_freq_mhz", "camera", 30.0, 0.0, 1000.0)
        codes = [c for c, f in MOD_FREQ_MHZ.items() if abs(f - mhz) < 1e-6]
        if not codes:
            raise SceneError(
                f"camera.mod_freq_mhz {mhz:g} is not one of {sorted(MOD_FREQ_MHZ.values())}"
            )
        code = codes[0]
    if code not in MOD_FREQ_MHZ:
        raise SceneError(f"camera.mod_code {code} is not supported")
    integration = int(
        _number(cam.get("integration", 30), "camera.integration", 0, 255, integer=True)
    )
    fps = _get(cam, "fps", "camera", 50.0, 1e4 / MAX_PERIOD_100US, 1e4 / MIN_PERIOD_100US)
    return CameraSettings(code, integration, round(1e4 / fps))


def _lens(cam: Table) -> LensSpec:
    values: dict[str, Any] = {}
    for f in fields(LensSpec):
        if f.name not in cam:
            continue
        what = f"camera.{f.name}"
        if f.name in _LENS_INTS:
            values[f.name] = int(_number(cam[f.name], what, 1, 0xFFFF, integer=True))
        elif f.name in ("fx", "fy"):
            values[f.name] = _number(cam[f.name], what, 1.0, 1e6)
        elif f.name in ("cx", "cy"):
            values[f.name] = _number(cam[f.name], what, -1e5, 1e5)
        elif f.name in ("distance_offset_m",):
            values[f.name] = _number(cam[f.name], what, -100.0, 100.0)
        elif f.name.endswith("_rad"):
            values[f.name] = _number(cam[f.name], what, 0.0, 10.0)
        else:  # distortion
            values[f.name] = _number(cam[f.name], what, -100.0, 100.0)
    lens = LensSpec(**values)
    if why := check_sensor_size(lens.width, lens.height):
        raise SceneError(f"camera: {why}")
    return lens


def _sensor(doc: Table) -> SensorSpec:
    t = _table(doc.get("sensor", {}), "[sensor]")
    _check_keys(t, set(_SENSOR_RANGES), "sensor")
    values: dict[str, Any] = {}
    for key, value in t.items():
        lo, hi = _SENSOR_RANGES[key]
        integer = isinstance(lo, int) and isinstance(hi, int)
        x = _number(value, f"sensor.{key}", lo, hi, integer=integer)
        values[key] = int(x) if integer else x
    return SensorSpec(**values)


def parse_scene(doc: Table, name: str = "scene") -> Scene:
    """Build a scene from a parsed TOML document; `SceneError` (one line) for anything off."""
    _check_keys(doc, set(_TOP_FORMS), "the scene", _TOP_FORMS)
    cam = _table(doc.get("camera", {}), "[camera]")
    lens_fields = {f.name for f in fields(LensSpec)}
    _check_keys(cam, _CAMERA_KEYS | lens_fields, "camera")
    lens = _lens(cam)
    sensor = _sensor(doc)
    position = _vec(cam.get("position", [0.0, -0.55, 1.25]), "camera.position")
    target = _vec(cam.get("look_at", [0.0, 0.0, 0.0]), "camera.look_at")
    up = _vec(cam.get("up", [0.0, 0.0, 1.0]), "camera.up")
    view = target - position
    if float(np.linalg.norm(view)) < 1e-6:
        raise SceneError("camera.position and camera.look_at are the same point")
    cross = float(np.linalg.norm(np.cross(view / np.linalg.norm(view), up)))
    if cross < 1e-6 * max(float(np.linalg.norm(up)), 1e-300):
        raise SceneError("camera.up must not be zero or along the view (position → look_at)")
    camera_from_world = look_at(position, target, up)
    belt = None
    surfaces: list[Surface] = []
    if "belt" in doc:
        belt, surfaces = _belt_surfaces(_table(doc["belt"], "[belt]"))
    for i, s in enumerate(_tables(doc.get("surface", []), "surface")):
        where = f"surface {i}"
        _check_keys(s, _SURFACE_KEYS, where)
        shape, pose = _shape_and_pose(s, where)
        surfaces.append(
            Surface(_text(s, "name", where, f"surface-{i}"), shape, pose,
                    _albedo(s, "albedo", where, 0.4))
        )  # fmt: skip
    objects = tuple(
        _object(t, i + 1) for i, t in enumerate(_tables(doc.get("object", []), "object"))
    )
    if sum(o.target for o in objects) > 1:
        raise SceneError("at most one object can be the target")
    if any(o.motion.kind == "belt" for o in objects) and belt is None:
        raise SceneError("objects ride a belt, but there is no [belt]")
    duration = _get(doc, "duration_s", "scene", 10.0, 0.0, MAX_TIME_S, above=True)
    return Scene(
        _text(doc, "name", "scene", name), _text(doc, "description", "scene", ""), duration,
        lens, camera_from_world, _settings(cam), sensor, belt, tuple(surfaces), objects,
    )  # fmt: skip


def load_scene(path: str | Path) -> Scene:
    """Read and build a scene file; `SceneError` (one line, naming the file) if it cannot be."""
    name = Path(path).stem
    return load_toml(path, MAX_FILE_BYTES, lambda doc: parse_scene(doc, name), SceneError)


def scene_toml(doc: Table, comment: str = "") -> str:
    """A scene document (what `tomllib` reads from a scene file) as TOML text: `tomllib.loads`
    gives `doc` back exactly, so `parse_scene` builds the same scene. `comment` goes first,
    each line as a `#` comment."""
    try:
        return dumps(doc, {"": comment.splitlines()})
    except ValueError as exc:
        raise SceneError(str(exc)) from None
