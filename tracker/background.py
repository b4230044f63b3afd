"""A range model of the empty scene: what each pixel sees when nothing stands in front of it.

Objects only ever come *between* the camera and the scenery, so the model keeps, per pixel,
the far range that pixel keeps returning to. It starts from the first frames (the farthest
of them, so objects that pass through do not stick), and afterwards it follows the scene
where nothing is tracked: slowly towards what is seen, and at once where the scenery turns
out to be farther than thought (an object that stood still at the start and then left).
Scenery beyond the camera's unambiguous range reads near, its phase wrapped round: an object
in front of it reads farther than it, and is told by its height over the belt
(`BackgroundModel.seen_range`).
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass, fields

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from tofcut._types import F64, I64, B
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.frames import Frame
from tofcut.tracker import background_kernels
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.neighbours import EIGHT, pair_slices, sides_reached

NOISE_SHARE = 0.7
"""Share of the noise its amplitude implies that a pixel's learned noise is at least: three
frames' spread alone can make a pixel look many times quieter than it is."""
BLEND_SIGMAS = 2.5
BLEND_VARIANCE_SHARE = 0.9113
"""Variance of a standard normal truncated to ±2.5 (what the blended deviations have)."""
MEDIAN_SHARES = np.array([1.0, 0.418, 0.251, 0.179])
"""By radius r, the noise of the median of (2r+1)² independent readings as a share of one
reading's, √(π/2)/(2r+1) (0.418 for 3×3): the windows that quieten loud pixels are at most
7×7."""
MAX_RAIL_M = 0.1
"""Where the belt's width is not known, what stands on its plane while the scenery is learned
and is narrower than this..."""
MIN_RAIL_M = 0.5
"""...and longer than this is a rail or a guide beside the belt: it stays scenery."""
RAIL_BIN_M = 0.01
"""Bins across a part in which a rail's band is measured..."""
RAIL_RUN_SHARE = 0.7
"""A rail's band runs at least this share of the longest band's length in its part."""
RAIL_STRETCH_M = 0.05
"""...and along it, its length (far away, a pixel spans centimetres of a rail seen edge on)."""
LEVEL_M = 0.02
"""Scenery within this of the belt's plane is the belt (for where it lies, width unknown)..."""
BAND_TRIM = 1.0
"""...its band across the run taken between these percentiles of its points (a few of a
rail's, read low in noise, do not widen it)..."""
BAND_MARGIN_M = 0.01
"""...narrowed by this (a rail's inner face stands right at the belt's edge)..."""
RUN_TO_WIDTH = 1.5
"""...where its run in view is at least this many times that band (else the run is unclear)."""
TALLEST_SHARE = 0.5
"""Nothing standing on the belt is taller than this share of the camera's height above it."""
BEHIND_BELT_M = 0.3
"""Scenery read this much farther than the belt or more is not the belt (the floor beside a
belt whose width is not known, a leg of its stand)."""
REGION_SIDE = 5
"""Side (pixels) of the neighbourhood whose mean height decides where one pixel cannot."""
REGION_SIGMAS = 6.0
"""A neighbourhood stands out where its mean nearness is this many times its own noise..."""
REGION_HEIGHT_SHARE = 0.5
"""...and at least this share of `min_height_sigmas` of its pixels' noise: half the height
of the lowest object to be found, so that its pixels, not the belt's round it, pass."""
WRAPPED_SIGMAS = 6.0
"""Over scenery whose phase wrapped round, a pixel reads an object behind it where it reads
farther than the scenery by this many of the scenery's noise sigmas..."""
WRAPPED_STEP_M = 0.3
"""...and by this much."""


@dataclass(frozen=True)
class BackgroundParams:
    """How the empty-scene model learns and what counts as standing out of it."""

    learn_frames: int = 3
    """Frames used to start the model before anything is detected."""
    rate: float = 0.02
    """Per-frame weight of a new frame where nothing is tracked (a slow running mean)."""
    min_sigma_m: float = 0.004
    """Floor of a pixel's range noise: no pixel is trusted to better than this."""
    noise_factor: float = 4.0
    """A pixel stands out when it is nearer than the model by this many sigmas..."""
    min_height_m: float = 0.02
    """...and by at least this much (thin things lying flat are part of the belt)."""
    min_height_sigmas: float = 2.5
    """The lowest object to be found stands this many of its pixels' range noise sigmas
    above the scenery: found by the mean height of its neighbourhoods (`standing_regions`),
    where no single pixel of it stands out by `noise_factor` sigmas."""
    reveal_frames: int = 5
    """Frames in a row a pixel must read farther than the model before the model moves back."""

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise SegmentError(f"BackgroundParams.{field.name} must be a number, got {value!r}")
        if self.reveal_frames < 1:
            raise SegmentError(f"reveal_frames must be at least 1, got {self.reveal_frames}")
        if self.learn_frames < 1:
            raise SegmentError(f"learn_frames must be at least 1, got {self.learn_frames}")
        if not 0.0 < self.rate <= 1.0:
            raise SegmentError(f"rate must be in (0, 1], got {self.rate}")
        if self.min_height_sigmas <= 0:
            raise SegmentError(f"min_height_sigmas must be > 0, got {self.min_height_sigmas}")
        if self.min_sigma_m <= 0 or self.noise_factor <= 0 or self.min_height_m < 0:
            raise SegmentError("min_sigma_m and noise_factor must be > 0, min_height_m >= 0")


class BackgroundModel:
    """Per-pixel range of the empty scene, with the range noise of each pixel."""

    def __init__(self, shape: tuple[int, int], params: BackgroundParams | None = None) -> None:
        self.params = params or BackgroundParams()
        self.shape = shape
        self._seen: list[tuple[F64, B]] = []
        self._noise: list[F64] = []
        self.range: F64 = np.full(shape, np.nan)
        self.sigma: F64 = np.full(shape, self.params.min_sigma_m)
        self.known: B = np.zeros(shape, bool)
        """Pixels whose scenery range is known (valid in enough of the learning frames)."""
        self._farther = np.zeros(shape, np.int32)
        self._farther_min = np.full(shape, np.inf)
        self._unknown_seen = np.zeros(shape, np.int32)
        self._unknown_reads = np.full((self.params.reveal_frames, *shape), np.nan)
        self._laid: B = np.zeros(shape, bool)
        """Pixels whose scenery `clear_belt` put on the belt, with what they held before and
        what it put there (to take a belt off again when another replaces it)."""
        self._unlaid_range: F64 = np.full(shape, np.nan)
        self._unlaid_sigma: F64 = np.full(shape, np.nan)
        self._laid_range: F64 = np.full(shape, np.nan)
        self._held_for: BeltGeometry | None = None
        self._held_surface: F64 = np.full(shape, np.nan)
        """The belt's surface along each pixel's ray, where it meets the belt (else NaN)."""
        self._cleared_range: F64 = np.full(shape, np.nan)
        """The scenery as the last `clear_belt` left it, and what `absorb` took in since: what
        `hold_belt` holds it to."""
        self._absorbed: B = np.zeros(shape, bool)
        """Pixels `absorb` took in: scenery by decision, which no belt laid later covers."""
        self._wrapped: B = np.zeros(shape, bool)
        """Scenery read near though it is far (its phase wrapped round: `clear_belt`)..."""
        self._wrapped_belt: BeltGeometry | None = None
        """...over this belt (the heights of what is read in front of it are measured from it)."""

        self.ready = False
        """True once the learning frames are in."""

    def learn(self, frame: Frame, noise: F64, occupied: F64, reach: float) -> bool:
        """Feed a learning frame with its range noise (`tofcut.tracker.noise`), less the
        pixels within `reach` of the (k, 3) `occupied` points (objects already followed);
        True once the model is ready."""
        valid = frame.valid & ~near_any(frame.xyz, frame.valid, occupied, reach)
        self._seen.append((frame.range, valid))
        self._noise.append(np.where(valid, noise, np.nan))
        if len(self._seen) < self.params.learn_frames:
            return False
        ranges = np.stack([np.where(v, r, np.nan) for r, v in self._seen])
        noise = np.stack(self._noise)
        self._seen.clear()
        self._noise.clear()
        count = np.sum(np.isfinite(ranges), axis=0)
        self.known = count >= max(2, ranges.shape[0] // 2)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            # pixels seen in no learning frame are NaN here, and stay unknown
            warnings.simplefilter("ignore", RuntimeWarning)
            # the median: objects passing through and flying pixels (which can even wrap
            # round to the far end of the range) are outvoted; objects that stood on the
            # belt all along are taken off by `clear_belt`
            far = np.nanmedian(ranges, axis=0)
            scenery = np.abs(ranges - far) < 0.05
            r = np.where(scenery, ranges, np.nan)
            self.range = np.where(self.known, np.nanmedian(r, axis=0), np.nan)
            spread = np.fmax(np.nanstd(r, axis=0), NOISE_SHARE * np.nanmedian(noise, axis=0))
        self.sigma = np.maximum(np.nan_to_num(spread, nan=0.0), self.params.min_sigma_m)
        self.ready = True
        return True

    def clear_belt(self, frame: Frame, belt: BeltGeometry) -> None:
        """Put the belt where the model saw something in front of it while learning (objects
        that stood on the belt during the first frames are not scenery), and where it saw a
        little behind it (an object's edge or a flying pixel read far while the scenery was
        learned: nothing is seen through a belt, and such a pixel would stand out once the
        belt shows there). A belt laid before is taken off first, where nothing was learned
        over it since: the belt found from the data can move to another layer (the floor
        beside a raised belt was taken for it), and what it laid was never seen. What `absorb`
        took in (a track that stayed put while the belt ran: a rail) is never covered again,
        nor is a far surface read near by its wrapped phase (`_going_on`)."""
        back = self._laid & (self.range == self._laid_range)
        self.range[back] = self._unlaid_range[back]
        self.sigma[back] = self._unlaid_sigma[back]
        rays = frame.rays
        surface = belt.range_along(rays)
        points = rays * self.range[..., None]
        on = self.known & np.isfinite(surface) & belt.over_belt(points)
        with np.errstate(invalid="ignore"):
            off = self.range - surface
            low = on_belt_height(points, belt)
            above = on & (off < -np.maximum(3.0 * self.sigma, self.params.min_height_m)) & low
            behind = on & (off > np.maximum(3.0 * self.sigma, self.params.min_height_m))
            behind &= off < BEHIND_BELT_M
            level = on & (np.abs(off) < LEVEL_M)
        # scenery standing higher over the belt than anything on it can is a far surface
        # (the floor past the belt, seen at a slant) read near because its phase wrapped
        # round: what stands in front of it reads farther than it (`seen_range`), and what
        # goes on from it without a step is more of it
        self._wrapped = self.known & np.isfinite(points).all(axis=-1) & ~low
        self._wrapped_belt = belt
        above &= ~_going_on(above, self._wrapped, self.range, self.sigma)
        fix = (_objects_only(above, points, belt, level) | behind) & ~self._absorbed
        self._laid = fix
        self._unlaid_range[fix] = self.range[fix]
        self._unlaid_sigma[fix] = self.sigma[fix]
        self.range[fix] = surface[fix]
        self.sigma[fix] = np.maximum(self.sigma[fix], self.params.min_sigma_m)
        self._laid_range = np.where(fix, self.range, np.nan)
        self._cleared_range = np.where(self.known, self.range, np.nan)

    def hold_belt(self, frame: Frame, belt: BeltGeometry, noise: F64) -> None:
        """Over a running belt nothing stands still (over its width where that is known, over
        its plane where not): where the scenery has come nearer than it was when the belt
        was laid (objects passing so slowly, or so close together, that the model took them
        in), it goes back to what it was then; and its noise is at most what the sensor's
        `noise` says (objects missed while passing would otherwise widen it, until none
        stood out of it). What stood there when the belt was laid (a rail, a guide), or was
        taken in by `absorb` since, stays; a pixel learned only since goes back to the belt's
        surface."""
        self._find_held_surface(frame, belt)
        background_kernels.hold_belt(
            self.range, self.sigma, self.known, self._held_surface, self._cleared_range, noise,
            self.params.min_sigma_m, self.params.min_height_m,
        )  # fmt: skip

    def _find_held_surface(self, frame: Frame, belt: BeltGeometry) -> None:
        """The belt's surface along each pixel's ray, for `hold_belt`: found once per belt
        (again while it is nowhere)."""
        if belt is not self._held_for or np.isnan(self._held_surface).all():
            surface = belt.range_along(frame.rays)
            self._held_for = belt
            self._held_surface = np.where(np.isfinite(surface), surface, np.nan)

    def absorb(self, frame: Frame, where: B, noise: F64) -> None:
        """Take what is seen in `where` as scenery from now on (something that stays put)."""
        take = where & frame.valid
        self.range[take] = frame.range[take]
        self.sigma[take] = noise[take]
        self._cleared_range[take] = frame.range[take]  # scenery by decision: `hold_belt` keeps it
        self._absorbed |= take
        self.known |= take
        self._farther[take] = 0
        self._farther_min[take] = np.inf

    def standing_out(self, frame: Frame) -> B:
        """Pixels nearer than the scenery by more than the noise allows: something is there."""
        p = self.params
        with np.errstate(invalid="ignore"):
            nearer = self.range - self.seen_range(frame)
            out = (nearer > p.noise_factor * self.sigma) & (nearer > p.min_height_m)
        return out & frame.valid & self.known

    def nearness(self, frame: Frame) -> F64:
        """How far in front of the scenery each pixel is, in its own noise sigmas (0 unknown)."""
        with np.errstate(invalid="ignore"):
            z = (self.range - self.seen_range(frame)) / self.sigma
        return np.where(frame.valid & self.known, z, 0.0)

    def seen_range(self, frame: Frame) -> F64:
        """The frame's ranges as the scenery is to be compared with: as read, except over
        scenery whose phase wrapped round (`clear_belt`), where a pixel that reads well
        behind it at the height of something on the belt reads an object in front of the far
        surface; there, a range as far in front of the scenery as it read behind it."""
        belt = self._wrapped_belt
        if belt is None or not self._wrapped.any():
            return frame.range
        with np.errstate(invalid="ignore"):
            behind = frame.range - self.range
            far = (
                self._wrapped
                & frame.valid
                & (behind > np.maximum(WRAPPED_SIGMAS * self.sigma, WRAPPED_STEP_M))
            )
        if not far.any():
            return frame.range
        points = frame.xyz[far]
        with np.errstate(invalid="ignore"):
            lifted = (belt.height(points) > self.params.min_height_m) & on_belt_height(points, belt)
        rows, cols = np.nonzero(far)
        rows, cols = rows[lifted], cols[lifted]
        seen = frame.range.copy()
        seen[rows, cols] = self.range[rows, cols] - behind[rows, cols]
        return seen

    def update(
        self,
        frame: Frame,
        free: B,
        noise: F64,
        occupied: F64,
        reach: float,
        seen: F64,
    ) -> None:
        """Follow the scene where nothing is tracked (`free`): slowly, and back to a farther
        range once the pixel has read farther for `reveal_frames` frames in a row, tracked
        or not (nothing stands behind the scenery: the model was wrong there). A pixel
        not known yet is learned after `reveal_frames` free frames in a row (the median of
        their readings; its noise `noise`, the frame's), unless it lies within `reach` of
        one of the `occupied` (k, 3) points: an object's part its track missed. `seen`: the
        frame's `seen_range`."""
        p = self.params
        usable = free & frame.valid
        due = usable & ~self.known & (self._unknown_seen >= p.reveal_frames - 1)
        background_kernels.follow_scene(
            self.range, self.sigma, self.known, self._farther, self._farther_min,
            self._unknown_seen, self._unknown_reads, seen, frame.valid, usable,
            near_any(frame.xyz, due, occupied, reach),
            noise, p.noise_factor, p.rate, p.min_sigma_m, p.reveal_frames, BLEND_SIGMAS,
            BLEND_VARIANCE_SHARE,
        )  # fmt: skip


def _objects_only(above: B, points: F64, belt: BeltGeometry, level: B) -> B:
    """The parts of `above` (scenery standing on the belt) that could be objects. Where the
    belt's width is not known, rails are told by their shape (`_rails`), and where the
    scenery at the belt's level (`level`) shows the belt's run, what stands beside it is
    not over the belt either (a rail's inner face, a guide)."""
    if belt.width_m is not None:
        return above
    above = above & ~_rails(above, points, belt)
    band = _belt_band(points[level])
    if band is None:
        return above
    centre, axis, lo, hi = band
    with np.errstate(invalid="ignore"):
        across = (points - centre) @ axis
    inside: B = above & (across >= lo + BAND_MARGIN_M) & (across <= hi - BAND_MARGIN_M)
    return inside


def _going_on(where: B, wrapped: B, rng: F64, sigma: F64) -> B:
    """The parts of `where` (connected in the image) that go on from `wrapped` scenery
    without a step, a difference in range of three times the noise of that difference or
    more, between neighbours: more of a far surface whose phase wrapped round, read near
    (on a slant, the part of it read low enough to stand on the belt), not something
    standing on the belt."""
    if not wrapped.any() or not where.any():
        return np.zeros(where.shape, bool)
    parts, _ = ndimage.label(where, EIGHT)
    touching = np.zeros(int(parts.max()) + 1, bool)
    for k in (0, 1):  # east and south neighbours, each way round
        p, q = pair_slices(where.shape, k)
        for a, b in ((p, q), (q, p)):
            with np.errstate(invalid="ignore"):
                seam = (parts[a] > 0) & wrapped[b]
                seam &= np.abs(rng[a] - rng[b]) < 3.0 * np.hypot(sigma[a], sigma[b])
            touching[parts[a][seam]] = True
    touching[0] = False
    going_on: B = touching[parts]
    return going_on


def _belt_band(points: F64) -> tuple[F64, F64, float, float] | None:
    """Where the belt lies across its run, from points on it: (a point, the across axis, the
    band's ends along that axis), or None where its run is not clearly the longer way (the
    view shows a short stretch of a wide belt, or too little of it)."""
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 100:
        return None
    centre = points.mean(axis=0)
    _, axes = np.linalg.eigh(np.cov((points - centre).T))  # ascending
    # the plane's two axes are the last two: the run is the longest, across the middle one
    run, axis = axes[:, 2], axes[:, 1]
    lo_r, hi_r = np.percentile((points - centre) @ run, [1, 99])
    lo, hi = np.percentile((points - centre) @ axis, [BAND_TRIM, 100 - BAND_TRIM])
    if hi_r - lo_r < RUN_TO_WIDTH * (hi - lo):
        return None
    return centre, axis, float(lo), float(hi)


def _rails(above: B, points: F64, belt: BeltGeometry) -> B:
    """The pixels of `above` on rails: in a part longer than `MIN_RAIL_M` in the belt's plane,
    a band along its length narrower than `MAX_RAIL_M` that runs `MIN_RAIL_M` or more, and
    nearly as far as the part's longest band. Boxes standing against a rail join its part in
    the image but not its band: they cover their own stretch of the bands beside it, not the
    rail's whole length; a row of boxes as long as the rail is wider than one. Where boxes
    beside it turn the part's axis off the rail's, the rail is looked for along other ways
    too (`_turned_band_runs`), and taken only where it crosses the view (reaches two of its
    sides)."""
    # a rail's pixels are broken up by noise: bridged
    near = ndimage.binary_dilation(above, EIGHT)
    parts, _ = ndimage.label(near, EIGHT)
    parts = np.where(above, parts, 0)
    rails = np.zeros(above.shape, bool)
    for k, box in enumerate(ndimage.find_objects(parts), start=1):
        if box is None:
            continue
        mine = parts[box] == k
        flat = np.stack([belt.along(points[box][mine]), belt.across(points[box][mine])])
        ok = np.isfinite(flat).all(axis=0)
        if ok.sum() < 3:
            continue
        centred = flat[:, ok] - flat[:, ok].mean(axis=1, keepdims=True)
        spread, axes = np.linalg.eigh(np.cov(centred))  # ascending
        if 4.0 * math.sqrt(max(spread[1], 0.0)) <= MIN_RAIL_M:  # ±2σ of a bar: most of it
            continue
        where = np.zeros(mine.sum(), bool)
        where[ok] = _narrow_lanes(*_band_runs(axes[:, 1] @ centred, axes[:, 0] @ centred))
        if not where.any():
            principal = math.atan2(axes[1, 1], axes[0, 1])
            where[ok] = _narrow_lanes(*_turned_band_runs(centred, principal))
            if not where.any():
                continue
            # a rail runs on past the view at both ends; a row of boxes in it seldom does
            rows, cols = np.nonzero(mine)
            rows, cols = rows[where] + box[0].start, cols[where] + box[1].start
            lane = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
            if sides_reached(lane, above.shape, EDGE_PX) < 2:
                continue
        rails[box][mine] = where
    return rails


def _narrow_lanes(band: I64, runs: F64) -> B:
    """Which points lie in a lane of bands that run `MIN_RAIL_M` or more, and nearly as far
    as the longest (a rail runs the part's whole length, but for what hides it; a box beside
    it less), narrower than `MAX_RAIL_M` together."""
    long = runs >= max(MIN_RAIL_M, RAIL_RUN_SHARE * runs.max())
    lanes, _ = ndimage.label(long)
    narrow = np.bincount(lanes) * RAIL_BIN_M < MAX_RAIL_M
    narrow[0] = False
    on_lane: B = narrow[lanes[band]]
    return on_lane


def _band_runs(length: F64, side: F64) -> tuple[I64, F64]:
    """Each point's band across the way a rail would run (`RAIL_BIN_M` wide, by its `side`
    position), and how far each band runs along it (the `RAIL_STRETCH_M` stretches of its
    `length` position that hold a point of it)."""
    band = np.floor(side / RAIL_BIN_M).astype(np.int64)
    band -= band.min()
    stretch = np.floor((length - length.min()) / RAIL_STRETCH_M).astype(np.int64)
    held = np.unique(np.stack([band, stretch]), axis=1)[0]
    runs = np.bincount(held, minlength=band.max() + 1).astype(np.float64) * RAIL_STRETCH_M
    return band, runs


def _turned_band_runs(centred: F64, principal: float) -> tuple[I64, F64]:
    """`_band_runs` along the way, within `RAIL_TURN_DEG` of the `principal` axis (radians in
    the belt's plane), along which a band runs farthest: boxes beside a rail turn the axis
    of the part they make with it off the rail's."""

    def farthest(angles: F64) -> tuple[float, I64, F64]:
        found = []
        for a in angles.tolist():
            c, s = math.cos(a), math.sin(a)
            found.append(
                (a, *_band_runs(c * centred[0] + s * centred[1], c * centred[1] - s * centred[0]))
            )
        # a band's run is counted in whole stretches: of the ways a band runs farthest,
        # the one whose bands that run nearly as far run farthest in all (a rail's width
        # in bands of its full length, not smeared over more bands that run part of it)
        return max(
            found, key=lambda f: (f[2].max(), f[2][f[2] >= RAIL_RUN_SHARE * f[2].max()].sum())
        )

    turn, step = math.radians(RAIL_TURN_DEG), math.radians(RAIL_STEP_DEG)
    a, _, _ = farthest(principal + np.arange(-turn, turn + step / 2, step))
    _, band, runs = farthest(a + np.linspace(-step / 2, step / 2, 9))
    return band, runs


RAIL_TURN_DEG = 30
"""A rail's run is looked for this far either way of its part's principal axis..."""
RAIL_STEP_DEG = 2
"""...in steps of this, then of an eighth of it round the best (over 1 m a rail turned
0.25° off moves 4 mm across: its bands run its length)."""
EDGE_PX = 2
"""A part this near the image's side reaches it (the outermost pixels read poorly)."""


def standing_regions(model: F64, sigma: F64, usable: B, seen: F64, params: BackgroundParams) -> B:
    """Pixels whose `REGION_SIDE` neighbourhood stands out of the scenery as a whole: its mean
    nearness (over the `usable` pixels in it, at least half of them) is `REGION_SIGMAS` times
    that mean's own noise and half the lowest object's height (`min_height_sigmas`). A low
    object in loud noise, none of whose pixels stands out alone, is found this way."""
    out: B = background_kernels.standing_regions(
        model, sigma, usable, seen, REGION_SIDE, REGION_SIGMAS,
        REGION_HEIGHT_SHARE * params.min_height_sigmas, params.min_height_m,
    )  # fmt: skip
    return out


def on_belt_height(points: F64, belt: BeltGeometry) -> B:
    """Which points could be on something standing on the belt: nothing there stands half as
    high as the camera above it (`TALLEST_SHARE`). What reads nearer is something else: a
    far surface whose phase wrapped round, read near (finite points only pass)."""
    with np.errstate(invalid="ignore"):
        low: B = belt.height(points) < TALLEST_SHARE * float(belt.height(np.zeros(3)))
    return low


def near_any(xyz: F64, where: B, points: F64, reach: float) -> B:
    """Which pixels in `where` have their 3D point within `reach` of one of `points`."""
    near = np.zeros(where.shape, bool)
    if len(points) and where.any():
        gap, _ = cKDTree(points).query(xyz[where], distance_upper_bound=reach)
        near[where] = np.isfinite(gap)
    return near
