"""A live track: what the tracker keeps of one object between frames, and how that changes.

A track predicts where its object is now (constant velocity; unseen on a running belt, at the
belt's pace) and carries its predicted surface along. Seen whole, it is measured (position,
shape, surface, usual size); seen in part, it coasts on its prediction; what it holds
changing (two tracks joined, surfaces dealt out again), it starts again from the new view;
unseen, it is predicted through occlusion until it has been hidden too long or leaves the
view. A track that stays put while the belt runs is part of the machine. Each frame it
reports itself as a `Track`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from tofcut._types import F64, I64
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.frames import Frame
from tofcut.tracker import measure_kernels, stats
from tofcut.tracker.belt_prior import VelocityPrior
from tofcut.tracker.motion import ConstantVelocity
from tofcut.tracker.params import TrackerParams
from tofcut.tracker.tracks import Track

SHAPE_FLOOR_M = 0.01
"""No track's shape is thinner than this (1σ) in any direction."""
USUAL_MEMORY = 0.995
"""Per frame, how much of its largest view a track's usual size keeps (about 4 s at 50 fps)."""

Box = tuple[slice, slice]
"""A mask's bounding slices: rows, columns."""


@dataclass(frozen=True, eq=False)
class SortedSurface:
    """A track's surface points as `distance_kernels.track_distances` takes them (arranged by
    `distance_kernels.sort_surfaces`), and the axis they are sorted along."""

    points: F64
    axis: int


class LiveTrack:
    """One object's state between frames (see the module's docstring)."""

    def __init__(
        self,
        id: int,
        points: F64,
        shape: F64,
        params: TrackerParams,
        velocity: F64 | None = None,
    ) -> None:
        """A track started from a view of its object (`points`) and its `shape`, at rest or
        at `velocity`."""
        self.id = id
        self.params = params
        self.filter = ConstantVelocity(points.mean(axis=0), params.motion, velocity)
        self.start = self.filter.position
        """Where it was first seen whole in view, as what it is now (not at the image's
        border, where its centroid moves as more of it comes into view, nor before a
        restart)..."""
        self.age_s = 0.0
        """...and how long ago."""
        self.shape = shape
        """3×3 covariance of the object's points: its size and orientation."""
        self.surface: SortedSurface | None = None
        """The cloud arranged for the distances, once arranged (until the cloud changes)."""
        self.cloud = subsample(points, params.cloud_points)
        self.usual_pixels = 0.0
        """The object's size in pixels when seen whole (slowly forgetting the largest view)."""
        self.measured = False
        """Whether the last frame measured the track (a whole, untainted view)."""
        self.entering = False
        """Whether it was last seen at the image's border."""
        self.hidden_s = 0.0
        self.hidden_frames = 0
        self.split_frames = 0
        """Frames running in which the track's mask held two surfaces..."""
        self.parted_frames = 0
        """...or fell in two parts with the scenery seen between them."""
        self.anchor: F64 | None = None
        """Where the track has been seen staying, its view's size there, and for how long
        (`still_s`)."""
        self.anchor_pixels = 0
        self.still_s = 0.0
        self.away_s = 0.0
        """How long it has been seen away from `anchor` since it was last seen there."""
        self.seed: F64 | None = None
        """A seeded target's seed point, from its centroid."""
        self.last: Track | None = None
        """What was reported of it in the last frame it was followed in."""

    @property
    def cloud(self) -> F64:
        """(N, 3) a subsample of the object's surface, where it is predicted to be now."""
        return self._cloud

    @cloud.setter
    def cloud(self, points: F64) -> None:
        self._cloud = points
        self.surface = None  # arranged anew when next needed

    def predict(self, dt: float, prior: VelocityPrior | None) -> None:
        """Move on `dt` seconds; `prior` is the belt's velocity, when known: an object not
        measured last frame keeps the belt's pace, one seen goes by its own motion (not
        everything in view rides the belt)."""
        before = self.filter.position
        self.age_s += dt
        self.filter.predict(dt)
        if prior is not None and not self.measured:
            self.filter.follow_belt(prior)
        shift = self.filter.position - before
        surface = self.surface
        self.cloud = self.cloud + shift
        if surface is not None:
            # a surface moved as a whole keeps its arrangement: move that along too
            self.surface = SortedSurface(surface.points + shift, surface.axis)

    def see(self, points: F64, box: Box, entering: bool, belt: BeltGeometry | None) -> None:
        """Seen this frame at `points`, within `box` (`entering`: at the image's border). A
        partial view (occlusion) or a tainted one (something else taken in) is not measured:
        its centroid is off, so the track coasts on its prediction, and its shape and
        surface stay as last seen whole, moved on with it."""
        p = self.params
        m = len(points)
        usual = self.usual_pixels
        whole = p.whole_fraction * usual <= m and (entering or m * p.whole_fraction <= usual)
        # a target that bends (a person) shows all of itself in every view
        self.measured = usual == 0 or whole or not p.rigid
        summary = measure_kernels.point_stats(points)  # mean, min and max
        if self.measured:
            self.filter.correct(summary[0])
            self.shape = 0.5 * self.shape + 0.5 * shape_of(points, SHAPE_FLOOR_M, belt)
            self.cloud = subsample(points, p.cloud_points)
            self.usual_pixels = max(float(m), USUAL_MEMORY * usual)
        self.hidden_s = 0.0
        self.hidden_frames = 0
        self.entering = entering
        if entering:
            self.start, self.age_s = self.filter.position, 0.0
        self.last = self.report(points, box, summary)

    def restart(self, points: F64, belt: BeltGeometry | None) -> None:
        """What it holds now (`points`) is a new view of it: its state starts again from this
        view, at the velocity it had."""
        p = self.params
        self.filter = ConstantVelocity(points.mean(axis=0), p.motion, self.filter.velocity)
        self.shape = shape_of(points, SHAPE_FLOOR_M, belt)
        self.cloud = subsample(points, p.cloud_points)
        self.usual_pixels = 0.0
        self.start, self.age_s = self.filter.position, 0.0

    def coast(self, dt: float, frame: Frame) -> bool:
        """Not seen in this frame (`dt` seconds on): predicted through occlusion until hidden
        longer than `max_hidden_s` or out of view; whether it goes on."""
        self.measured = False
        self.hidden_s += dt
        self.hidden_frames += 1
        if self.hidden_s > self.params.max_hidden_s or not self.in_view(frame):
            return False
        pos = self.filter.position
        self.last = Track(
            self.id, pos, self.filter.velocity, pos, pos, (0, 0, 0, 0), 0,
            np.zeros((0, 3), np.float32), self.hidden_frames,
        )  # fmt: skip
        return True

    def stays_put(self, dt: float, hold_s: float | None) -> bool:
        """Whether it has been seen within `gate_m` of one place for `hold_s` (`dt` seconds
        more now) while the belt runs (`hold_s` None while it does not, `still_time`): part
        of the machine, not something on it. At the image's border a view that grows or
        shrinks is coming into or going out of view on a slow belt, not staying put."""
        p = self.params
        pos = self.filter.position
        if hold_s is None:
            self.anchor, self.still_s, self.away_s = None, 0.0, 0.0
            return False
        if not self.measured:  # not seen whole this frame: it neither stayed nor moved
            return False
        pixels = self.last.pixels if self.last is not None else 0
        if self.anchor is None:
            self.anchor, self.anchor_pixels, self.still_s, self.away_s = pos, pixels, 0.0, 0.0
            return False
        resized = abs(pixels - self.anchor_pixels) > (1 - p.whole_fraction) * self.anchor_pixels
        if np.linalg.norm(pos - self.anchor) > p.gate_m or (self.entering and resized):
            # seen away from where it stayed: a moment (something passing took in part of
            # it) is forgiven, a quarter of `hold_s` is a move
            self.away_s += dt
            if self.away_s > hold_s / 4:
                self.anchor, self.anchor_pixels = pos, pixels
                self.still_s, self.away_s = 0.0, 0.0
            return False
        self.away_s = 0.0
        self.still_s += dt
        return self.still_s > hold_s

    def pace(self, still_s: float, gate_m: float) -> float:
        """The pace (m/s) it was carried off at from where it was first seen whole, if
        followed for `still_s / 2` at least and carried `2 gate_m` or more; else 0."""
        if self.age_s < still_s / 2:
            return 0.0
        far = float(np.linalg.norm(self.filter.position - self.start))
        return far / self.age_s if far > 2 * gate_m else 0.0

    def in_view(self, frame: Frame) -> bool:
        """Whether the predicted centroid still falls on the sensor."""
        pos = self.filter.position
        if pos[2] <= 0:
            return False
        # the sensor's field of view, from its corner pixels, in normalised coordinates
        corners = frame.xyz[[0, 0, -1, -1], [0, -1, 0, -1]]
        xs = corners[:, 0] / corners[:, 2]
        ys = corners[:, 1] / corners[:, 2]
        x, y = pos[0] / pos[2], pos[1] / pos[2]
        return bool(xs.min() <= x <= xs.max() and ys.min() <= y <= ys.max())

    def report(self, points: F64, box: Box, summary: tuple[F64, F64, F64] | None = None) -> Track:
        """What is reported of it seen this frame at `points`, within `box` (`summary`: the
        points' `measure_kernels.point_stats`, where already taken)."""
        bbox = (box[1].start, box[0].start, box[1].stop, box[0].stop)
        centroid, lo, hi = summary or measure_kernels.point_stats(points)
        return Track(
            self.id, centroid, self.filter.velocity, lo, hi, bbox, len(points),
            points.astype(np.float32),
        )  # fmt: skip


def subsample(points: F64, n: int) -> F64:
    """At most n of the points, evenly spread through the array (deterministic)."""
    if len(points) <= n:
        return points
    return points[_spread(len(points), n)]


@functools.lru_cache(maxsize=256)
def _spread(m: int, n: int) -> I64:
    """`np.linspace(0, m - 1, n).astype(np.int64)`, made once for each (m, n) (read-only):
    a track's pixel count changes little from frame to frame."""
    out = np.linspace(0, m - 1, n).astype(np.int64)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=4)
def _floor_cov(floor_m: float) -> F64:
    """`np.eye(3) * floor_m**2`, made once (read-only)."""
    out = np.eye(3) * floor_m**2
    out.flags.writeable = False
    return out


def shape_of(points: F64, floor_m: float, belt: BeltGeometry | None = None) -> F64:
    """Covariance of a point cloud, kept from collapsing in thin directions. On a belt an
    object reaches down to the belt, though the camera sees mostly its top: the spread
    along the belt's normal is at least that of a solid from the belt to its top."""
    cov = stats.covariance(points) if len(points) > 3 else np.zeros((3, 3))
    cov = cov + _floor_cov(floor_m)
    if belt is not None and len(points):
        n = belt.normal
        top = stats.percentile((points - belt.point) @ n, 90)
        missing = top * top / 3.0 - float(n @ cov @ n)
        if missing > 0:
            cov = cov + missing * np.outer(n, n)
    return np.asarray(cov)
