"""Finding the belt from the data: its plane, direction of travel, speed and width.

A real camera's stream carries no belt geometry; this module finds it in the first seconds
of a run. The maths are pure functions; `BeltFinder` is the thin stateful object that feeds
them frame by frame, and `find_belt` the one-shot form. How and why: `docs/calibrate.md`.

1. The plane, from the first frame: floor, belt, rail tops and box tops are parallel, so
   the heights of the points along their common normal pile up in peaks, one per layer (the
   normal is the RANSAC plane's along which they pile up most sharply, unless another sharp
   pile's family has a clearly larger support: a slanted family of box faces can pile up
   more sharply). The belt is the nearest layer that is a *support* — what borders it in the
   image rises from it (boxes, rails) rather than dropping away from it (a box top, a rail
   top), or it runs right across the view — and is not small beside the largest support. The
   floor is a support too, but farther away. After `plane_frames` frames the plane is
   refitted on their mean, which is quiet enough to leave out a rail's top and the feet of
   the boxes.
2. The travel: the level tops of what stands on the belt are followed from frame to frame
   in the plane's own coordinates; each gives a velocity, the slope of a least-squares line
   through its positions, and the direction and speed are medians over them, weighted by
   how well each line pins its slope. Things that stand still give no vote: a scene in which
   nothing moves for `patience_s` has no travel direction ("none"), not a guessed one.
3. The width: across the travel, between the belt's last points on either side — or the
   inner side of a rail that hides the belt's edge — wherever the view reaches past both.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import ndimage

from tofcut._types import F32, F64, I64, U16, B
from tofcut.driver.belt import BeltGeometry, KnownBelt
from tofcut.driver.frames import Frame
from tofcut.tracker import stats_kernels
from tofcut.tracker.belt_sweep import (
    SweepParams,
    SweepWindow,
    SweptLayer,
    choose_swept,
    swept_layers,
)
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.neighbours import EIGHT
from tofcut.tracker.noise import range_noise
from tofcut.tracker.stats import robust_sigma

Travel = Literal["looking", "found", "none", "unsure"]
"""Whether the belt's direction of travel is known: still looking; found; none (nothing moved
on the belt while the finder looked: a static scene); unsure (things moved, but too little,
or not together, to tell the belt's travel)."""

NOISE_FLOOR_M = 0.003
"""No pixel's range is trusted to better than this (`tofcut.tracker.noise`)."""


# --- parameters and results ------------------------------------------------------------


@dataclass(frozen=True)
class FinderParams:
    """How the belt is looked for (the defaults serve belts of 0.4-1 m seen from 1-2.5 m)."""

    plane_frames: int = 5
    """Frames averaged for the plane's final fit (the first frame alone gives the first)."""
    ransac_tries: int = 150
    """Plane hypotheses tried for the dominant orientation (fixed seed: deterministic)."""
    ransac_points: int = 3000
    """Points the dominant normal is refitted on (an even subsample of the valid pixels; its
    hypotheses are scored on `SCORE_POINTS` of them)."""
    normal_candidates: int = 3
    """Families of parallel planes tried for the belt's (`candidate_normals`)..."""
    candidates_apart_deg: float = 15.0
    """...their normals at least this far apart..."""
    switch_share: float = 1.5
    """...and another family than the sharpest taken when its largest support is this many
    times larger (`_family_support`)."""
    layer_bin_m: float = 0.01
    """Bin of the height histogram that finds the layers."""
    min_layer_share: float = 0.03
    """A layer holds at least this share of the valid pixels."""
    min_band_m: float = 0.015
    """A point is on a plane within 2 of its noise sigmas, and at least this..."""
    max_band_m: float = 0.03
    """...and at most this."""
    max_sigma_m: float = 0.05
    """Pixels noisier than this (far, dark, grazing) take no part in finding the plane,
    unless the median pixel is (`quiet_enough`)."""
    drop_m: float = 0.03
    """A neighbour this much lower than a layer is a drop off its edge (and 3 sigmas)."""
    island_share: float = 0.5
    """A layer whose border is more drops than rises is a top, not a support..."""
    min_span_m: float = 0.2
    """...unless it runs across the view and is at least this wide (a belt; a rail is not)."""
    min_support_share: float = 0.2
    """A support holding less than this share of the largest support's pixels, and not
    running across the view, is not the belt (a box top between taller ones)."""
    top_height_m: float = 0.05
    """The tops followed stand at least this far above the belt (a low rim does not)."""
    top_tilt_deg: float = 25.0
    """A top's surface normal is within this of the belt's."""
    top_grow: int = 3
    """Pixels a top's flat core grows by over its neighbours..."""
    top_reach_m: float = 0.015
    """...that are at its height within this above it..."""
    top_below_m: float = 0.005
    """...and this below it (lower, a pixel is more likely on a face below the top's edge, or
    mixing the top with what lies behind it, than on the top: a top grown over those leans
    towards the camera)."""
    min_top_pixels: int = 20
    """Smaller tops are not followed."""
    max_speed_mps: float = 2.0
    """No belt moves faster (the matching gate)."""
    min_speed_mps: float = 0.02
    """Slower tops are standing still: they do not vote for the direction."""
    max_gap_s: float = 0.1
    """A followed top missed for longer than this is let go."""
    min_follow_s: float = 0.2
    """A top followed for less time gives no velocity."""
    max_track_rms_m: float = 0.01
    """A followed top whose positions stray further from a straight line is not trusted."""
    size_change: float = 0.15
    """A top whose area changes by more than this share (a merge, a split) is another top..."""
    area_gate: float = 0.06
    """...and its position is only taken when its area is within this share of its usual."""
    settle_s: float = 1.0
    """Followed-top time (summed over tops) before the travel is trusted."""
    min_longest_s: float = 0.5
    """...and one top followed this long at least (short lines give loose velocities)."""
    done_s: float = 3.0
    """Followed-top time after which the estimate is final and updates cost nothing..."""
    min_done_s: float = 1.5
    """...once this many seconds of frames are in..."""
    max_s: float = 3.0
    """...or seconds of frames, once the travel is trusted."""
    patience_s: float = 20.0
    """Seconds of frames with no moving top after which there is no travel direction (a line
    that starts empty may show its first object some seconds in)..."""
    give_up_s: float = 20.0
    """...and with tops moving, but not enough to trust, after which the travel is unsure."""
    min_shift_m: float = 0.02
    """A top that went this far has moved (less is the noise of a still one)."""
    edges_every: int = 5
    """Every this many frames goes into the width (the edges do not move: a few suffice)..."""
    width_every_s: float = 1.0
    """...and once the travel is final, the width is fitted every this many seconds until it is
    found, or `give_up_s`..."""
    width_run_m: float = 0.5
    """...from when the belt has run this far: what it carries has then swept its surface, and
    an object standing a second on a slow belt is not taken for a rail beside it."""
    max_spread_deg: float = 5.0
    """A top agrees with the travel when its direction is within this of it..."""
    agree_speed: float = 0.1
    """...and its speed within this share of it."""
    min_agreeing: float = 0.5
    """The travel is unknown until the tops that agree with it hold more than this share of
    the weight (a top's weight: how well its line pins its velocity)..."""
    max_speed_se: float = 0.01
    """...and while its velocity's standard error is more than this share of the speed."""
    sweep: SweepParams = field(default_factory=SweepParams)
    """How the belt is told from the floor and from box tops by what moves over it."""

    def __post_init__(self) -> None:
        if self.plane_frames < 1 or self.ransac_tries < 1 or self.ransac_points < 3:
            raise SegmentError("plane_frames >= 1, ransac_tries >= 1, ransac_points >= 3")
        if self.edges_every < 1 or self.top_grow < 0 or self.min_top_pixels < 1:
            raise SegmentError("edges_every >= 1, top_grow >= 0, min_top_pixels >= 1")
        if self.normal_candidates < 1 or self.switch_share < 1:
            raise SegmentError("normal_candidates >= 1 and switch_share >= 1")
        if not 0 < self.candidates_apart_deg < 90:
            raise SegmentError("candidates_apart_deg must be in (0, 90)")
        if not 0 < self.top_tilt_deg < 90:
            raise SegmentError("top_tilt_deg must be in (0, 90)")
        shares = (self.min_layer_share, self.island_share, self.min_support_share)
        if not all(0 < x < 1 for x in shares):
            raise SegmentError("min_layer_share, island_share, min_support_share: in (0, 1)")
        positive = (
            self.layer_bin_m, self.min_band_m, self.max_band_m, self.max_sigma_m, self.drop_m,
            self.min_span_m, self.top_reach_m, self.top_below_m, self.top_height_m,
            self.max_speed_mps, self.min_speed_mps, self.max_gap_s, self.min_follow_s,
            self.max_track_rms_m, self.size_change, self.area_gate, self.settle_s,
            self.min_longest_s, self.done_s, self.min_done_s, self.max_s, self.patience_s,
            self.give_up_s, self.min_shift_m, self.width_every_s, self.width_run_m,
            self.max_spread_deg,
            self.agree_speed, self.min_agreeing, self.max_speed_se,
        )  # fmt: skip
        if not all(math.isfinite(x) and x > 0 for x in positive):
            raise SegmentError("lengths, speeds, times and shares must be positive numbers")
        if self.done_s < self.settle_s or self.max_speed_mps <= self.min_speed_mps:
            raise SegmentError("done_s >= settle_s and max_speed_mps > min_speed_mps")


@dataclass(frozen=True, eq=False)
class PlaneFit:
    """A plane n·p = offset in camera coordinates, n unit and pointing up (to the camera)."""

    normal: F64
    offset_m: float
    """n·p of the plane's points: minus the camera's height above it."""
    rms_m: float
    """RMS distance of the inliers from the plane."""
    inliers: int
    valid: int
    """Valid pixels of the frames fitted (inliers / valid: the inlier share)."""

    def height(self, points: F64) -> F64:
        """Height above the plane of (..., 3) points."""
        return np.asarray(points @ self.normal - self.offset_m, dtype=np.float64)

    @property
    def axis_point(self) -> F64:
        """Where the optical axis meets the plane (the view's centre)."""
        return np.array([0.0, 0.0, self.offset_m / self.normal[2]])

    @property
    def inlier_share(self) -> float:
        """Share of the valid pixels on the plane."""
        return self.inliers / self.valid if self.valid else 0.0


@dataclass(frozen=True, eq=False)
class Layer:
    """One horizontal surface: a peak of the heights along the dominant normal, with its own
    plane fitted."""

    plane: PlaneFit
    pixels: int
    drop_share: float
    """Share of its border in the image that drops away from it (1: an island, a top)."""
    span_m: float = 0.0
    """Width of its widest piece that runs right across the image (0: none does)."""

    def supports(self, params: FinderParams) -> bool:
        """Whether things could stand on it: what borders it rises from it, or it runs across
        the whole view and is wide (an empty belt with no rails, its edges dropping away)."""
        return self.rises(params) or self.span_m >= params.min_span_m

    def rises(self, params: FinderParams) -> bool:
        """Whether what borders it in the image rises from it more than it drops away: things
        stand on it."""
        return self.drop_share < params.island_share


@dataclass(frozen=True, eq=False)
class Segment:
    """One top followed over time: its velocity in plane coordinates."""

    velocity: F64
    """(2,) m/s, in the plane's (e1, e2) basis."""
    seconds: float
    frames: int
    rms_m: float
    centre: F64
    """(2,) m, its mean position in the plane's basis (where on the belt it went)."""


@dataclass(frozen=True, eq=False)
class TravelFit:
    """Direction and speed from the followed tops."""

    direction: F64
    """(2,) unit, in the plane's basis."""
    speed_mps: float
    direction_spread_deg: float
    """How much the tops that agree scatter in direction (`stats.robust_sigma`: a standard
    deviation where they scatter normally)."""
    speed_spread_mps: float
    """The same for their speeds along the direction."""
    segments: int
    """Tops that agree with the travel."""
    seconds: float
    """Followed-top time of the tops that agree (summed)."""
    longest_s: float
    """The longest time one of them was followed."""
    speed_se_mps: float
    """Standard error of the velocity from their scatter about their lines (combined by
    inverse variance): what noise alone leaves uncertain."""
    agreeing: float
    """The share of the moving tops' weight that the tops agreeing hold."""


@dataclass(frozen=True)
class WidthFit:
    """The belt's edges across its direction of travel, where both are in view."""

    width_m: float
    centre_m: float
    """The centre line's position across the belt (the plane basis' across axis)."""
    slices: int
    """Slices along the belt in which both edges were seen."""
    spread_m: float


@dataclass(frozen=True, eq=False)
class BeltEstimate:
    """What the finder knows of the belt so far, with how well it knows it."""

    belt: KnownBelt | None
    """Source "found"; None until a plane is found. Its point is where the optical axis meets
    the plane, or on the centre line once the width is known. Until `travel` is "found", its
    direction is only an axis laid in the plane (the belt's long axis as seen, or the
    camera's x axis) — not a travel direction — and its speed is None."""
    travel: Travel
    plane_final: bool = False
    """Whether the plane is the refit over the first `plane_frames` (it will not change again);
    before, it is the first frame's (within about 1-2 cm and 1°)."""
    plane_rms_m: float = math.nan
    """RMS distance from the plane of the pixels on it (after averaging over the first
    frames, once refitted)."""
    inlier_share: float = 0.0
    """Share of the usable pixels on the plane."""
    frames: int = 0
    """Frames used."""
    seconds: float = 0.0
    """Device time spanned by the frames used."""
    direction_spread_deg: float = math.nan
    """How much the followed tops disagree on the direction (a standard deviation, robustly)."""
    speed_spread_mps: float = math.nan
    """The same for their speeds."""
    speed_se_mps: float = math.nan
    """Standard error of the velocity that the tops' scatter about their lines leaves."""
    tops: int = 0
    """Followed tops that voted for the travel."""
    layers: int = 0
    """Level surfaces seen in the first frame (floor, belt, rail and box tops...)."""

    @property
    def found_travel(self) -> bool:
        """Whether the belt's direction and speed are known."""
        return self.travel == "found"

    def describe(self) -> str:
        """One line for a run's closing lines."""
        if self.belt is None:
            return f"belt: not found in {self.frames} frames (no plane stands out)"
        g = self.belt.geometry
        n = ", ".join(f"{x:+.3f}" for x in g.normal)
        text = (
            f"belt: plane n=({n}) {float(np.linalg.norm(g.origin)):.3f} m out on the optical "
            f"axis, rms {self.plane_rms_m * 1e3:.1f} mm over {self.inlier_share:.0%} of "
            f"pixels; "
        )
        if self.travel == "found" and self.belt.speed_mps is not None:
            d = ", ".join(f"{x:+.3f}" for x in g.direction)
            text += (
                f"travel ({d}) at {self.belt.speed_mps:.3f} m/s (spread "
                f"{self.direction_spread_deg:.1f}°, {self.speed_spread_mps * 1e3:.1f} mm/s over "
                f"{self.tops} tops); "
            )
        elif self.travel == "none":
            text += "no travel direction found (nothing moved on it); "
        elif self.travel == "unsure":
            text += "travel unsure (things moved, but too little or not together to tell); "
        else:
            text += "travel not known yet; "
        width = "not seen (an edge is out of view)" if g.width_m is None else f"{g.width_m:.3f} m"
        return text + f"width {width}; {self.frames} frames, {self.seconds:.1f} s"


# --- pure maths: points, planes, layers --------------------------------------------------


def usable(frame: Frame) -> B:
    """Pixels whose range and point can be trusted: valid, finite, in front of the camera."""
    with np.errstate(invalid="ignore"):
        ok = frame.valid & np.isfinite(frame.range) & (frame.range > 0)
        ok &= np.isfinite(frame.xyz).all(axis=-1) & (frame.xyz[..., 2] > 0)
    return np.asarray(ok, dtype=np.bool_)


def fit_plane(points: F64, weights: F64 | None = None) -> tuple[F64, float]:
    """Weighted least-squares plane of (N, 3) points: unit normal (pointing to the camera,
    which is at the origin) and offset n·p."""
    w = np.ones(len(points)) if weights is None else weights
    return plane_from_moments(float(w.sum()), w @ points, (points * w[:, None]).T @ points)


def plane_from_moments(count: float, total: F64, outer: F64) -> tuple[F64, float]:
    """The least-squares plane from accumulated (weighted) moments: Σw, Σw·p and Σw·pp^T."""
    centre = total / count
    cov = outer / count - np.outer(centre, centre)
    _, vecs = np.linalg.eigh(cov)
    n = vecs[:, 0]
    if float(n @ centre) > 0:
        n = -n
    return n, float(n @ centre)


SCORE_POINTS = 800
"""RANSAC hypotheses are scored on this many points (their refit uses all it was given)."""
PILE_BIN_M = 0.02
"""Bin of the heights along a hypothesis' normal when scoring how sharply they pile up."""


def candidate_normals(
    points: F64, sigma: F64, tries: int, count: int, apart_deg: float, seed: int = 0
) -> list[F64]:
    """Normals of families of parallel planes that may hold the scene, best first: of RANSAC's
    planes through three points, those along whose normal the points' heights pile up most
    sharply (the sum of squared histogram counts, sharp points weighing more) — floor, belt,
    rail and box tops all pile up along the vertical, but so may a row of box faces seen
    from the side — at most `count`, each `apart_deg` or more from those before it, each
    refitted on its largest pile. Pointing to the camera."""
    rng = np.random.default_rng(seed)
    if len(points) < 3:
        raise SegmentError("a plane needs three points")
    picks = rng.integers(0, len(points), (tries, 3))
    a, b, c = points[picks[:, 0]], points[picks[:, 1]], points[picks[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    good = lengths > 1e-9
    if not good.any():
        raise SegmentError("the points are all on one line")
    normals = normals[good] / lengths[good, None]
    step = max(1, len(points) // SCORE_POINTS)
    scored, weight = points[::step], 1.0 / sigma[::step]
    bins = np.floor(scored @ normals.T / PILE_BIN_M).astype(np.int64)
    bins -= bins.min(axis=0)
    span = int(bins.max()) + 1  # every hypothesis' histogram in one: its bins offset by span
    flat = (bins + span * np.arange(bins.shape[1])).T.ravel()
    piles = np.bincount(
        flat, weights=np.tile(weight, bins.shape[1]), minlength=span * bins.shape[1]
    )
    scores = (piles.reshape(bins.shape[1], span) ** 2).sum(axis=1)
    close = math.cos(math.radians(apart_deg))
    chosen: list[F64] = []
    for i in np.argsort(-scores, kind="stable"):
        if len(chosen) == count:
            break
        if any(abs(float(normals[i] @ m)) >= close for m in chosen):
            continue
        n = _refit_on_pile(points, sigma, normals[i])
        if all(abs(float(n @ m)) < close for m in chosen):
            chosen.append(n)
    return chosen


def _refit_on_pile(points: F64, sigma: F64, n: F64) -> F64:
    """The plane refitted on the largest pile of the heights along `n`, and on what the refit
    holds; its normal, pointing to the camera."""
    heights = points @ n
    reach = 2.5 * sigma
    counts = np.bincount(np.floor((heights - heights.min()) / PILE_BIN_M).astype(np.int64))
    off = heights.min() + (int(np.argmax(counts)) + 0.5) * PILE_BIN_M
    for _ in range(4):
        held = np.abs(points @ n - off) < reach
        if np.count_nonzero(held) < 3:
            break
        n, off = fit_plane(points[held], 1.0 / sigma[held] ** 2)
    return np.asarray(n if float(n @ points.mean(axis=0)) < 0 else -n, np.float64)


def layer_offset(heights: F64, band: F64, start: float) -> float:
    """Where a layer lies along the normal: the median of the heights within `band` of it,
    thrice (a median: what stands on the layer, inside the band's upper edge, barely moves
    it)."""
    off = start
    for _ in range(3):
        inside = np.abs(heights - off) < band
        if not inside.any():
            break
        off = float(np.median(heights[inside]))
    return off


def family_plane(
    points: F64, sigma: F64, normal: F64, offsets: list[float], band: F64
) -> tuple[F64, list[float]]:
    """The normal shared by parallel layers (floor, belt, tops; at `offsets` along `normal`):
    the one that makes all of them flattest at once (the pooled scatter of each layer's
    points about its own centre), twice, with each layer's offset found again. The floor's
    wide extent pins the normal far better than a belt seen as a strip between boxes — for a
    belt that runs level, parallel to the floor."""
    offsets = list(offsets)
    for _ in range(2):
        heights = points @ normal
        scatter = np.zeros((3, 3))
        for off in offsets:
            inside = np.abs(heights - off) < band
            count = np.count_nonzero(inside)
            if count < 3:
                continue
            w = 1.0 / sigma[inside] ** 2
            d = points[inside] - w @ points[inside] / w.sum()
            scatter += (d * w[:, None]).T @ d * (count / w.sum())
        if not scatter.any():
            break
        _, vecs = np.linalg.eigh(scatter)
        normal = vecs[:, 0] if float(vecs[:, 0] @ normal) > 0 else -vecs[:, 0]
        heights = points @ normal
        offsets = [layer_offset(heights, band, off) for off in offsets]
    return normal, offsets


def find_layers(heights: F64, bin_m: float, min_pixels: int) -> list[tuple[float, float, int]]:
    """Peaks of a height histogram: (height, sigma, pixels) of every layer holding at least
    `min_pixels`, nearest the camera (highest) first. A peak's height and sigma are the median
    and MAD of the heights within a few bins of it; its pixels those within 2 sigmas."""
    if heights.size == 0:
        return []
    lo, hi = float(np.min(heights)), float(np.max(heights))
    bins = max(1, math.ceil((hi - lo) / bin_m) + 1)
    counts = np.bincount(((heights - lo) / bin_m).astype(np.int64), minlength=bins)
    smooth = np.convolve(counts, [1.0, 2.0, 1.0], mode="same") / 4.0
    peaks: list[int] = []
    for i in np.argsort(-smooth, kind="stable"):
        if smooth[i] * 8 < min_pixels:
            break
        window = smooth[max(0, i - 2) : i + 3]
        if smooth[i] < window.max() or any(abs(i - j) <= 2 for j in peaks):
            continue
        peaks.append(int(i))
    layers = []
    for i in peaks:
        centre = lo + (i + 0.5) * bin_m
        near = heights[np.abs(heights - centre) < 2.5 * bin_m]
        if near.size == 0:
            continue
        med = float(np.median(near))
        sigma = max(robust_sigma(near - med), bin_m / 2)
        pixels = int(np.count_nonzero(np.abs(heights - med) < 2 * sigma))
        if pixels >= min_pixels:
            layers.append((med, sigma, pixels))
    layers.sort(key=lambda x: -x[0])
    return layers


def drop_share(heights: F64, reach: F64, ok: B, layer: B) -> float:
    """Share of a layer's border pixels (a 2-pixel ring around it in the image) lower than it
    by more than their `reach`, among those lower or higher by that much: 1 for a top
    (everything around drops away), near 0 for a support (what borders it stands on it).
    `heights` are above the layer's own plane."""
    ring = ndimage.binary_dilation(layer, iterations=2) & ~layer & ok
    dh, r = heights[ring], reach[ring]
    lower = int(np.count_nonzero(dh < -r))
    higher = int(np.count_nonzero(dh > r))
    return lower / (lower + higher) if lower + higher else 0.0


def quiet_enough(sigma: F64, params: FinderParams) -> float:
    """The loudest range noise a pixel may have to take part in finding the plane:
    `max_sigma_m`, or the median noise of the usable pixels where that is more (on a loud
    line, a belt read far and dark with more noise than that is still most of the view)."""
    if not sigma.size:
        return params.max_sigma_m
    return max(params.max_sigma_m, float(np.median(sigma)))


def choose_belt(layers: list[Layer], params: FinderParams) -> int | None:
    """Index of the belt among the layers: the nearest support (not an island) that is large
    beside the largest support (or runs across the view); failing any support, the largest
    layer; None when there are no layers."""
    if not layers:
        return None
    supports = [i for i, lay in enumerate(layers) if lay.supports(params)]
    if not supports:
        return max(range(len(layers)), key=lambda i: layers[i].pixels)
    most = max(layers[i].pixels for i in supports)
    # a box top hemmed in by taller boxes can look like a support; it is small beside the
    # belt (and the floor), and does not run across the view
    large = [
        i for i in supports
        if layers[i].pixels >= params.min_support_share * most
        or layers[i].span_m >= params.min_span_m
    ]  # fmt: skip
    return max(large, key=lambda i: layers[i].plane.offset_m)  # the nearest: least far


UNSUPPORTED = 0.5
"""A family with no support counts its largest layer's pixels at this share (so does another
family than the sharpest whose supports only run across the view: a stand's side does, but
nothing stands on it)."""


def find_belt_layers(xyz: F64, ok: B, sigma: F64, params: FinderParams) -> list[Layer]:
    """The horizontal layers of a frame, nearest the camera first: each with its plane (all
    share the family's normal), how much its border drops away and how wide it runs across
    the view.

    The family is the candidate normals' (`candidate_normals`) whose largest support
    (`_family_support`) is the largest: the first candidate's unless another's is
    `switch_share` times larger. On a line packed with boxes seen steeply from the side, a
    slanted family of their faces can pile up more sharply than the level one. (Not the
    belt each would choose, the nearest support: that may be a layer of box tops.)"""
    quiet = ok & (sigma <= quiet_enough(sigma[ok], params))
    pts, sig = xyz[quiet], sigma[quiet]
    if len(pts) < 3:
        return []
    step = max(1, len(pts) // params.ransac_points)
    normals = candidate_normals(
        pts[::step], sig[::step], params.ransac_tries, params.normal_candidates,
        params.candidates_apart_deg,
    )  # fmt: skip
    best: list[Layer] = []
    best_pixels = 0.0
    for k, normal in enumerate(normals):
        layers = layers_along(xyz, ok, quiet, sigma, normal, params)
        pixels = _family_support(layers, k == 0, params)
        pixels /= 1.0 if k == 0 else params.switch_share
        if k == 0 or pixels > best_pixels:
            best, best_pixels = layers, pixels
    return best


def _family_support(layers: list[Layer], sharpest: bool, params: FinderParams) -> float:
    """How well a family of layers holds a belt: the pixels of its largest support, or
    `UNSUPPORTED` of its largest layer's where it has none. The sharpest family's supports
    may be so by running across the view; another's must show things standing on them (their
    border rises) to overturn it."""
    if not layers:
        return 0.0
    held = [
        lay.pixels for lay in layers
        if (lay.supports(params) if sharpest else lay.rises(params))
    ]  # fmt: skip
    return float(max(held)) if held else UNSUPPORTED * max(lay.pixels for lay in layers)


def layers_along(
    xyz: F64, seen: B, ok: B, sigma: F64, normal: F64, params: FinderParams
) -> list[Layer]:
    """The layers of a frame along about `normal`, nearest the camera first (`ok`: the
    quiet pixels, `seen`: all usable). They are the peaks of the heights along it (of the
    sharper half of the pixels: far, noisy ones blur the peaks), their shared normal refitted
    to make them flattest (`family_plane`)."""
    pts, sig = xyz[ok], sigma[ok]
    along = pts @ normal
    sharp = sig <= np.percentile(sig, 50)
    found = find_layers(
        along[sharp], params.layer_bin_m, round(params.min_layer_share * np.count_nonzero(sharp))
    )
    band = band_of(sigma, params)
    few = slice(None, None, 2)  # half the points fix the layers well enough for a first look
    offsets = [layer_offset(along[few], band[ok][few], h) for h, _, _ in found]
    if offsets:
        normal, offsets = family_plane(pts[few], sig[few], normal, offsets, band[ok][few])
    distinct: list[float] = []
    for off in sorted(offsets, reverse=True):  # two peaks may have found the same layer
        if all(abs(off - d) >= params.min_band_m for d in distinct):
            distinct.append(off)
    layers = []
    reach = np.maximum(3.0 * sigma, params.drop_m)
    for off in distinct:
        held = np.abs(pts @ normal - off) < band[ok]
        if np.count_nonzero(held) < 3:
            continue
        rms = float(np.sqrt(np.mean((pts[held] @ normal - off) ** 2)))
        fit = PlaneFit(normal, off, rms, int(np.count_nonzero(held)), len(pts))
        height = fit.height(xyz)
        with np.errstate(invalid="ignore"):
            on = np.abs(height) < band
        heights = np.where(ok, height, np.nan)
        share = drop_share(heights, reach, ok, ok & on)
        # how far it runs across the view, over every pixel it shows (the far end of a belt
        # is read too loud to help find the plane, but it is there)
        shown = seen & on
        layers.append(Layer(fit, fit.inliers, share, span_width(xyz, shown, fit.normal)))
    return layers


def pooled_layers(heights: F32, ok: B, sigma: F32, band: F32, params: FinderParams) -> list[float]:
    """The layers' offsets (n·p) in heights pooled over several frames (samples, pixels):
    peaks of all of them (3×3 medians are sharp enough: the sharper half alone would leave out
    a dark, noisy belt), each refined to the median of what lies within its band, and peaks
    that found the same layer kept once."""
    if not ok.any():
        return []
    found = find_layers(
        heights[ok].astype(np.float64), params.layer_bin_m,
        round(params.min_layer_share * np.count_nonzero(ok) / len(heights)),
    )  # fmt: skip
    few = slice(None, None, 3)
    pooled, reach = heights[ok][few].astype(np.float64), band[ok][few].astype(np.float64)
    distinct: list[float] = []
    for off in sorted((layer_offset(pooled, reach, h) for h, _, _ in found), reverse=True):
        if all(abs(off - d) >= params.min_band_m for d in distinct):
            distinct.append(off)
    return distinct


def span_width(xyz: F64, mask: B, normal: F64) -> float:
    """The width (across its long axis, in the plane of `normal`) of the widest piece of
    `mask` that touches two opposite borders of the image; 0 when no piece does."""
    labels, count = ndimage.label(mask, structure=EIGHT)
    if count == 0:
        return 0.0
    n = count + 1
    touches = [
        np.bincount(edge.ravel(), minlength=n) > 0
        for edge in (labels[:2], labels[-2:], labels[:, :2], labels[:, -2:])
    ]
    across = (touches[0] & touches[1]) | (touches[2] & touches[3])
    across[0] = False
    e1, e2 = plane_basis(normal)
    best = 0.0
    for k in np.flatnonzero(across):
        pts = xyz[labels == k]
        uv = np.stack([pts @ e1, pts @ e2], axis=1)
        axis = long_axis(uv)
        side = uv @ np.array([-axis[1], axis[0]])
        lo, hi = np.percentile(side, [2, 98])
        best = max(best, float(hi - lo))
    return best


def band_of(sigma: F64, params: FinderParams) -> F64:
    """How far from a plane a point with range noise `sigma` may lie and still be on it."""
    return np.asarray(np.clip(2.0 * sigma, params.min_band_m, params.max_band_m), np.float64)


def plane_basis(normal: F64) -> tuple[F64, F64]:
    """Two unit axes in the plane: e1 the camera's x axis laid into it (y when x is along the
    normal), e2 = normal × e1."""
    for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        e1 = axis - float(axis @ normal) * normal
        length = float(np.linalg.norm(e1))
        if length > 0.1:
            e1 = e1 / length
            return e1, np.cross(normal, e1)
    raise SegmentError("no plane axis")  # unreachable for a unit normal


def long_axis(uv: F64) -> F64:
    """The direction (2,) along which plane points (N, 2) spread most (their first principal
    axis), sign fixed so that its larger component is positive."""
    if len(uv) < 3:
        return np.array([1.0, 0.0])
    d = uv - uv.mean(axis=0)
    _, vecs = np.linalg.eigh(d.T @ d)
    axis = vecs[:, -1]
    return axis if axis[int(np.argmax(np.abs(axis)))] > 0 else -axis


# --- pure maths: following tops ----------------------------------------------------------


def pixel_angle(xyz: F64, rng: F64, ok: B) -> float:
    """The angle between neighbouring pixels' rays (radians; the median over the frame)."""
    rows = slice(None, None, 8)  # a few rows say it as well as all of them
    with np.errstate(invalid="ignore", divide="ignore"):
        rays = xyz[rows] / rng[rows, :, None]
    both = ok[rows, 1:] & ok[rows, :-1]
    steps = np.linalg.norm(rays[:, 1:] - rays[:, :-1], axis=-1)[both]
    return float(np.median(steps)) if steps.size else 0.004


@dataclass(frozen=True, eq=False)
class Tops:
    """The tops seen in one frame: connected horizontal faces standing above the belt."""

    uv: F64
    """(k, 2) area-weighted centroid in plane coordinates, metres."""
    height_m: F64
    """(k,) mean height above the belt."""
    area_m2: F64
    """(k,) the face's area as seen (metric: it does not change with distance)."""
    pixels: I64


TALLER_M = 0.03
"""A pixel beside a top this much higher than it is on something taller, which may hide it."""
FLAT_SPAN = 2
"""Heights are compared FLAT_SPAN pixels either side of a pixel (over a 5 × 5 mean)."""


def find_tops(
    xyz: F64, rng: F64, ok: B, plane: PlaneFit, e1: F64, e2: F64, pixel_rad: float,
    params: FinderParams,
) -> Tops:  # fmt: skip
    """The horizontal faces standing above the belt, whole and not cut by the view's edge or
    an invalid pixel (a cut top moves at another pace than the belt).

    A face's core is where the mean height over 5 × 5 pixels is level (changes by less than
    `top_tilt_deg` allows over the pixels' spacing); it is grown over its neighbours at its
    height (a metric test, so the face's outline does not change with its distance), and its
    centroid weighs each pixel by the area it covers (r² over the cosine of incidence), so
    near and far parts count as they are."""
    with np.errstate(invalid="ignore"):
        h = np.where(ok, plane.height(xyz), 0.0)
    fg = ok & (h > params.top_height_m)
    w = fg.astype(np.float64)
    wsum = ndimage.uniform_filter(w, 5, mode="constant")
    hs = ndimage.uniform_filter(h * w, 5, mode="constant") / np.maximum(wsum, 1e-6)
    k = FLAT_SPAN
    limit = math.tan(math.radians(params.top_tilt_deg)) * 2 * k * pixel_rad * rng
    flat = fg & (wsum > 1 - 1e-6)
    du = np.full(h.shape, np.inf)
    dv = np.full(h.shape, np.inf)
    du[:, k:-k] = np.abs(hs[:, 2 * k :] - hs[:, : -2 * k])
    dv[k:-k] = np.abs(hs[2 * k :] - hs[: -2 * k])
    with np.errstate(invalid="ignore"):
        flat &= (du < limit) & (dv < limit)
    labels, count = ndimage.label(flat)
    if count == 0:
        return Tops(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, np.int64))
    n = count + 1
    idx = labels.ravel()
    level = np.bincount(idx, weights=h.ravel(), minlength=n) / np.maximum(
        np.bincount(idx, minlength=n), 1
    )
    reach = params.top_reach_m
    for _ in range(params.top_grow):  # grow each core over its neighbours at its height
        grown = ndimage.grey_dilation(labels, size=3)
        dh = h - level[grown]
        take = fg & (labels == 0) & (grown > 0) & (dh < reach) & (dh > -params.top_below_m)
        labels[take] = grown[take]
    edge = ~ok
    edge[0, :] = edge[-1, :] = True
    edge[:, 0] = edge[:, -1] = True
    near_edge = ndimage.binary_dilation(edge, iterations=2)
    at = np.flatnonzero(labels)
    idx = labels.ravel()[at]
    pixels = np.bincount(idx, minlength=n)
    cut = np.bincount(idx[near_edge.ravel()[at]], minlength=n) > 0
    # something higher beside a top may hide part of it (only a taller thing can): not followed
    around = ndimage.grey_dilation(labels, size=5)
    ring = ok & (labels == 0) & (around > 0)
    # a taller surface: over the median of its 3 × 3 heights. A lone pixel read high is not
    # one: in noise, or on a moving edge, whose four taps saw different surfaces (it reads
    # anywhere)
    above = level[around[ring]] + TALLER_M
    higher = stats_kernels.median3_at(h, ring)[ring] > above  # the median at the ring only
    rings = np.bincount(around[ring], minlength=n)
    enough = np.maximum(3, 0.05 * rings)
    cut |= np.bincount(around[ring][higher], minlength=n) > enough
    # each pixel's point where its ray meets the top's level (the mean of many heights): the
    # range noise along the ray no longer moves it in the plane, only the outline does
    top_level = level  # of the core: the grown rim takes in a little of the faces below
    rays = xyz.reshape(-1, 3)[at] / rng.ravel()[at, None]
    incidence = np.abs(rays @ plane.normal)
    reach_t = (plane.offset_m + top_level[idx]) / -np.maximum(incidence, 0.05)
    pts = rays * reach_t[:, None]
    a = (reach_t * pixel_rad) ** 2 / np.maximum(incidence, 0.05)
    total = np.bincount(idx, weights=a, minlength=n)
    u = np.bincount(idx, weights=a * (pts @ e1), minlength=n)
    v = np.bincount(idx, weights=a * (pts @ e2), minlength=n)
    keep = (pixels >= params.min_top_pixels) & ~cut & (total > 0)
    keep[0] = False
    tot = np.asarray(total[keep], np.float64)
    uv = np.stack([u[keep] / tot, v[keep] / tot], axis=1)
    return Tops(uv, np.asarray(top_level[keep], np.float64), tot, pixels[keep].astype(np.int64))


@dataclass
class _Follow:
    """One top being followed: running sums for its least-squares line (positions relative
    to its first, so the sums keep their precision)."""

    area: float
    """Its area as last seen (for matching)."""
    height: float
    last_t: float
    last_uv: F64
    areas: list[float] = field(default_factory=list)
    """Areas of the positions taken (the last few): their median is its usual size."""
    n: int = 0
    t0: float = 0.0
    uv0: F64 = field(default_factory=lambda: np.zeros(2))
    st: float = 0.0
    stt: float = 0.0
    su: F64 = field(default_factory=lambda: np.zeros(2))
    stu: F64 = field(default_factory=lambda: np.zeros(2))
    suu: F64 = field(default_factory=lambda: np.zeros(2))

    KEEP = 15

    @property
    def usual_area(self) -> float:
        """The median area of its last sightings taken: its size when seen whole."""
        return float(np.median(self.areas)) if self.areas else self.area

    def add(self, t: float, uv: F64, area: float, height: float, gate: float) -> None:
        """Take a sighting; its position counts only when the top is seen whole (its area
        within `gate` of its usual one): a top missing a piece has its centroid moved."""
        self.area, self.height, self.last_t, self.last_uv = area, height, t, uv
        if self.n and abs(area / self.usual_area - 1) > gate:
            return
        if self.n == 0:
            self.t0, self.uv0 = t, uv
        self.areas = [*self.areas[-(self.KEEP - 1) :], area]
        tt, d = t - self.t0, uv - self.uv0
        self.n += 1
        self.st += tt
        self.stt += tt * tt
        self.su = self.su + d
        self.stu = self.stu + tt * d
        self.suu = self.suu + d * d

    def segment(self) -> Segment | None:
        """The velocity of the line through its positions, or None for fewer than 3."""
        if self.n < 3:
            return None
        n = self.n
        var_t = self.stt - self.st * self.st / n
        if var_t <= 0:
            return None
        slope = (self.stu - self.st * self.su / n) / var_t
        ss_u = self.suu - self.su * self.su / n  # residual sum of squares of u = a + b·t
        ss_res = np.maximum(ss_u - slope * slope * var_t, 0.0)
        rms = math.sqrt(float(ss_res.sum()) / n)
        return Segment(slope, self.last_t - self.t0, n, rms, self.uv0 + self.su / n)


def match_tops(
    follows: list[_Follow], tops: Tops, t: float, params: FinderParams
) -> list[int | None]:
    """For each top of this frame (at time `t`), the followed top it continues (or None): the
    nearest within how far the belt can have moved since that one was last seen, at the same
    height, of about the same size."""
    out: list[int | None] = [None] * len(tops.area_m2)
    if not follows or not out:
        return out
    last = np.array([f.last_uv for f in follows])
    gap = np.linalg.norm(tops.uv[:, None, :] - last[None, :, :], axis=-1)
    height = np.array([f.height for f in follows])
    ratio = tops.area_m2[:, None] / np.array([f.usual_area for f in follows])[None, :]
    since = np.array([t - f.last_t for f in follows])
    grow = 1 + params.size_change
    fits = gap < params.max_speed_mps * since[None, :] + 0.02
    fits &= np.abs(tops.height_m[:, None] - height[None, :]) < 0.025
    fits &= (ratio > 1 / grow) & (ratio < grow)
    used: set[int] = set()
    for k in np.argsort(np.where(fits, gap, np.inf), axis=None, kind="stable"):
        i, j = divmod(int(k), len(follows))
        if not fits[i, j]:
            break
        if out[i] is None and j not in used:
            out[i] = j
            used.add(j)
    return out


TOP_BIAS = 0.02
"""How far a followed top's velocity may be off, as a share of its speed, however well its
line fits: its outline, and so its centroid, changes a little as the view of it changes."""


def travel_from(segments: list[Segment], params: FinderParams) -> TravelFit | None:
    """Direction and speed from followed tops: medians of their directions and speeds over the
    tops that moved, each weighted by how well its line pins its velocity (the inverse square
    of the slope's standard error, frames × time² / scatter²: a top followed twice as long
    counts eight times as much), taken again over the tops that agree with the first (within
    `max_spread_deg` and `agree_speed`); None when none moved.

    Agreement, not the scatter of all, is what the travel is judged by: a top followed over a
    few frames while a moving edge misreads its outline votes wide of the rest, and many such
    votes hid the tops followed cleanly for a second."""
    moving = [
        s for s in segments
        if s.seconds >= params.min_follow_s and s.rms_m <= params.max_track_rms_m
        and params.min_speed_mps <= float(np.linalg.norm(s.velocity)) <= params.max_speed_mps
    ]  # fmt: skip
    if not moving:
        return None
    vel = np.array([s.velocity for s in moving])
    # 1 / the slope's variance: a line through n evenly spaced points over T seconds with
    # scatter rms has variance 12 rms² / (n T²)
    w = np.array([s.frames * s.seconds**2 / (12 * max(s.rms_m, 0.001) ** 2) for s in moving])
    speeds = np.linalg.norm(vel, axis=1)
    # no top pins the travel better than its own way of being seen allows (its outline
    # changes with the view as it goes): the medians weigh each at most so
    vote = 1.0 / (1.0 / w + (TOP_BIAS * speeds) ** 2)
    mean = (vel / speeds[:, None] * w[:, None]).sum(axis=0)
    if float(np.linalg.norm(mean)) < 1e-9:
        return None
    base = math.atan2(float(mean[1]), float(mean[0]))
    angles = np.angle(np.exp(1j * (np.arctan2(vel[:, 1], vel[:, 0]) - base)))
    turn, speed = _medians(vel, angles, base, vote, np.ones(len(moving), np.bool_))
    along = vel @ np.array([math.cos(base + turn), math.sin(base + turn)])
    agree = (np.abs(angles - turn) <= math.radians(params.max_spread_deg)) & (
        np.abs(along - speed) <= params.agree_speed * abs(speed)
    )
    if not agree.any():
        agree[int(np.argmax(w))] = True
    turn, speed = _medians(vel, angles, base, vote, agree)
    direction = np.array([math.cos(base + turn), math.sin(base + turn)])
    along = vel @ direction
    kept = [s for s, a in zip(moving, agree, strict=True) if a]
    return TravelFit(
        direction,
        speed,
        # how much the agreeing tops scatter, each counting once (a weighted spread would be
        # that of the one top that holds most of the weight: nothing)
        math.degrees(robust_sigma(angles[agree] - turn)),
        robust_sigma(along[agree] - speed),
        len(kept),
        float(sum(s.seconds for s in kept)),
        max(s.seconds for s in kept),
        1.0 / math.sqrt(float(w[agree].sum())),
        float(w[agree].sum() / w.sum()),
    )


def _medians(vel: F64, angles: F64, base: float, w: F64, use: B) -> tuple[float, float]:
    """The weighted median turn from `base` and speed along it of the velocities in `use`."""
    turn = weighted_median(angles[use], w[use])
    along = vel[use] @ np.array([math.cos(base + turn), math.sin(base + turn)])
    return turn, weighted_median(along, w[use])


def moved(segments: list[Segment], params: FinderParams) -> bool:
    """Whether any followed top moved: went `min_shift_m` or more along a straight line."""
    return any(
        s.rms_m <= params.max_track_rms_m and s.seconds >= params.min_follow_s / 2
        and float(np.linalg.norm(s.velocity)) * s.seconds >= params.min_shift_m
        and params.min_speed_mps <= float(np.linalg.norm(s.velocity)) <= params.max_speed_mps
        for s in segments
    )  # fmt: skip


def weighted_median(values: F64, weights: F64) -> float:
    """The value below which half the weight lies."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    i = int(np.searchsorted(cum, cum[-1] / 2))
    return float(values[order][min(i, len(values) - 1)])


# --- pure maths: width --------------------------------------------------------------------


def belt_edges(
    belt_uv: F64, rim_uv: F64, rim_h: F64, lower_uv: F64, along: F64, across: F64,
    slice_m: float = 0.05,
) -> WidthFit | None:  # fmt: skip
    """The belt's width across `across` where both its edges are in view.

    In each slice along the belt, an edge is where the belt's own points end — or, where a
    raised rim (a rail; its level points `rim_uv` at heights `rim_h`) stands just beyond
    them, the inner side of the rim's top: a rail nearer the camera hides a strip of the belt
    beside it, and the belt runs on to the rail. An edge is in view when something (a rim or
    something lower) is seen beyond it in that slice. The width is the median over the slices
    where both are."""
    if len(belt_uv) < 30:
        return None
    belt = _Slices(belt_uv @ along, belt_uv @ across, slice_m)
    rim = _Slices(rim_uv @ along, rim_uv @ across, slice_m, rim_h)
    lower = _Slices(lower_uv @ along, lower_uv @ across, slice_m)
    widths, centres = [], []
    for k in np.unique(belt.keys):
        s = np.sort(belt.get(k)[0])
        if s.size < 10:
            continue
        s_lo, s_hi = float(s[1]), float(s[-2])  # the second extreme: one stray point is noise
        r, rh = rim.get(k)
        q = lower.get(k)[0]
        hi_edge = _edge(r - s_hi, rh, q - s_hi)
        lo_edge = _edge(s_lo - r, rh, s_lo - q)
        if hi_edge is None or lo_edge is None:
            continue
        top, bottom = s_hi + hi_edge, s_lo - lo_edge
        widths.append(top - bottom)
        centres.append((top + bottom) / 2)
    if len(widths) < 3:
        return None
    w = np.array(widths)
    width = float(np.median(w))
    spread = float(np.median(np.abs(w - width)))
    if spread > MAX_WIDTH_SPREAD_M:
        return None  # the slices disagree: the edges seen are not the belt's (boxes hide them)
    return WidthFit(width, float(np.median(centres)), len(widths), spread)


def holds_tops(
    width: WidthFit, travel: TravelFit, segments: list[Segment], params: FinderParams
) -> bool:
    """Whether the belt's `width` holds the tops carried along the `travel` (their mean
    positions within its edges, `MAX_OUTSIDE_M` of slack): edges read wrong (in loud noise,
    or where a rail's shadow ends the belt's points early) leave the tops outside."""
    across = np.array([-travel.direction[1], travel.direction[0]])
    carried = [
        float(s.centre @ across) for s in segments
        if s.seconds >= params.min_follow_s and s.rms_m <= params.max_track_rms_m
        and float(s.velocity @ travel.direction) >= travel.speed_mps / 2
    ]  # fmt: skip
    if not carried:
        return True
    off = np.abs(np.array(carried) - width.centre_m) - width.width_m / 2
    return int((off > MAX_OUTSIDE_M).sum()) <= MAX_OUTSIDE_SHARE * len(carried)


MAX_OUTSIDE_M = 0.03
"""A carried top's mean position may lie this far outside the belt's edges (its outline
misread at a rail)..."""
MAX_OUTSIDE_SHARE = 0.1
"""...and this share of them farther: a width leaving more outside is not the belt's."""


class _Slices:
    """Points sorted into slices along the belt, for looking them up slice by slice."""

    def __init__(self, along: F64, across: F64, slice_m: float, extra: F64 | None = None):
        keys = np.floor(along / slice_m).astype(np.int64)
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.across = across[order]
        self.extra = (np.zeros(len(order)) if extra is None else extra)[order]

    def get(self, key: int) -> tuple[F64, F64]:
        """The across positions (and extra values) of the points in slice `key`."""
        lo, hi = np.searchsorted(self.keys, [key, key + 1])
        return self.across[lo:hi], self.extra[lo:hi]


def _rank(values: F64, share: float) -> float:
    """The value `share` of the way up the sorted values (a percentile without numpy's
    interpolation machinery: these are small arrays, looked at many times)."""
    ordered = np.sort(values)
    return float(ordered[round(share * (len(ordered) - 1))])


MAX_WIDTH_SPREAD_M = 0.02
"""Slices whose widths scatter more than this (median absolute deviation) give no width."""
ADJACENT_M = 0.025
"""A rim this close past the belt's last point stands right beside it: nothing is hidden."""


def _edge(rim: F64, rim_h: F64, lower: F64, reach: float = 0.25) -> float | None:
    """How far past the belt's last point its edge lies on one side, from the rim points' and
    the lower points' distances past that point; None when nothing is seen past it.

    A rim within `reach` is where the belt runs to, hidden in the rim's shadow when the camera
    looks over it: its edge is the inner side of the rim's top (the points within 1 cm of
    the highest — pixels mixing the rim with the belt behind it lie between, lower), or
    halfway to it when it stands right beside the belt's last point. Else the belt ends at
    its last point (a drop: the floor, or the belt's own side)."""
    near = (rim > -0.02) & (rim < reach)
    if np.count_nonzero(near) >= 3:
        r, h = rim[near], rim_h[near]
        top = r[h >= _rank(h, 0.95) - 0.01]
        past = max(0.0, _rank(top, 0.05))
        # next to the belt's last point (no shadow between), the edge lies between the two
        return past / 2 if past < ADJACENT_M else past
    q = lower[(lower > 0.0) & (lower < reach)]
    return 0.0 if q.size >= 3 else None


# --- pure maths: the plane from a few frames ------------------------------------------


def steady_plane(
    mean_xyz: F64, steady: B, sigma: F64, layers: list[PlaneFit], belt: int,
    params: FinderParams,
) -> PlaneFit | None:  # fmt: skip
    """The belt's plane from pixels averaged over a few frames, starting from the first
    frame's layers (`belt` indexes the belt's): averaging brings a pixel's noise down enough
    that a rail's top (a few cm up) or a box's foot no longer falls within the band, and the
    pixels beside anything standing on the belt (mixed with it) are left out. `steady`:
    pixels valid in every frame and not moving; `sigma`: their averaged noise."""
    first = layers[belt]
    with np.errstate(invalid="ignore"):
        h = np.where(steady, first.height(mean_xyz), 0.0)
    standing = steady & (h > params.top_height_m)
    use = steady & ~ndimage.binary_dilation(standing, iterations=2) & np.isfinite(h)
    if np.count_nonzero(use) < 3:
        return None
    pts, sig = mean_xyz[use], sigma[use]
    band = band_of(sig, params)
    normal, offsets = family_plane(pts, sig, first.normal, [lay.offset_m for lay in layers], band)
    off = offsets[belt]
    held = np.abs(pts @ normal - off) < band
    if np.count_nonzero(held) < 3:
        return None
    rms = float(np.sqrt(np.mean((pts[held] @ normal - off) ** 2)))
    return PlaneFit(normal, off, rms, int(np.count_nonzero(held)), int(np.count_nonzero(steady)))


@dataclass
class _Stack:
    """Per-pixel sums over the first frames: how often valid, summed points, range extremes."""

    frames: int
    count: I64
    xyz: F64
    sigma2: F64
    low: F64
    high: F64

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> _Stack:
        return cls(
            0, np.zeros(shape, np.int64), np.zeros((*shape, 3)), np.zeros(shape),
            np.full(shape, np.inf), np.full(shape, -np.inf),
        )  # fmt: skip

    def add(self, frame: Frame, ok: B, sigma: F64) -> None:
        """Add a frame's usable pixels."""
        self.frames += 1
        self.count += ok
        self.xyz += np.where(ok[..., None], frame.xyz, 0.0)
        self.sigma2 += np.where(ok, sigma**2, 0.0)
        rng = np.where(ok, frame.range, np.nan)
        np.fmin(self.low, rng, out=self.low)
        np.fmax(self.high, rng, out=self.high)

    def mean(self) -> tuple[F64, B, F64]:
        """Mean points, the steady pixels (valid in every frame, their range spread within
        their noise) and the mean's noise."""
        full = self.count == self.frames
        n = np.maximum(self.count, 1)
        sigma = np.sqrt(self.sigma2 / n) / np.sqrt(n)
        steady = full & (self.high - self.low < np.maximum(6.0 * sigma * np.sqrt(n), 0.03))
        return self.xyz / n[..., None], steady, sigma


# --- the stateful finder ------------------------------------------------------------------


class BeltFinder:
    """Finds the belt from the frames of the first seconds of a run.

    The plane comes from the first frame (about 25-40 ms), and is refitted once on the mean
    of the first `plane_frames` (a few ms); the travel once enough tops have been followed
    (about 3 ms a frame until then); the width with it. Once the estimate is final (`done`),
    `update` returns it at once: a live run can keep calling it.
    """

    def __init__(self, params: FinderParams | None = None) -> None:
        self.params = params or FinderParams()
        self.done = False
        """True once the estimate is final: `update` then does nothing."""
        self._estimate = BeltEstimate(None, "looking")
        self._frames = 0
        self._t_first: float | None = None
        self._t_last: float | None = None
        self._plane: PlaneFit | None = None
        self._plane_final = False
        self._stack: _Stack | None = None
        self._layers: list[PlaneFit] = []
        self._belt_layer = 0
        self._e1 = np.array([1.0, 0.0, 0.0])
        self._e2 = np.array([0.0, 1.0, 0.0])
        self._axis2d = np.array([1.0, 0.0])
        self._pixel_rad = 0.004
        self._follows: list[_Follow] = []
        self._segments: list[Segment] = []
        self._travel: TravelFit | None = None
        self._status: Travel = "looking"
        self._moved = False
        self._edges: _EdgeSums | None = None
        self._width: WidthFit | None = None
        self._width_tried: float | None = None
        self._sweep: SweepWindow | None = None
        self._swept: SweptLayer | None = None
        self.moves = 0
        """Times the plane was moved to another layer, once it was seen what moves over which."""

    @property
    def estimate(self) -> BeltEstimate:
        """The latest estimate."""
        return self._estimate

    def update(self, frame: Frame) -> BeltEstimate:
        """Take one frame (in device-time order; a repeated or older one is passed over, as is
        one with fewer than three usable pixels); the estimate so far."""
        if self.done:
            return self._estimate
        t = frame.device_time_us * 1e-6
        if self._t_last is not None and t <= self._t_last:
            return self._estimate  # a repeated or out-of-order frame
        ok = usable(frame)
        if np.count_nonzero(ok) < 3:
            return self._estimate
        self._frames += 1
        self._t_first = t if self._t_first is None else self._t_first
        self._t_last = t
        sigma = range_noise(frame, NOISE_FLOOR_M)
        if not self._plane_final:
            self._fit_plane(frame, ok, sigma)
        elif self._plane is not None:
            self._follow(frame, ok, t)
            if self._edges is None:
                self._edges = _EdgeSums.empty(ok.shape)
            if self._edges.frames % self.params.edges_every == 0:
                self._edges.add(frame.xyz, ok, self._plane, self._e1, self._e2)
            self._edges.frames += 1
        self._sweep_frame(frame, ok, sigma, t)
        if self._plane_final and self._status != "looking" and self._settled(t):
            self.done = self._width_settled(t)
        self._estimate = self._make_estimate()
        return self._estimate

    def finish(self) -> BeltEstimate:
        """The estimate when no more frames will come: a travel not yet trusted becomes "none"
        when nothing moved on the belt, "unsure" when things did."""
        if not self.done and self._plane is not None:
            self._close_follows()
            travel = travel_from(self._segments, self.params)
            self._travel = travel if self._trusted(travel) else None
            self._moved = self._moved or moved(self._segments, self.params)
            self._status = (
                "found" if self._travel is not None else "unsure" if self._moved else "none"
            )
            self._width = self._fit_width()
        self.done = True
        self._estimate = self._make_estimate()
        return self._estimate

    # --- the plane -----------------------------------------------------------------------

    def _fit_plane(self, frame: Frame, ok: B, sigma: F64) -> None:
        """The first frame's layers and belt; the frames' sums; the refit once enough are in."""
        p = self.params
        if self._plane is None:
            layers = find_belt_layers(frame.xyz, ok, sigma, p)
            pick = choose_belt(layers, p)
            if pick is None:
                return
            self._layers = [lay.plane for lay in layers]
            self._belt_layer = pick
            self._pixel_rad = pixel_angle(frame.xyz, frame.range, ok)
            self._set_plane(layers[pick].plane)
            self._stack = _Stack.empty(ok.shape)
        assert self._stack is not None
        assert self._plane is not None
        self._stack.add(frame, ok, sigma)
        if self._stack.frames < p.plane_frames:
            return
        mean, steady, noise = self._stack.mean()
        steady &= noise <= quiet_enough(noise[steady], p)
        fit = steady_plane(mean, steady, noise, self._layers, self._belt_layer, p)
        if fit is not None:
            self._set_plane(fit)
        self._plane_final = True
        self._stack = None
        with np.errstate(invalid="ignore"):
            on = steady & (np.abs(self._plane.height(mean)) < band_of(noise, p))
        pts = mean[on]
        self._axis2d = long_axis(np.stack([pts @ self._e1, pts @ self._e2], axis=1))

    def _set_plane(self, plane: PlaneFit) -> None:
        self._plane = plane
        self._e1, self._e2 = plane_basis(plane.normal)

    # --- the travel ----------------------------------------------------------------------

    def _follow(self, frame: Frame, ok: B, t: float) -> None:
        """Follow this frame's tops on, re-estimate the travel, and settle the state."""
        if self._status != "looking":
            return
        assert self._plane is not None
        assert self._t_first is not None
        p = self.params
        tops = find_tops(
            frame.xyz,
            frame.range,
            ok,
            self._plane,
            self._e1,
            self._e2,
            self._pixel_rad,
            p,
        )
        matched = match_tops(self._follows, tops, t, p)
        taken = {j for j in matched if j is not None}
        kept: list[_Follow] = []
        for j, f in enumerate(self._follows):
            if j in taken:
                continue
            if t - f.last_t <= p.max_gap_s:
                kept.append(f)  # missed this frame: it may be seen again
            else:
                self._close(f)
        for i, which in enumerate(matched):
            uv, area, h = tops.uv[i], float(tops.area_m2[i]), float(tops.height_m[i])
            f = _Follow(area, h, t, uv) if which is None else self._follows[which]
            f.add(t, uv, area, h, p.area_gate)
            kept.append(f)
        self._follows = kept
        ongoing = [s for f in kept if (s := f.segment()) is not None]
        travel = travel_from(self._segments + ongoing, p)
        self._travel = travel if self._trusted(travel) else None
        elapsed = t - self._t_first
        self._moved = self._moved or moved(self._segments + ongoing, p)
        if self._travel is not None and (
            (self._travel.seconds >= p.done_s and elapsed >= p.min_done_s) or elapsed >= p.max_s
        ):
            self._status = "found"
        elif self._travel is None and not self._moved and elapsed >= p.patience_s:
            self._status = "none"  # long enough, and nothing moved
        elif self._travel is None and elapsed >= p.give_up_s:
            self._status = "unsure"
        if self._status != "looking":
            self._close_follows()

    def _trusted(self, travel: TravelFit | None) -> bool:
        """Enough tops, followed long enough, agreeing well enough, to say the travel."""
        p = self.params
        return (
            travel is not None and travel.seconds >= p.settle_s
            and travel.longest_s >= p.min_longest_s
            and travel.speed_se_mps <= p.max_speed_se * abs(travel.speed_mps)
            and travel.agreeing > p.min_agreeing
        )  # fmt: skip

    def _close(self, f: _Follow) -> None:
        s = f.segment()
        if s is not None:
            self._segments.append(s)

    def _close_follows(self) -> None:
        for f in self._follows:
            self._close(f)
        self._follows = []

    # --- the layer things move over -----------------------------------------------------

    def _width_settled(self, t: float) -> bool:
        """Fit the width (again every `width_every_s`) once the travel is final and the belt
        has run `width_run_m`: whether it is settled, found or looked for until `give_up_s`
        (the edges take more frames than the travel: a belt whose travel was plain in a
        second hid its edges under its objects)."""
        assert self._t_first is not None
        p = self.params
        elapsed = t - self._t_first
        travel = self._travel
        swept = travel is None or travel.speed_mps * elapsed >= p.width_run_m
        if not swept and elapsed < p.give_up_s:
            return False
        if self._width_tried is None or t - self._width_tried >= p.width_every_s:
            self._width_tried = t
            self._width = self._fit_width()
        return self._width is not None or travel is None or elapsed >= p.give_up_s

    def _settled(self, t: float) -> bool:
        """Whether the belt's layer is settled: seen swept, or nothing moved to sweep it, or
        looked for long enough."""
        assert self._t_first is not None
        if self._swept is not None or self._status == "none":
            return True
        return t - self._t_first >= self.params.give_up_s

    def _sweep_frame(self, frame: Frame, ok: B, sigma: F64, t: float) -> None:
        """Sample the frame into the sweep window and, when due, judge which layer is swept
        (`tracker.belt_sweep`); move the plane there if it is not the one chosen."""
        if self._plane is None or not self._plane_final or self._swept is not None:
            return  # the refitted plane's normal: the first frame's may be a little off
        p = self.params
        if self._sweep is None:
            self._sweep = SweepWindow(ok.shape, self._plane.normal, p.sweep)
        if self._sweep.sampling(t):  # the noise's median only for the frames sampled
            self._sweep.add(frame.xyz, ok & (sigma <= quiet_enough(sigma[ok], p)), sigma, t)
        if not self._sweep.due(t):
            return
        window = self._sweep
        heights, usable, noise = window.judged(t)
        band = band_of(noise.astype(np.float64), p).astype(np.float32)
        offsets = pooled_layers(heights, usable, noise, band, p)
        verdict = choose_swept(
            swept_layers(heights, usable, noise, offsets, band, p.sweep), window.pixels, p.sweep
        )
        if verdict is None:
            return
        self._swept, self._sweep = verdict, None
        if abs(verdict.offset_m - self._plane.offset_m) <= p.max_band_m:
            return
        plane = PlaneFit(
            window.normal, verdict.offset_m, verdict.rms_m, verdict.on,
            int(np.count_nonzero(usable)),
        )  # fmt: skip
        self._move_plane(plane, frame, ok, sigma)

    def _move_plane(self, plane: PlaneFit, frame: Frame, ok: B, sigma: F64) -> None:
        """Put the belt on another layer: what was followed over the old one starts again."""
        self._set_plane(plane)
        self.moves += 1
        self._follows, self._segments, self._travel = [], [], None
        self._status, self._edges, self._width = "looking", None, None
        with np.errstate(invalid="ignore"):
            on = ok & (np.abs(plane.height(frame.xyz)) < band_of(sigma, self.params))
        pts = frame.xyz[on]
        self._axis2d = long_axis(np.stack([pts @ self._e1, pts @ self._e2], axis=1))

    # --- the estimate --------------------------------------------------------------------

    def _direction2d(self) -> F64:
        return self._travel.direction if self._travel is not None else self._axis2d

    def _fit_width(self) -> WidthFit | None:
        """The width across the travel (none without one: across what?), if it holds the
        tops that were carried along it (`holds_tops`)."""
        if self._travel is None or self._edges is None:
            return None
        width = self._edges.width(self._travel.direction)
        if width is None or not holds_tops(width, self._travel, self._segments, self.params):
            return None
        return width

    def _make_estimate(self) -> BeltEstimate:
        """The estimate from what is known now."""
        plane = self._plane
        seconds = (self._t_last or 0.0) - (self._t_first or 0.0)
        if plane is None:
            return BeltEstimate(None, "looking", frames=self._frames, seconds=seconds)
        d2 = self._direction2d()
        direction = d2[0] * self._e1 + d2[1] * self._e2
        across = np.cross(plane.normal, direction)  # = -d2[1] e1 + d2[0] e2
        point = plane.axis_point
        width = self._width
        if width is not None:  # the centre line, level with the optical axis
            point = point + (width.centre_m - float(point @ across)) * across
        geometry = BeltGeometry(point, direction, plane.normal, width.width_m if width else None)
        travel = self._travel
        return BeltEstimate(
            KnownBelt(geometry, travel.speed_mps if travel else None, "found"),
            "found" if travel is not None else self._status,
            self._plane_final,
            plane.rms_m,
            plane.inlier_share,
            self._frames,
            seconds,
            travel.direction_spread_deg if travel else math.nan,
            travel.speed_spread_mps if travel else math.nan,
            travel.speed_se_mps if travel else math.nan,
            travel.segments if travel else 0,
            len(self._layers),
        )


@dataclass
class _EdgeSums:
    """Per pixel, over the frames: its heights where it read near the belt (a histogram, for
    their median), how often it read well above or below it, and its mean height and plane
    position in each case (for the width)."""

    frames: int
    """Frames offered (every `edges_every`-th is taken)."""
    valid: I64
    counts: I64
    """(3, H, W): frames near the belt (within `NEAR_M`), well above it, well below it."""
    heights: F64
    """(3, H, W): heights summed per case."""
    sums: F64
    """(3, H, W, 2): plane positions summed per case."""
    near: U16
    """(NEAR_BINS, H, W): the readings near the belt, by height."""

    NEAR_M = 0.06
    """A reading this close to the belt is the belt or a low rim on it."""
    BELT_M = 0.015
    """A pixel whose mean height near the belt is within this is the belt (a rail 4 cm up,
    within a few noise sigmas of the belt frame by frame, is not)."""
    MAX_RIM_M = 0.3
    """A rim or guard beside the belt stands no higher than this."""
    NEAR_BINS = 48
    """Bins of the near readings' histogram, across +-`NEAR_M` (2.5 mm each)."""

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> _EdgeSums:
        return cls(
            0, np.zeros(shape, np.int64), np.zeros((3, *shape), np.int64),
            np.zeros((3, *shape)), np.zeros((3, *shape, 2)),
            np.zeros((cls.NEAR_BINS, *shape), np.uint16),
        )  # fmt: skip

    def add(self, xyz: F64, ok: B, plane: PlaneFit, e1: F64, e2: F64) -> None:
        """Add a frame's usable pixels, by their height above the plane."""
        self.valid += ok
        with np.errstate(invalid="ignore"):
            h = plane.height(xyz)
            near = ok & (np.abs(h) < self.NEAR_M)
            cases = (near, ok & (h >= self.NEAR_M), ok & (h <= -self.NEAR_M))
        uv = np.stack([xyz @ e1, xyz @ e2], axis=-1)
        for k, mask in enumerate(cases):
            self.counts[k] += mask
            self.heights[k][mask] += h[mask]
            self.sums[k][mask] += uv[mask]
        at = np.flatnonzero(near)
        step = 2 * self.NEAR_M / self.NEAR_BINS
        bins = np.clip(
            ((h.ravel()[at] + self.NEAR_M) / step).astype(np.int64), 0, self.NEAR_BINS - 1
        )
        flat = self.near.reshape(self.NEAR_BINS, -1)
        flat[bins, at] += np.uint16(1)  # one reading per pixel: no repeated index

    def near_median(self) -> F64:
        """Each pixel's median height of its readings near the belt (to the histogram's 2.5
        mm; NaN under 3 readings)."""
        n = self.counts[0]
        cum = np.cumsum(self.near, axis=0, dtype=np.int64)
        k = np.argmax(cum >= np.maximum(0.5 * n, 1), axis=0)  # the bin holding the middle one
        step = 2 * self.NEAR_M / self.NEAR_BINS
        return np.where(n >= 3, -self.NEAR_M + (k + 0.5) * step, np.nan)

    def width(self, d2: F64) -> WidthFit | None:
        """The width across the direction `d2` (plane basis), where both edges are seen."""
        near_n, up_n, down_n = self.counts
        seen = self.valid > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            median = self.near_median()
            uv = self.sums[0] / near_n[..., None]
            steady_up = seen & (up_n >= 0.8 * self.valid)
            up = np.where(steady_up, self.heights[1] / up_n, np.nan)
            up_uv = self.sums[1] / up_n[..., None]
        flat = level(median, uv)  # not a wall, nor pixels mixing two surfaces at an edge
        is_belt = flat & (np.abs(median) < self.BELT_M)
        low_rim = flat & (median >= self.BELT_M)
        # a taller guard's level top; not what stands far above (nor a far pixel whose range
        # wrapped round to look near)
        high_rim = ~is_belt & ~low_rim & level(np.where(up <= self.MAX_RIM_M, up, np.nan), up_uv)
        is_lower = seen & ~is_belt & ~low_rim & ~high_rim
        is_lower &= (down_n >= 0.8 * self.valid) | (median <= -self.BELT_M)

        def place(k: int, mask: B) -> F64:
            return np.asarray(self.sums[k][mask] / self.counts[k][mask][:, None], np.float64)

        def height(k: int, mask: B) -> F64:
            return np.asarray(self.heights[k][mask] / self.counts[k][mask], np.float64)

        rim = np.concatenate([place(0, low_rim), place(1, high_rim)])
        rim_h = np.concatenate([height(0, low_rim), height(1, high_rim)])
        lower_near = is_lower & (near_n >= 3)
        lower = np.concatenate([place(0, lower_near), place(2, is_lower & ~lower_near)])
        across = np.array([-d2[1], d2[0]])
        return belt_edges(place(0, is_belt), rim, rim_h, lower, d2, across)


def level(height: F64, uv: F64, max_tilt_deg: float = 30.0) -> B:
    """Pixels on a level surface: their neighbours either side (along rows and columns) are at
    nearly the same height for their distance apart in the plane. A wall's pixels at the
    belt's height are not the belt (the outer face of a rail the camera looks at)."""
    limit = math.tan(math.radians(max_tilt_deg))
    out = np.isfinite(height)
    for axis in (0, 1):
        after, before, inner = [slice(None)] * 2, [slice(None)] * 2, [slice(None)] * 2
        after[axis], before[axis], inner[axis] = slice(2, None), slice(None, -2), slice(1, -1)
        dh = np.abs(height[tuple(after)] - height[tuple(before)])
        duv = np.linalg.norm(uv[tuple(after)] - uv[tuple(before)], axis=-1)
        flat = np.zeros(height.shape, bool)
        with np.errstate(invalid="ignore"):
            flat[tuple(inner)] = dh <= limit * duv
        out &= flat
    return out


def find_belt(
    frames: Iterable[Frame], seconds: float, params: FinderParams | None = None
) -> BeltEstimate:
    """The belt from a source's frames: at most `seconds` of them (device time), fewer when
    the estimate is final before; what was not found by then is reported as such."""
    finder = BeltFinder(params)
    start: float | None = None
    for frame in frames:
        t = frame.device_time_us * 1e-6
        start = t if start is None else start
        if t - start > seconds:
            break
        finder.update(frame)
        if finder.done:
            return finder.estimate
    return finder.finish()
