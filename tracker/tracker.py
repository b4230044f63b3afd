"""The multi-object tracker: `Tracker.update(frame) -> TrackedFrame`, the per-frame step.

Each frame: every track predicts its 3D position (constant velocity; unseen, at the belt's
pace: `tofcut.tracker.live_track`); all tracks and the background then compete for the
pixels in one Potts energy (`tofcut.tracker.cut`) whose data term is the paper's eq. (6): a
pixel's cost for track k grows with its 3D distance from the track's prediction, measured in
the track's own shape (so a person and a box are both "near" over their own extent) and from
its predicted surface (so two touching objects are told apart), and its cost for the
background with how far it stands out in front of the empty-scene range model
(`tofcut.tracker.background`). The tracks are then measured from their masks, and what
stands out and no track can claim, two frames running, becomes a new track
(`tofcut.tracker.roster`, on the pieces of what stands out: `tofcut.tracker.pieces`). Rigid
objects on a belt: a track holding two touching surfaces (a step apart, or two tops at
different heights: `tofcut.tracker.tops`), or two parts with the belt seen between them, for
a few frames has them dealt out again (two objects that came into view as one), two tracks
that meet at a convex edge with no step are faces of one object and become one, a track that
stays put while the belt runs becomes scenery, and what lies beside a belt of known width,
or flat on a belt laid anew, is no object. A mask's rim, pixels read between the object and
the scenery behind it, is given to the track whose range it is nearer, and a notch in it to
the track round it (`tofcut.tracker.rims`). Each pixel's range noise
(`tofcut.tracker.noise`) scales what counts as near on far, dark targets. The belt is given
(`Tracker(belt=...)`) or set when it becomes known (`tracker.belt = ...`, as the run's belt
holder does with a belt found from the frames, `tofcut.tracker.belt_finder`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tofcut._types import F64
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.frames import Frame
from tofcut.tracker import compiled, frame_kernels
from tofcut.tracker.background import BackgroundModel
from tofcut.tracker.belt_prior import VelocityPrior
from tofcut.tracker.cut import JointCut
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.noise import range_noise
from tofcut.tracker.params import TrackerParams
from tofcut.tracker.pieces import Pieces
from tofcut.tracker.rims import add_rims
from tofcut.tracker.roster import Roster, Seed
from tofcut.tracker.tracks import TrackedFrame

__all__ = ["Tracker", "TrackerParams"]


class Tracker:
    """Frames in, tracks out. Feed every frame in order with `update`."""

    background_model: type[BackgroundModel] = BackgroundModel
    cut_model: type[JointCut] = JointCut
    pieces_model: type[Pieces] = Pieces

    def __init__(
        self, params: TrackerParams | None = None, belt: BeltGeometry | None = None
    ) -> None:
        self.params = params or TrackerParams()
        self._belt = belt
        self._belt_laid = False
        """Whether the belt has been put under what stood on it while the scenery was learned."""
        self.background: BackgroundModel | None = None
        self._last_time_us: int | None = None
        self.cut = self.cut_model(self.params)
        """The joint cut of all tracks (`tofcut.tracker.cut`)."""
        self.pieces = self.pieces_model(self.params)
        """What stands out, in pieces (`tofcut.tracker.pieces`)."""
        self.roster = Roster(self.params, self.cut, self.pieces)
        """The live tracks, measured and created (`tofcut.tracker.roster`)."""
        compiled.warm_up()

    @property
    def belt(self) -> BeltGeometry | None:
        """The belt objects ride on, where known."""
        return self._belt

    @belt.setter
    def belt(self, belt: BeltGeometry | None) -> None:
        """A belt that became known during the run (found from the data, or given late): used
        from the next frame on, and put under what the scenery took in on it."""
        if belt is not self._belt:
            self._belt = belt
            self._belt_laid = False

    def add_target(self, *, pixel: tuple[int, int] | None = None, point: F64 | None = None) -> None:
        """Follow a known target from the next frame on: a seed pixel (u, v) or a 3D point."""
        if (pixel is None) == (point is None):
            raise SegmentError(
                "give a target as a seed pixel or as a 3D point, not both or neither"
            )
        if point is not None:
            point = np.asarray(point, float)
            if point.shape != (3,) or not np.isfinite(point).all():
                raise SegmentError(f"a target point must be three finite numbers, got {point!r}")
        self.roster.add_seed(Seed(pixel, point))

    def update(self, frame: Frame, prior: VelocityPrior | None = None) -> TrackedFrame:
        """Track one frame; `prior` is the belt's velocity now, when known."""
        p = self.params
        frame = _checked(frame, self.background.shape if self.background is not None else None)
        h, w = frame.shape
        if self.background is None:
            self.background = self.background_model((h, w), p.background)
        dt = 0.0
        if self._last_time_us is not None:
            dt = max(0.0, (frame.device_time_us - self._last_time_us) / 1e6)
        self._last_time_us = frame.device_time_us
        noise = range_noise(frame, p.background.min_sigma_m)
        born = self.roster.take_seeds(frame, self.belt)
        for t in self.roster.tracks:
            t.predict(dt, prior)
        # before the scenery is known, a seeded target is what lies round its seed
        ready = self.background.ready
        # the frame's ranges as the scenery is compared with, once for the frame
        seen = self.background.seen_range(frame) if ready else frame.range
        labels = (
            self.cut.labels(frame, noise, self.roster.tracks, self.background, seen)
            if ready
            else self.roster.grown(frame)
        )
        measured = self.roster.measure(frame, labels, dt, noise, self.background, self.belt, seen)
        born += measured.born
        ended = list(measured.ended) + self.roster.off_belt(labels, self.belt)
        if ready and (prior is not None or (p.rigid and self.belt is not None)):
            still = self.roster.to_scenery(frame, labels, prior, dt, noise, self.background)
            if still:  # the scenery took them in: its ranges changed
                seen = self.background.seen_range(frame)
            ended += still
        occupied = self.roster.points()
        if ready:
            self.background.update(frame, labels == 0, noise, occupied, p.keep_clear_m, seen)
        else:
            self.background.learn(frame, noise, occupied, p.keep_clear_m)
        if not self._belt_laid and self.background.ready and self.belt is not None:
            # what stood on the belt while the scenery was learned is not scenery: the
            # belt goes under it, once the scenery and the belt are both known
            self.background.clear_belt(frame, self.belt)
            self._belt_laid = True
            ended += self.roster.flat_on(labels, self.belt, p.background.min_height_m)
        if ready and prior is not None and self.belt is not None:
            # a running belt: held from its travel on, not only once its width is seen (a
            # belt wider than the view never shows it)
            self.background.hold_belt(frame, self.belt, noise)
        out = tuple(t.last for t in self.roster.tracks if t.last is not None)
        if ready and out:
            bg = self.background
            rimmed = add_rims(labels, out, seen, frame.valid, bg.range, bg.known)
            labels, out = rimmed.labels, rimmed.tracks
        return TrackedFrame(frame, labels, out, tuple(born), tuple(ended))


def _checked(frame: Frame, shape: tuple[int, int] | None) -> Frame:
    """The frame as the compiled kernels may take it: of the run's size (`SegmentError` if
    not), its arrays of one shape, and every range and point finite (a NaN would reach an
    index): a pixel that is not is made invalid, at range 0."""
    h, w = frame.shape
    if shape is not None and (h, w) != shape:
        raise SegmentError(f"a {w}x{h} frame in a run of {shape[1]}x{shape[0]} frames")
    if frame.range.shape != (h, w) or frame.valid.shape != (h, w) or frame.xyz.shape != (h, w, 3):
        raise SegmentError("the frame's range, valid mask and points differ in shape")
    if frame_kernels.all_finite(frame.range, frame.xyz):
        return frame
    finite = np.isfinite(frame.range) & np.isfinite(frame.xyz).all(axis=-1)
    # a point the cut may still hand to a track (an invalid pixel inside an object) must
    # not carry a NaN into its cloud: such pixels read 0
    rng = np.where(finite, frame.range, 0.0)
    xyz = np.where(finite[..., None], frame.xyz, 0.0)
    return dataclasses.replace(frame, range=rng, xyz=xyz, valid=frame.valid & finite)
