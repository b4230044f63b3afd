"""The physically based scene source: a `Scene` rendered as a SwissRanger-class sensor sees it.

Per frame: place every solid at the four tap times and the mid time, and find the pixel
window that can see it (bounding sphere, swept over the frame); cast the pixel centres at
the mid time for the ground truth and to find depth edges; then for each tap cast the
pixel centres at that tap's time, re-cast the edge pixels (and everything near a part too
thin to hit a pixel centre) with n×n sub-pixel rays and average their phasors, and turn
the result into counts with `tofcut.sim.sensor`. The static background is cast once.
Noise is drawn from a generator seeded by (seed, sequence), so a frame is the same
whatever frames were rendered or skipped before it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from tofcut._types import F64
from tofcut.driver.belt import KnownBelt
from tofcut.driver.calibration import Calibration
from tofcut.driver.protocol import TAPS, mod_freq_hz
from tofcut.sim.conveyor import belt_geometry
from tofcut.sim.lens import RayGrid, make_calibration, sphere_window
from tofcut.sim.raycast import Hits, Placed, cast_all, cast_samples, cast_windows, depth_edges
from tofcut.sim.scene import CameraSettings, Scene, body_part_poses, body_pose, part_poses
from tofcut.sim.sensor import active_signal, expose, phase_of, tap_means
from tofcut.sim.source import Exposure, Rendered
from tofcut.sim.truth import FrameTruth, ObjectTruth

THIN_PX = 2.5
"""A part thinner than this many pixels may slip between pixel centres: sample all its window."""


@dataclass(frozen=True)
class ObjectInfo:
    """An object of the scene as the rest of the project sees it."""

    id: int
    name: str
    target: bool


@dataclass(frozen=True, eq=False)
class TargetInfo:
    """The marked object of a paper scene, and where the tracker can start at t = 0."""

    id: int
    name: str
    seed_pixel: tuple[int, int]
    """(u, v): column and row of a pixel well inside the target at t = 0."""
    seed_point: F64
    """Camera-frame point of that pixel's surface at t = 0, metres."""
    centroid: F64
    """The target's centroid in camera coordinates at t = 0."""


class SceneSource:
    """A `TapSource` that renders a scene with noise, mixed pixels, wrapping and saturation."""

    def __init__(self, scene: Scene, seed: int = 0) -> None:
        self.scene = scene
        self.seed = seed
        self._calibration = make_calibration(scene.lens, scene.settings.mod_code, seed)
        self._rays = RayGrid.build(
            self._calibration, scene.sensor.supersample, scene.sensor.falloff_exponent
        )
        po = self._calibration.phase_offset
        self._cos_po = np.cos(po)
        self._sin_po = np.sin(po)
        cam = scene.camera_from_world
        solids = [
            (s.shape, cam.compose(s.pose), -(i + 1), s.albedo) for i, s in enumerate(scene.surfaces)
        ]
        self._background = cast_all(solids, self._rays.centre)
        self._background_sub = cast_all(solids, self._rays.sub)

    # --- what the rest of the project reads ------------------------------------------------

    @property
    def calibration(self) -> Calibration:
        """The true lens, phase offsets and distance offset (the emulated camera's flash)."""
        return self._calibration

    @property
    def name(self) -> str:
        return self.scene.name

    @property
    def duration_s(self) -> float:
        """The scene loops: scene time is device time modulo this."""
        return self.scene.duration_s

    @property
    def settings(self) -> CameraSettings:
        """Modulation code, integration and frame period registers the camera should start with."""
        return self.scene.settings

    @property
    def objects(self) -> list[ObjectInfo]:
        """Every labelled object: id (≥ 1), name, and whether it is the marked target."""
        return [ObjectInfo(o.id, o.name, o.target) for o in self.scene.objects]

    @property
    def belt(self) -> KnownBelt | None:
        """The belt in camera coordinates, with its speed, or None where there is none."""
        if self.scene.belt is None:
            return None
        return KnownBelt(belt_geometry(self.scene), self.scene.belt.speed_mps, "scene")

    @cached_property
    def target(self) -> TargetInfo | None:
        """The marked target, with a seed pixel deep inside it at t = 0; None if unmarked."""
        marked = [o for o in self.scene.objects if o.target]
        if not marked:
            return None
        obj = marked[0]
        truth = self.truth_at(0.0)
        mask = truth.labels == obj.id
        if not mask.any():
            raise ValueError(f"the target {obj.name!r} is not in view at t = 0")
        inner = mask
        while True:  # erode until one more step would leave nothing: the deepest pixels
            e = inner.copy()
            e[1:] &= inner[:-1]
            e[:-1] &= inner[1:]
            e[:, 1:] &= inner[:, :-1]
            e[:, :-1] &= inner[:, 1:]
            if not e.any():
                break
            inner = e
        rows, cols = np.nonzero(inner)
        i = int(np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2))
        v, u = int(rows[i]), int(cols[i])
        point = self._rays.centre[:, v, u] * float(truth.range[v, u])
        return TargetInfo(obj.id, obj.name, (u, v), point, truth.object(obj.id).centroid)

    # --- rendering ------------------------------------------------------------------------

    def _place(self, times: list[float]) -> tuple[list[Placed], npt.NDArray[np.bool_]]:
        """Every part at every time, with its window; and the windows of thin parts."""
        calib = self._calibration
        scene = self.scene
        cam = scene.camera_from_world
        thin = np.zeros((calib.height, calib.width), bool)
        placed: list[Placed] = []
        local = [t % scene.duration_s for t in times]
        for obj in scene.objects:
            per_time = [part_poses(obj, t, scene.belt, cam) for t in local]
            for j, part in enumerate(obj.parts):
                poses = tuple(p[j] for p in per_time)
                mid = poses[-1].translation
                sweep = max(float(np.linalg.norm(p.translation - mid)) for p in poses)
                radius = part.shape.bound_radius + sweep
                window = sphere_window(calib, self._rays.limit, mid, radius)
                if window is None:
                    continue
                placed.append(Placed(part.shape, poses, obj.id, part.albedo, window))
                z = float(mid[2]) - radius
                if z > 0 and calib.fx * part.shape.thickness / (z + 2 * radius) < THIN_PX:
                    v0, v1, u0, u1 = window
                    thin[v0:v1, u0:u1] = True
        return placed, thin

    def _truth(self, sequence: int, times: list[float], hits: Hits) -> FrameTruth:
        """Labels, range and object poses at the mid time (the last of `times`)."""
        scene = self.scene
        t_mid = times[-1] % scene.duration_s
        labels = np.maximum(hits.sid, 0).astype(np.int32)
        counts = np.bincount(labels.ravel(), minlength=len(scene.objects) + 1)
        objects = []
        for obj in scene.objects:
            body = scene.camera_from_world.compose(body_pose(obj, t_mid, scene.belt))
            poses = part_poses(obj, t_mid, scene.belt, scene.camera_from_world)
            vols = np.array([p.shape.volume for p in obj.parts])
            centres = np.array([p.translation for p in poses])
            boxes = [part.shape.aabb(pose) for part, pose in zip(obj.parts, poses, strict=True)]
            own = [
                part.shape.aabb(pose)
                for part, pose in zip(obj.parts, body_part_poses(obj, t_mid), strict=True)
            ]
            objects.append(
                ObjectTruth(
                    obj.id,
                    obj.name,
                    body.matrix(),
                    (vols @ centres) / vols.sum(),
                    np.min([b[0] for b in boxes], axis=0),
                    np.max([b[1] for b in boxes], axis=0),
                    np.max([b[1] for b in own], axis=0) - np.min([b[0] for b in own], axis=0),
                    int(counts[obj.id]),
                )
            )
        return FrameTruth(
            sequence, times[-1], (times[0], times[1], times[2], times[3]), labels,
            hits.range.astype(np.float32), tuple(objects),
        )  # fmt: skip

    def truth_at(self, t_s: float, sequence: int = -1) -> FrameTruth:
        """Ground truth of an instant (all four tap times equal to it), without rendering taps."""
        times = [t_s] * 5
        placed, _ = self._place(times)
        hits = cast_windows(self._background, placed, 4, self._rays.centre)
        return self._truth(sequence, times, hits)

    def render(self, exposure: Exposure) -> Rendered:
        """The four taps of one exposure and its ground truth."""
        means, truth = self.mean_taps(exposure)
        rng = np.random.default_rng([self.seed, exposure.sequence & 0xFFFFFFFF])
        normals = rng.standard_normal(means.shape, dtype=np.float32)
        return Rendered(expose(self.scene.sensor, means, normals), truth)

    def mean_taps(self, exposure: Exposure) -> tuple[F64, FrameTruth]:
        """Noise-free expected count of every tap (4, H, W), before rounding, and the truth."""
        calib = self._calibration
        sensor = self.scene.sensor
        freq = mod_freq_hz(exposure.mod_code)
        t_int_ms = exposure.integration_s * 1e3
        times = [exposure.tap_time_s(k) for k in range(TAPS)] + [mid_time(exposure)]
        placed, thin = self._place(times)
        rays = self._rays
        mid_hits = cast_windows(self._background, placed, 4, rays.centre)
        truth = self._truth(exposure.sequence, times, mid_hits)
        edges = depth_edges(mid_hits, sensor.edge_jump_m) | thin
        rows, cols = np.nonzero(edges)
        sub_rays = rays.sub[:, rows, cols]
        sub_base = self._background_sub.take((rows, cols))
        falloff = rays.vignette
        falloff_e = falloff[rows, cols][:, None]
        offset = calib.distance_offset_m
        means = np.empty((TAPS, calib.height, calib.width))
        for k in range(TAPS):
            h = (
                mid_hits
                if len(placed) == 0
                else cast_windows(self._background, placed, k, rays.centre)
            )
            s = active_signal(sensor, t_int_ms, h.albedo, h.cos, h.range, falloff)
            # float32 trigonometry is many times faster and still sub-micrometre exact
            phase = phase_of(np.where(np.isfinite(h.range), h.range, 0.0), offset, freq)
            phase = phase.astype(np.float32)
            p_re = s * np.cos(phase)
            p_im = s * np.sin(phase)
            albedo = h.albedo
            if rows.size:
                sh = cast_samples(sub_base, placed, k, sub_rays, rows, cols)
                ss = active_signal(sensor, t_int_ms, sh.albedo, sh.cos, sh.range, falloff_e)
                sp = phase_of(np.where(np.isfinite(sh.range), sh.range, 0.0), offset, freq)
                sp = sp.astype(np.float32)
                s = s.copy()
                albedo = albedo.copy()
                s[rows, cols] = ss.mean(axis=1)
                p_re[rows, cols] = (ss * np.cos(sp)).mean(axis=1)
                p_im[rows, cols] = (ss * np.sin(sp)).mean(axis=1)
                albedo[rows, cols] = sh.albedo.mean(axis=1)
            q_re = p_re * self._cos_po - p_im * self._sin_po
            q_im = p_re * self._sin_po + p_im * self._cos_po
            means[k] = tap_means(sensor, t_int_ms, k, s, albedo, q_re, q_im)
        return means, truth


def mid_time(exposure: Exposure) -> float:
    """The frame's mid time: halfway through the four taps."""
    return exposure.t0_s + 1.5 * exposure.tap_interval_s + 0.5 * exposure.integration_s
