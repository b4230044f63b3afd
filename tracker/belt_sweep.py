"""Which layer is the belt: the surface that things are seen to move over.

One frame can take the floor beside a raised belt, or the tops of boxes packed side by side,
for the belt: both are large, level and have things standing on them or edges dropping away.
Over a few seconds the belt tells itself apart by what happens on it. Its pixels are covered
by what passes over them and show the belt again afterwards, and nothing is ever seen below
it. A box top is seen through when its box moves on (the belt shows below it); the floor is
only hidden, behind what passes at a tilt, and far less of it than the belt.

So, over a window of sampled frames, each layer (a peak of the heights along the family's
normal, pooled over the window) scores the pixels that were on it, were above it at other
times, and were never below it. The belt is the layer that scores most; a nearer layer that
scores at least half as much, and is clearly apart from it, is the belt instead (the floor
can score high at steep tilts, never a layer above the belt) — unless the best one's swept
pixels were seen on the nearer one too: then the nearer one is a layer of tops that went over
the best (a big box, followed by a taller one, swept and never showed the belt in the first
second of a line that starts full), and the best is the belt. Heights are 3×3 medians, so
that a pixel's noise or a wrapped far reading does not pass for something going over it;
nor does a reading nearer the camera than anything on a layer can stand (`TALLEST_SHARE` of
the camera's height over it): beyond the unambiguous range the floor's noise throws its phase
round and back, and it flickers between itself and a point by the camera. Above or below is
judged against the median's noise: against one reading's, on a loud line the belt seen 13 cm
below a layer of box tops did not count as below it, and those tops were taken for the belt.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofcut._types import F32, F64, B
from tofcut.tracker import belt_sweep_kernels, stats_kernels
from tofcut.tracker.background import MEDIAN_SHARES, TALLEST_SHARE
from tofcut.tracker.errors import SegmentError

INVALID = -1e3
"""Height given to unusable pixels before the median (far below any layer)."""


@dataclass(frozen=True)
class SweepParams:
    """How the belt is told from the other layers by what moves over it."""

    every_s: float = 0.1
    """A frame is sampled this often..."""
    window_s: float = 4.0
    """...and the last this many seconds of samples are judged."""
    first_s: float = 1.0
    """No verdict before this many seconds of samples..."""
    judge_every_s: float = 0.5
    """...and then one this often, until there is one."""
    max_pixels: int = 8000
    """At most this many pixels are sampled (an even grid over the frame)."""
    min_share: float = 0.01
    """No verdict before the best layer's swept pixels are this share of those sampled."""
    nearer_share: float = 0.5
    """A nearer layer with this share of the best's score is the belt instead..."""
    apart_m: float = 0.06
    """...if it is at least this much nearer (two peaks of one layer are not two layers)..."""
    max_shared: float = 0.1
    """...and at most this share of the best's swept pixels were seen on it: more, and it is
    a layer of tops going over the best one (the floor's pixels, which the belt never moves
    away from, are not)."""
    min_times: int = 2
    """A pixel is on a layer, or above it, in at least this many samples."""
    above_m: float = 0.03
    """Above (or below) a layer: by 3 sigmas of a height's noise (a 3×3 median's), and at least
    this."""

    def __post_init__(self) -> None:
        times = (self.every_s, self.window_s, self.first_s, self.judge_every_s, self.apart_m)
        if not all(x > 0 for x in (*times, self.above_m)):
            raise SegmentError("sweep times and lengths must be positive")
        if not (0 < self.min_share < 1 and 0 < self.nearer_share <= 1):
            raise SegmentError("min_share in (0, 1) and nearer_share in (0, 1]")
        if not 0 <= self.max_shared <= 1:
            raise SegmentError("max_shared in [0, 1]")
        if self.max_pixels < 1 or self.min_times < 1:
            raise SegmentError("max_pixels >= 1 and min_times >= 1")


@dataclass(frozen=True)
class SweptLayer:
    """One layer of the window and how much it was swept."""

    offset_m: float
    """n·p of the layer (minus the camera's height above it)."""
    swept: int
    """Sampled pixels seen on it, above it at other times, and never below it."""
    rms_m: float
    """RMS distance from the layer of the heights seen on it."""
    on: int
    """Height samples seen on it (the RMS's count)."""
    shared: dict[float, int] = field(default_factory=dict)
    """For each other layer (by offset), how many of its swept pixels were seen on that one
    as well: what a layer that moves over it (box tops) shows over the belt."""


def median_heights(xyz: F64, ok: B, normal: F64, at: B | None = None) -> tuple[F64, B]:
    """Heights along `normal` (n·p), each the median of its 3×3 neighbourhood (at the pixels
    of `at` only, when given: the others keep their own), and where they are usable (the
    pixel itself usable)."""
    with np.errstate(invalid="ignore"):
        h = np.where(ok, xyz @ normal, INVALID)
    h = stats_kernels.median3_at(h, np.ones(ok.shape, np.bool_) if at is None else at)
    return h, ok & (h > INVALID / 2)


def swept_layers(
    heights: F32, ok: B, sigma: F32, layers: list[float], band: F32, params: SweepParams
) -> list[SweptLayer]:
    """Score each layer (offsets n·p) over (samples, pixels) arrays of heights, usability,
    noise and on-plane band."""
    # the heights are 3×3 medians: their noise is a share of one reading's
    reach = np.maximum(np.float32(3.0 * MEDIAN_SHARES[1]) * sigma, np.float32(params.above_m))
    offsets = np.asarray(layers, np.float64)
    # nearer the camera than anything on a layer can stand: a far surface read near because
    # its phase wrapped round (it flickers there and back with the noise), not a sweep
    tallest = TALLEST_SHARE * np.maximum(-offsets, 0.0)
    swept, on, squares, shared = belt_sweep_kernels.sweep_scores(
        heights, ok, reach, band, offsets, tallest, params.min_times
    )
    out = []
    for k, off in enumerate(layers):
        n = int(on[k])
        others = {float(o): int(shared[k, j]) for j, o in enumerate(layers) if j != k}
        rms = float(np.sqrt(squares[k] / n)) if n else 0.0
        out.append(SweptLayer(float(off), int(swept[k]), rms, n, others))
    return out


def choose_swept(layers: list[SweptLayer], pixels: int, params: SweepParams) -> SweptLayer | None:
    """The belt among scored layers, or None while none was swept enough to say."""
    if not layers:
        return None
    best = max(layers, key=lambda lay: lay.swept)
    if best.swept < params.min_share * pixels:
        return None
    nearer = [
        lay for lay in layers
        if lay.swept >= params.nearer_share * best.swept
        and lay.offset_m > best.offset_m + params.apart_m
        and best.shared.get(lay.offset_m, 0) <= params.max_shared * best.swept
    ]  # fmt: skip
    return max(nearer, key=lambda lay: lay.offset_m) if nearer else best


class SweepWindow:
    """The last seconds of sampled heights, and the verdict on them once there is one."""

    def __init__(self, shape: tuple[int, int], normal: F64, params: SweepParams) -> None:
        self.params = params
        self.normal = normal
        h, w = shape
        step = max(1, int(np.ceil(np.sqrt(h * w / params.max_pixels))))
        self._rows, self._cols = slice(step // 2, None, step), slice(step // 2, None, step)
        self._grid = np.zeros(shape, np.bool_)
        self._grid[self._rows, self._cols] = True
        self.pixels = int(np.count_nonzero(self._grid))
        size = max(1, round(params.window_s / params.every_s))
        self._heights = np.zeros((size, self.pixels), np.float32)
        self._ok = np.zeros((size, self.pixels), np.bool_)
        self._sigma = np.ones((size, self.pixels), np.float32)
        self._samples = 0
        self._t_first: float | None = None
        self._t_sampled: float | None = None
        self._t_judged: float | None = None

    @property
    def filled(self) -> int:
        """Samples in the window."""
        return min(self._samples, len(self._heights))

    def sampling(self, t: float) -> bool:
        """Whether a frame at time `t` (s) is to be sampled."""
        return self._t_sampled is None or t - self._t_sampled >= self.params.every_s * 0.999

    def add(self, xyz: F64, ok: B, sigma: F64, t: float) -> bool:
        """Sample the frame at time `t` (s) if it is time to; True if it was."""
        if not self.sampling(t):
            return False
        self._t_first = t if self._t_first is None else self._t_first
        self._t_sampled = t
        h, usable = median_heights(xyz, ok, self.normal, self._grid)
        i = self._samples % len(self._heights)
        self._heights[i] = h[self._rows, self._cols].ravel()
        self._ok[i] = usable[self._rows, self._cols].ravel()
        self._sigma[i] = sigma[self._rows, self._cols].ravel()
        self._samples += 1
        return True

    def due(self, t: float) -> bool:
        """Whether a verdict is to be tried at time `t`."""
        p = self.params
        if self._t_first is None or t - self._t_first < p.first_s:
            return False
        return self._t_judged is None or t - self._t_judged >= p.judge_every_s * 0.999

    def judged(self, t: float) -> tuple[F32, B, F32]:
        """The window's (samples, pixels) heights, usability and noise, to judge at `t`."""
        self._t_judged = t
        n = self.filled
        return self._heights[:n], self._ok[:n], self._sigma[:n]
