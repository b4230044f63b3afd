"""Measuring and creating tracks: the live tracks, and what each frame's labels do to them.

Each frame, every track is measured from its mask (`LiveTrack.see`), grown by what stands
out right beside it and goes on from its surface, any top it shows at the track's height (an
object coming into view), or coasts unseen (`LiveTrack.coast`). What stands out and no track
can claim, two frames running, becomes a new track. Rigid objects: a track holding two
touching surfaces (a step apart, or two tops at different heights: `tofcut.tracker.tops`),
or two parts with the scenery seen between them, for a few frames has them dealt out again
(two objects that came into view as one, or one the cut gave a track beside it), two tracks
that meet at a convex edge with no step are faces of one object and become one, and a track
that stays put while the belt runs becomes scenery; what lies beside a belt of known width,
or flat on a belt laid anew, is no object. Targets the user gives are started from their
seeds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from tofcut._types import F64, I32, I64, U16, B
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.frames import Frame
from tofcut.tracker import components_kernels, frame_kernels, measure_kernels
from tofcut.tracker.background import BackgroundModel
from tofcut.tracker.belt_prior import VelocityPrior
from tofcut.tracker.cut import JointCut
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.live_track import SHAPE_FLOOR_M, Box, LiveTrack, shape_of
from tofcut.tracker.neighbours import EIGHT, sides_reached
from tofcut.tracker.params import TrackerParams
from tofcut.tracker.pieces import Pieces
from tofcut.tracker.tops import (
    MIN_TOP,
    facing_up,
    heights_apart,
    level,
    meetings,
    seamless,
    sides_of,
    top_height,
)

MIN_PIECE = 5
"""Pieces smaller than this are noise, not more of an object coming into view."""


@dataclass(eq=False)
class Candidate:
    """What stands out and no track claims, seen again within `gate_m`: how often so far."""

    centroid: F64
    seen: int = 1


@dataclass(frozen=True)
class Seed:
    """A target the user gave: a seed pixel (u, v) or a 3D point."""

    pixel: tuple[int, int] | None
    point: F64 | None


@dataclass(frozen=True)
class Measured:
    """The tracks a frame's measuring started and ended (`Roster.measure`)."""

    born: tuple[int, ...]
    ended: tuple[int, ...]


_NONE = np.zeros((0, 0), bool)


def _touching_pieces(labels: U16, pieces: I32, reach: int) -> dict[int, I32]:
    """Per track id, the pieces with a pixel within `reach` pixels (8-connected steps) of
    its mask: `pieces[binary_dilation(labels == id, EIGHT, reach)]`, for all tracks at
    once (`measure_kernels.touching`)."""
    ids, starts, near = measure_kernels.touching(labels, pieces, reach)
    return {i: near[starts[k] : starts[k + 1]] for k, i in enumerate(ids.tolist())}


class Roster:
    """The live tracks, the candidates for new ones and the targets to start (see the
    module's docstring); the cut (for its distances) and the pieces it measures with."""

    def __init__(self, params: TrackerParams, cut: JointCut, pieces: Pieces) -> None:
        self.params = params
        self.cut = cut
        self.pieces = pieces
        self.tracks: list[LiveTrack] = []
        self.candidates: list[Candidate] = []
        self.seeds: list[Seed] = []
        """Targets to start from the next frame on."""
        self.joining: dict[tuple[int, int], int] = {}
        """Pairs of tracks seen as faces of one object, and for how many frames running."""
        self._next_id = 1
        self.seen_pace = 0.0
        """The pace (m/s) a rigid track has been seen carried off at (`LiveTrack.pace`), 0
        until one is: the belt runs, though nothing gave its speed yet."""

    def add_seed(self, seed: Seed) -> None:
        """A known target to follow from the next frame on."""
        self.seeds.append(seed)

    def take_seeds(self, frame: Frame, belt: BeltGeometry | None) -> list[int]:
        """Start the targets given by the user, each as the region round its seed
        (`_region`), so it is followed whole from the first frame; their ids."""
        born = []
        h, w = frame.shape
        for target in self.seeds:
            pixel, point = target.pixel, target.point
            if pixel is None:
                assert point is not None
                v, u = _nearest_pixel(frame, point)
            else:
                u, v = pixel
                if not (0 <= u < w and 0 <= v < h):
                    raise SegmentError(f"seed pixel {pixel} is outside the {w}x{h} frame")
                if not frame.valid[v, u]:
                    raise SegmentError(f"seed pixel {pixel} is not valid in this frame")
            seed = frame.xyz[v, u]
            pts = frame.xyz[self._region(frame, seed)]
            born.append(self._start(pts, shape_of(pts, SHAPE_FLOOR_M, belt)))
            self.tracks[-1].seed = seed - self.tracks[-1].filter.position
        self.seeds.clear()
        return born

    def _region(self, frame: Frame, centre: F64) -> B:
        """A seeded target: the pixels within `seed_radius_m` of the 3D point `centre`
        connected in the image to the one nearest it (the paper's µ_d and its 3D distance:
        a body, an arm in front of it and the legs below it, but not the floor and walls
        beyond that distance)."""
        v, u = _nearest_pixel(frame, centre)
        ball = frame.valid & (
            np.linalg.norm(frame.xyz - centre, axis=-1) < self.params.seed_radius_m
        )
        ball[v, u] = True
        parts, _ = ndimage.label(ball, EIGHT)
        region: B = parts == parts[v, u]
        return region

    def grown(self, frame: Frame) -> U16:
        """Labels while the scenery is being learned: each seeded track is the region round
        its seed, moved on with the track (a cut needs the scenery; pixels left out of the
        target now would be learned as scenery)."""
        labels = np.zeros(frame.shape, np.uint16)
        for t in self.tracks:
            if t.seed is not None:
                region = self._region(frame, t.filter.position + t.seed)
                labels[region & (labels == 0)] = t.id
        return labels

    def points(self) -> F64:
        """(N, 3) every track's predicted surface points."""
        return np.concatenate([t.cloud for t in self.tracks] + [np.zeros((0, 3))])

    def _start(self, points: F64, shape: F64, velocity: F64 | None = None) -> int:
        """A new track, from a view of its object and its shape; its id."""
        track = LiveTrack(self._next_id, points, shape, self.params, velocity)
        self._next_id += 1
        self.tracks.append(track)
        return track.id

    def measure(
        self,
        frame: Frame,
        labels: U16,
        dt: float,
        noise: F64,
        background: BackgroundModel,
        belt: BeltGeometry | None,
        seen: F64,
    ) -> Measured:
        """Update every track from its mask in `labels` (`dt` seconds since the last frame),
        and look for new objects (`seen`: the frame's `BackgroundModel.seen_range`). Changes
        `labels`."""
        p = self.params
        ended: list[int] = []
        keep: list[LiveTrack] = []
        born = self._reconcile(frame, labels, noise, belt)
        ended += self._join(frame, labels, noise, belt)
        born += self._part(frame, labels, noise, belt, background, seen)
        pieces = (
            self.pieces.loose(frame, labels, noise, background, belt, seen)
            if background.ready
            else None
        )
        # across a 3D step, what stands out lies past the seam the step leaves
        seam = 1 if p.rigid else 2
        touching = _touching_pieces(labels, pieces, seam) if pieces is not None else {}
        # each track's box and points (`ndimage.find_objects`, `frame.xyz[box][mask]`)
        corners, starts, held = measure_kernels.label_points(
            labels, frame.xyz, np.array([t.id for t in self.tracks], np.int64)
        )
        piece_boxes: I64 | None = None  # (pieces, 4), as `measure_kernels.piece_boxes`
        for k, t in enumerate(self.tracks):
            r0, r1, c0, c1 = corners[k].tolist()
            box = (slice(r0, r1), slice(c0, c1)) if starts[k + 1] > starts[k] else None
            mask = labels[box] == t.id if box is not None else _NONE  # within the box
            n = int(starts[k + 1] - starts[k])
            if n >= p.min_pixels:
                assert box is not None
                pts = held[starts[k] : starts[k + 1]]
                entering = sides_reached(box, labels.shape) > 0
                if pieces is not None and t.id in touching:
                    # what stands out right beside a track and goes on from its surface is
                    # more of it: an object coming into view is bigger than its mask, one
                    # first seen in part (a bag's rounded rim, a roll's far end) bigger than
                    # its shape, and a person may have moved a limb where its prediction
                    # did not reach
                    if piece_boxes is None:
                        piece_boxes = measure_kernels.piece_boxes(pieces)
                    beside = self._continuing(
                        frame, mask, box, pieces, touching[t.id], piece_boxes, noise, belt
                    )
                    if beside.size:
                        # all of it lies within its box and those of the pieces it takes,
                        # which are whole (none was taken before): its box is theirs
                        win = _union(box, piece_boxes[beside - 1])
                        taken = np.zeros(len(piece_boxes) + 1, bool)  # by piece
                        taken[beside] = True
                        grown = taken[pieces[win]] | _placed(mask, box, win)
                        pieces[win][grown] = 0
                        labels[win][grown] = t.id
                        box = win
                        pts = frame_kernels.points_in(frame.xyz, grown, win[0].start, win[1].start)
                t.see(pts, box, entering, belt)
            else:
                if box is not None:
                    labels[box][mask] = 0
                if not t.coast(dt, frame):
                    ended.append(t.id)
                    continue
            keep.append(t)
        self.tracks = keep
        if pieces is not None:
            born += self._detect(frame, pieces, labels, noise, belt)
        return Measured(tuple(born), tuple(ended))

    def off_belt(self, labels: U16, belt: BeltGeometry | None) -> list[int]:
        """Rigid objects on a belt of known width: end the tracks seen this frame beside the
        belt (`_beside`; begun before its width was known); their ids. Changes `labels`."""
        if not self.params.rigid or belt is None or belt.width_m is None:
            return []
        return self._end(labels, lambda pts: _beside(pts, belt))

    def flat_on(self, labels: U16, belt: BeltGeometry, min_height_m: float) -> list[int]:
        """End the tracks seen this frame lying flat on the belt (the median height of their
        points under half of `min_height_m`): the belt itself, taken for an object while
        another layer (the floor under a raised belt) was taken for the belt; their ids.
        Changes `labels`."""
        return self._end(labels, lambda pts: float(np.median(belt.height(pts))) < min_height_m / 2)

    def _end(self, labels: U16, wrong: Callable[[F64], bool]) -> list[int]:
        """End the tracks whose points this frame (`LiveTrack.last`) are `wrong`: no object
        on the belt; their ids. Changes `labels`."""
        ended = []
        for t in list(self.tracks):
            if t.last is not None and t.last.pixels and wrong(t.last.points.astype(np.float64)):
                labels[labels == t.id] = 0
                self.tracks.remove(t)
                ended.append(t.id)
        return ended

    def to_scenery(
        self,
        frame: Frame,
        labels: U16,
        prior: VelocityPrior | None,
        dt: float,
        noise: F64,
        background: BackgroundModel,
    ) -> list[int]:
        """End the tracks that stay put while the belt runs, their pixels becoming scenery
        (`still_time`); their ids. Changes `labels`. The belt runs by its velocity `prior`,
        or, while none is known, at the pace a rigid track has been seen carried off at
        (`seen_pace`): a rail's ghost need not wait for the belt's travel to be found."""
        p = self.params
        bg = background
        if prior is not None and prior.informed:
            pace = float(np.linalg.norm(prior.mean))
        else:
            if not self.seen_pace and p.rigid:  # once seen, the belt runs: no need to look again
                paces = [t.pace(p.still_s, p.gate_m) for t in self.tracks if t.measured]
                pace = max(paces, default=0.0)
                self.seen_pace = pace if still_time(pace, p.still_s, p.gate_m) else 0.0
            pace = self.seen_pace
        hold_s = still_time(pace, p.still_s, p.gate_m)
        ended = []
        for t in list(self.tracks):
            if t.stays_put(dt, hold_s):
                mask = labels == t.id
                bg.absorb(frame, mask, noise)
                labels[mask] = 0
                self.tracks.remove(t)
                ended.append(t.id)
        return ended

    def _join(self, frame: Frame, labels: U16, noise: F64, belt: BeltGeometry | None) -> list[int]:
        """Rigid objects on a known belt: two tracks whose masks meet with no step between
        them and no two tops at different heights (`tops.one_object`'s two steps, `seamless`
        and `level`), or where one is a side face of the other (`tops.sides_of`), for
        `split_frames` frames running hold faces of one object (its side seen first, a rim,
        the far end of a roll): the younger is handed to the older. Changes `labels`; the ids
        ended."""
        p = self.params
        if not p.rigid or belt is None or len(self.tracks) < 2:
            self.joining = {}
            return []
        met = meetings(labels)
        pairs = seamless(labels, frame.xyz, p.joined_m, met)
        if pairs:  # what faces up is weighed only where two tracks meet so
            pairs = level(
                pairs, labels, facing_up(labels > 0, frame.xyz, noise, belt), frame.xyz, belt
            )
        pairs += sides_of(labels, frame.xyz, noise, belt, known=set(pairs), met=met)
        self.joining = {pair: self.joining.get(pair, 0) + 1 for pair in pairs}
        ended: list[int] = []
        for (older, younger), frames in sorted(self.joining.items()):
            if frames < p.split_frames or older in ended or younger in ended:
                continue
            keep = next(t for t in self.tracks if t.id == older)
            self.tracks = [t for t in self.tracks if t.id != younger]
            labels[labels == younger] = older
            ended.append(younger)
            keep.restart(frame.xyz[labels == older], belt)
        self.joining = {k: v for k, v in self.joining.items() if not set(k) & set(ended)}
        return ended

    def _reconcile(
        self, frame: Frame, labels: U16, noise: F64, belt: BeltGeometry | None
    ) -> list[int]:
        """Deal the surfaces out again where a track has held two for `split_frames` frames
        (two objects that came into view together, taken as one, or split along the wrong
        line): each surface goes whole to one of the tracks holding it, most pixels kept in
        place; a surface left over is a new track. Changes `labels`; the new tracks' ids."""
        p = self.params
        if not p.rigid or not self.tracks:
            return []  # a person's limbs are not other people
        pieces = self.pieces.split(frame, labels > 0, noise, belt, step_noise=False)
        n_pieces = int(pieces.max()) + 1
        row = np.zeros(max(t.id for t in self.tracks) + 1, np.int64)
        for k, t in enumerate(self.tracks):
            row[t.id] = k + 1
        # by track, the pixels of each piece (none of piece 0, which is no piece)
        held = measure_kernels.held_pieces(labels, pieces, row, len(self.tracks) + 1, n_pieces)[1:]
        size = held.sum(axis=1)
        big = (held >= p.min_pixels) & (
            held >= np.minimum(p.split_share * size[:, None], p.split_pixels)
        )
        small = (held >= p.min_pixels) & ~big
        if belt is not None and small.any():
            big |= self._own_tops(small, pieces, labels, frame, noise, belt)
        splitting = []
        many = big.sum(axis=1) >= 2
        for k, t in enumerate(self.tracks):
            two = bool(many[k]) and _two_objects(
                pieces, np.nonzero(big[k])[0], labels == t.id, frame.range, p.connect_m
            )
            t.split_frames = t.split_frames + 1 if two else 0
            if t.split_frames >= p.split_frames:
                splitting.append(k)
        if not splitting:
            return []
        surfaces = np.nonzero(big[splitting].any(axis=0))[0]
        involved = np.nonzero((held[:, surfaces] >= p.min_pixels).any(axis=1))[0]
        rows, cols = linear_sum_assignment(held[np.ix_(involved, surfaces)], maximize=True)
        owner = dict(zip(surfaces[cols].tolist(), involved[rows].tolist(), strict=True))
        # the surfaces' pixels are dealt out anew; elsewhere the cut's labels stand
        dealt = np.isin(pieces, surfaces)
        labels[dealt] = 0
        born = []
        for r in surfaces.tolist():
            surface = pieces == r
            if r in owner:
                labels[surface] = self.tracks[owner[r]].id
            else:
                # it moved with the track that held most of it
                carrier = self.tracks[int(np.argmax(held[:, r]))].filter.velocity
                pts = frame.xyz[surface]
                shape = shape_of(pts, SHAPE_FLOOR_M, belt)
                labels[surface] = self._start(pts, shape, carrier)
                born.append(int(labels[surface][0]))
        for k in involved.tolist():
            t = self.tracks[k]
            t.split_frames = 0
            pts = frame.xyz[labels == t.id]
            if len(pts) < p.min_pixels:
                continue
            t.restart(pts, belt)
        return born

    def _own_tops(
        self, small: B, pieces: I32, labels: U16, frame: Frame, noise: F64, belt: BeltGeometry
    ) -> B:
        """Of the `small` surfaces (by track and piece, as `_reconcile` holds them: under
        `split_share` of their track and `split_pixels`), those that are an object's top:
        half of the surface or more faces up (`tops.facing_up`), at a height apart from the
        top of the rest of the track's mask (`tops.heights_apart`). A low box pressed
        against a tall one is a small share of their track; the tall one's side face does
        not face up, and a top that noise or a rim breaks up stands at one height."""
        out = np.zeros(small.shape, bool)
        up = facing_up(labels > 0, frame.xyz, noise, belt)
        if up is None:
            return out
        whole = np.bincount(pieces.ravel())
        facing = 2 * np.bincount(pieces[up], minlength=whole.size) >= whole
        for k, r in zip(*np.nonzero(small & facing[None, :]), strict=True):
            piece = pieces == r
            mine = _top(piece & up, frame.xyz, noise, belt)
            rest = _top((labels == self.tracks[k].id) & ~piece & up, frame.xyz, noise, belt)
            out[k, r] = mine is not None and rest is not None and bool(heights_apart(*mine, *rest))
        return out

    def _part(
        self,
        frame: Frame,
        labels: U16,
        noise: F64,
        belt: BeltGeometry | None,
        background: BackgroundModel,
        seen: F64,
    ) -> list[int]:
        """Rigid objects: a track whose mask has fallen in parts, two of them large (each
        `min_pixels` and `split_share` of it or `split_pixels`) with the scenery seen between
        them (`_scenery_between`: not an occluder, nor a band of an object the cut missed),
        for `split_frames` frames running, holds two objects apart (the cut gave it a second
        object that came into view beside it, and its shape grew to hold both): its largest
        part stays its own, each other large part goes to the track that can claim it
        (`_claimant`: more of an object it follows) or becomes a new track, at its velocity.
        Changes `labels`; the new tracks' ids."""
        p = self.params
        if not p.rigid or not self.tracks or not background.ready:
            return []
        regions, owner, large = _large_regions(labels, p)
        # the tracks whose masks hold two large regions or more
        parted = np.bincount(owner[large]) >= 2
        born: list[int] = []
        for t in list(self.tracks):
            apart = np.zeros(0, np.int64)
            if t.id < parted.size and parted[t.id]:
                mask = labels == t.id
                box = _box_of(mask)
                parts = np.where(mask[box], regions[box], 0)
                big = np.nonzero(large & (owner == t.id))[0]
                bg = background
                nearer = np.where(
                    frame.valid[box] & bg.known[box], bg.range[box] - seen[box], np.nan
                )
                apart = _scenery_between(
                    parts, big, frame.range[box], nearer, bg.sigma[box], p.connect_m
                )
            t.parted_frames = t.parted_frames + 1 if apart.size else 0
            if t.parted_frames < p.split_frames:
                continue
            t.parted_frames = 0
            window = labels[box]
            others = [o for o in self.tracks if o is not t]
            for r in apart.tolist():
                part = parts == r
                pts = frame.xyz[box][part]
                claimant = self._claimant(others, pts, noise[box][part])
                if claimant is not None:  # more of an object another track follows
                    window[part] = claimant.id
                    continue
                shape = shape_of(pts, SHAPE_FLOOR_M, belt)
                window[part] = self._start(pts, shape, t.filter.velocity)
                born.append(int(window[part][0]))
            t.restart(frame.xyz[labels == t.id], belt)
        return born

    def _claimant(self, tracks: list[LiveTrack], points: F64, noise: F64) -> LiveTrack | None:
        """The track that can claim `points` (their median distance cost from it under what
        a pixel could cost the background: `_detect`'s rule), the nearest if several."""
        p = self.params
        if not tracks:
            return None
        near = np.median(self.cut.distances(tracks, points, noise), axis=1)
        k = int(np.argmin(near))
        return tracks[k] if near[k] < p.claim_distance else None

    def _continuing(
        self,
        frame: Frame,
        mask: B,
        box: Box,
        pieces: I32,
        near: I32,
        piece_boxes: I64,
        noise: F64,
        belt: BeltGeometry | None,
    ) -> I32:
        """Which pieces beside a track's `mask` (within its `box`) are more of the same
        object (pieces smaller than MIN_PIECE are noise): for rigid targets, those that go on
        from the mask's surface without a 3D step (`joined_m`) and, on a known belt, with their
        top at the height of the mask's (`_on_level`); for targets that bend, all (a limb).
        `piece_boxes` are the pieces' boxes (`measure_kernels.piece_boxes`), `noise` each
        pixel's range noise."""
        ids = near.astype(np.int64)
        sizes, meet, joined = measure_kernels.seams(
            mask, box[0].start, box[1].start, pieces, ids, piece_boxes[ids - 1], frame.xyz,
            self.params.joined_m,
        )  # fmt: skip
        keep = []
        most = 0  # the most pixels of a piece kept
        for k, r in enumerate(near.tolist()):
            if sizes[k] < MIN_PIECE:
                continue
            # for rigid targets: most of the seam without a step
            if self.params.rigid and not (meet[k] and joined[k] / meet[k] >= 0.5):
                continue
            keep.append(r)
            most = max(most, int(sizes[k]))
        # a piece of fewer than `MIN_TOP` pixels shows no top (most of what comes into view)
        if most >= MIN_TOP and self.params.rigid and belt is not None:
            keep = _on_level(frame, mask, box, pieces, keep, piece_boxes, noise, belt)
        return np.array(keep, np.int32)

    def _detect(
        self, frame: Frame, pieces: I32, labels: U16, noise: F64, belt: BeltGeometry | None
    ) -> list[int]:
        """Pieces no track can claim become candidates; one seen `confirm_frames` times in a
        row (within `gate_m`), a track. A piece most of which a track could claim is a
        fringe of that track, not a new object; one beside the belt (`_beside`), none."""
        p = self.params
        sizes = measure_kernels.piece_sizes(pieces)
        found = []
        for r in np.nonzero(sizes >= p.min_pixels)[0]:
            if r == 0:
                continue
            piece = pieces == r
            if not _solid(piece, p.min_pixels):
                continue
            pts = frame_kernels.points_in(frame.xyz, piece, 0, 0)
            centroid = pts.mean(axis=0)
            if p.rigid and belt is not None and _beside(pts, belt):
                continue
            if (
                self.tracks
                and np.median(self.cut.distances(self.tracks, pts, noise[piece]).min(axis=0))
                < p.claim_distance
            ):
                continue
            found.append((centroid, pts, piece))
        born = []
        next_candidates = []
        for centroid, pts, piece in found:
            match = None
            for c in self.candidates:
                if np.linalg.norm(c.centroid - centroid) < p.gate_m:
                    match = c
                    break
            if match is None:
                next_candidates.append(Candidate(centroid))
                continue
            self.candidates.remove(match)
            match.seen += 1
            match.centroid = centroid
            if match.seen >= p.confirm_frames:
                born.append(self._start(pts, shape_of(pts, SHAPE_FLOOR_M, belt)))
                t = self.tracks[-1]
                labels[piece] = t.id
                t.usual_pixels = float(len(pts))
                t.last = t.report(pts, _box_of(piece))
            else:
                next_candidates.append(match)
        self.candidates = next_candidates
        return born


OVER_SHARE = 0.25
"""Share of an object's points over the belt, at the least: what the belt carries stands on it,
and one at its edge seen from the side still shows half its points over it."""


def _beside(points: F64, belt: BeltGeometry) -> bool:
    """Whether points lie beside the belt, not on it: fewer than `OVER_SHARE` of them over
    its width (never where the width is not known)."""
    return belt.width_m is not None and float(belt.over_belt(points).mean()) < OVER_SHARE


def _on_level(
    frame: Frame,
    mask: B,
    box: Box,
    pieces: I32,
    keep: list[int],
    piece_boxes: I64,
    noise: F64,
    belt: BeltGeometry,
) -> list[int]:
    """Of the pieces `keep` that go on from a track's `mask` (within its `box`), those whose
    top is not at a height apart from the mask's (`tops.heights_apart`): an object pressed
    against another meets it with no step, the one's side face running into the other's top,
    but their tops stand apart."""
    if np.count_nonzero(mask) < MIN_TOP:
        return keep
    win = _union(box, piece_boxes[np.array(keep) - 1])
    held = _placed(mask, box, win)
    cut = pieces[win]
    kept = np.zeros(len(piece_boxes) + 1, bool)  # by piece
    kept[keep] = True
    # contiguous, as the compiled kernels take them
    xyz, spread = np.ascontiguousarray(frame.xyz[win]), np.ascontiguousarray(noise[win])
    up = facing_up(held | kept[cut], xyz, spread, belt)
    if up is None:
        return keep
    own = _top(held & up, xyz, spread, belt)
    if own is None:
        return keep
    out = []
    for r in keep:
        top = _top((cut == r) & up, xyz, spread, belt)
        if top is None or not heights_apart(*own, *top):
            out.append(r)
    return out


def _top(top: B, xyz: F64, noise: F64, belt: BeltGeometry) -> tuple[float, float] | None:
    """The height of a top (`tops.top_height`) and the noise of its pixels' mean height, if
    it has `MIN_TOP` pixels."""
    height = top_height(top, xyz, belt)
    if height is None:
        return None
    spread = noise[top]
    return height, float(np.sqrt(np.mean(spread**2) / spread.size))


def _solid(piece: B, min_pixels: int) -> bool:
    """Whether a piece has a body: `min_pixels` / 2 pixels or more whose 3×3 neighbourhood is
    all in it, or it is coming into view. A sliver along a depth edge (mixed pixels
    flickering in front of the scenery, a rail's rim) has none; the narrowest object has."""
    box = _box_of(piece)
    if sides_reached(box, piece.shape) > 0:
        return True  # coming into view: a sliver of it first
    core = ndimage.binary_erosion(piece[box], EIGHT)
    return int(np.count_nonzero(core)) * 2 >= min_pixels


def _nearest_pixel(frame: Frame, point: F64) -> tuple[int, int]:
    """(v, u) of the valid pixel whose 3D point is nearest `point`."""
    dist = np.linalg.norm(frame.xyz - point, axis=-1)
    dist[~frame.valid] = np.inf
    v, u = np.unravel_index(int(np.argmin(dist)), dist.shape)
    return int(v), int(u)


def _placed(mask: B, box: Box, win: Box) -> B:
    """`mask`, which covers `box`, as it falls within the window `win` (False elsewhere)."""
    out = np.zeros((win[0].stop - win[0].start, win[1].stop - win[1].start), bool)
    r0, r1 = max(box[0].start, win[0].start), min(box[0].stop, win[0].stop)
    c0, c1 = max(box[1].start, win[1].start), min(box[1].stop, win[1].stop)
    if r0 < r1 and c0 < c1:
        out[r0 - win[0].start : r1 - win[0].start, c0 - win[1].start : c1 - win[1].start] = mask[
            r0 - box[0].start : r1 - box[0].start, c0 - box[1].start : c1 - box[1].start
        ]
    return out


def _union(box: Box, corners: I64) -> Box:
    """The smallest box holding `box` and the boxes of (n, 4) `corners` (first row, row past
    the last, first column, column past the last)."""
    rows, cols = box
    r0, r1, c0, c1 = rows.start, rows.stop, cols.start, cols.stop
    for a0, a1, b0, b1 in corners.tolist():
        r0, r1, c0, c1 = min(r0, a0), max(r1, a1), min(c0, b0), max(c1, b1)
    return slice(r0, r1), slice(c0, c1)


def _box_of(mask: B) -> tuple[slice, slice]:
    """The bounding slices (rows, columns) of a mask that is not empty."""
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)


def _large_regions(labels: U16, p: TrackerParams) -> tuple[I32, I64, B]:
    """Every track's mask in its 8-connected regions, all at once
    (`components_kernels.region_sizes`): the regions (numbered from 1), each region's track,
    and whether it is large enough to be an object of its own: `min_pixels`, and
    `split_share` of its track's mask or `split_pixels`."""
    regions, owner, sizes = components_kernels.region_sizes(labels)
    pixels = np.bincount(owner, weights=sizes)[owner]  # of each region's track
    large = sizes >= np.maximum(p.min_pixels, np.minimum(p.split_share * pixels, p.split_pixels))
    large[0] = False
    return regions, owner, large


def _scenery_between(
    parts: I32, big: I64, ranges: F64, nearer: F64, sigma: F64, step_m: float
) -> I64:
    """Of a mask's `big` parts (numbered in `parts`), those apart from the largest with the
    scenery seen between: the band of pixels along the shortest way across (`_behind`)
    reads farther than both by `step_m` (`ranges`), and reads the scenery (`nearer`: how
    far each pixel stands in front of it, NaN where not known; its median within the median
    of the scenery's noise `sigma`). The belt between two objects is that; an occluder in
    front (a gantry, part of the scenery too), or a band of an object's own surface the cut
    missed, even a low one in loud noise, is not."""
    sizes = np.bincount(parts.ravel())
    first = int(big[np.argmax(sizes[big])])
    home = parts == first
    to_home = ndimage.distance_transform_edt(~home)
    apart = []
    for r in big.tolist():
        if r == first:
            continue
        band = _behind(home, parts == r, to_home, ranges, step_m)
        if band is None:
            continue
        read = band & np.isfinite(nearer)
        if read.any() and np.median(nearer[read]) < np.median(sigma[read]):
            apart.append(r)
    return np.array(apart, np.int64)


def _behind(home: B, there: B, to_home: F64, ranges: F64, step_m: float) -> B | None:
    """The band of pixels along the shortest way from `home` to `there` (`to_home`: each
    pixel's distance to `home`; neither's own pixels, within one pixel of the gap), if what
    it reads (`ranges`) lies farther than both by `step_m` on the median: something behind
    them is seen between them. None where it does not, or reads nothing."""
    to_there = ndimage.distance_transform_edt(~there)
    apart = to_home + to_there
    gap = float(apart[there].min())
    band = (apart <= gap + 1.0) & ~home & ~there
    seen = ranges[band]
    seen = seen[np.isfinite(seen)]
    if seen.size == 0:
        return None
    near = max(
        float(np.median(ranges[home & (to_there <= gap + 3)])),
        float(np.median(ranges[there & (to_home <= gap + 3)])),
    )
    return band if float(np.median(seen)) > near + step_m else None


def _two_objects(pieces: I32, surfaces: I64, mask: B, rng: F64, step_m: float) -> bool:
    """Whether a track's `mask` holds two objects: the largest of these pieces meets another
    of them within the mask (across the seam a 3D step leaves, or across a side face between
    them that noise breaks into specks), or another lies in a part of the mask that the
    scenery behind parts from it (the belt seen between them, `step_m` farther in range
    than both: `_behind`). One object seen either side of an occluder has the occluder in
    front."""
    box = _box_of(mask)
    inside, cut, ranges = mask[box], pieces[box], rng[box]
    parts, _ = ndimage.label(inside, EIGHT)
    sizes = np.bincount(pieces.ravel())
    first = surfaces[np.argmax(sizes[surfaces])]
    home = parts == np.bincount(parts[(cut == first) & inside]).argmax()
    others = np.isin(cut, surfaces[surfaces != first]) & inside
    if (others & home).any():
        return True
    to_home = ndimage.distance_transform_edt(~home)
    return any(
        _behind(home, parts == part, to_home, ranges, step_m) is not None
        for part in np.unique(parts[others]).tolist()
    )


def still_time(pace: float, still_s: float, gate_m: float) -> float | None:
    """How long a track must be seen within `gate_m` of one place, on a belt running at
    `pace` (m/s), to be part of the machine: `still_s`, or the time the belt takes to carry
    an object `2 gate_m`, whichever is longer. None on a belt too slow to tell (not `2
    gate_m` in twice `still_s`) or standing."""
    if pace * still_s <= gate_m:
        return None
    return max(still_s, 2 * gate_m / pace)
