"""Everything the multi-object tracker's behaviour depends on: `TrackerParams`."""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field, fields, replace
from typing import Any, get_type_hints

from tofcut.tracker.background import BackgroundParams
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.motion import MotionParams


@dataclass(frozen=True)
class TrackerParams:
    """Everything the tracker's behaviour depends on, with the defaults it was built with."""

    background: BackgroundParams = field(default_factory=BackgroundParams)
    motion: MotionParams = field(default_factory=MotionParams)
    beta: float = 2.5
    """Weight of the 3D distance penalty (eq. 6), in the track's shape: (D−µ)ᵀΣ⁻¹(D−µ)."""
    object_cost: float = 8.0
    """Cost of any pixel belonging to an object: what the pixel's evidence must outweigh."""
    deadband: float = 1.0
    """Nearness (in noise sigmas) that costs the background nothing: plain sensor noise."""
    background_cap: float = 40.0
    """Most a pixel can cost the background, however far in front it stands."""
    unknown_cost: float = 30.0
    """Background cost where the empty scene is not known yet (a seeded target's pixels)."""
    smoothness: float = 0.8
    """Potts weight λ between neighbours at the same 3D place."""
    smoothness_sigma_m: float = 0.02
    """Neighbours this far apart in 3D are tied by λ·e^(−1/2): eq. (7) in the Potts term."""
    confirm_frames: int = 2
    """Frames a new region must persist before it becomes a track."""
    min_pixels: int = 30
    """Smaller regions are noise, not objects."""
    connect_m: float = 0.03
    """Neighbours farther apart than this in 3D belong to different surfaces."""
    joined_m: float = 0.02
    """A piece beside an object coming into view is more of it where most of the neighbours
    across their contact are this near in 3D: a box's faces meet edge to edge, and another
    box beside it stands a step apart."""
    gate_m: float = 0.08
    """A region seen again within this distance (metres) is the same candidate."""
    max_hidden_s: float = 2.0
    """A hidden track is predicted this long before it ends."""
    still_s: float = 2.0
    """A track seen within `gate_m` of one place this long, and as long as the belt takes to
    carry an object twice that far, is part of the machine (a gantry, a guide): it becomes
    scenery (`roster.still_time`)."""
    whole_fraction: float = 0.85
    """A view within this share of the track's usual size (either way) shows the whole
    object, and is measured; others are partial (occlusion) or tainted."""
    keep_clear_m: float = 0.15
    """Pixels this near a track's surface are not learned as scenery: they are likely parts
    of it the cut missed (a target standing in view from the first frame, its feet)."""
    seed_radius_m: float = 1.0
    """A seeded target is what lies within this distance of its seed, connected to it in
    the image."""
    surface_weight: float = 0.2
    """Weight of the distance from the track's predicted surface, (d/s)², added to the
    shape's: the shape bounds an object's extent, the surface tells two neighbours apart."""
    surface_sigma_m: float = 0.015
    """How far (1σ) an object's surface may stray from where it was predicted, per frame."""
    cloud_points: int = 400
    """Points kept of each track's surface for that distance (a fixed subsample)."""
    split_share: float = 0.2
    """A track whose mask holds two surfaces (apart by `connect_m` steps), the smaller at
    least this share of it or `split_pixels`, holds two objects..."""
    split_pixels: int = 100
    """...(a box coming into view beside a bigger one is a small share of their mask), or
    is an object's top, facing up at a height apart from the rest of the track's top
    (`roster._own_tops`: a low box pressed against a tall one)..."""
    split_frames: int = 3
    """...when it does so this many frames running: the surfaces are then dealt out again."""
    rigid: bool = True
    """Whether the targets are rigid (boxes and parts on a line: a view is measured only when
    it shows the whole object, and touching surfaces a step apart are different objects) or
    may bend (a walking person: every view is measured, and what stands out beside it is a
    limb). A property of the targets, chosen by the user: not inferred from the belt."""

    def __post_init__(self) -> None:
        for name, kind in (("background", BackgroundParams), ("motion", MotionParams)):
            nested = getattr(self, name)
            if not isinstance(nested, kind):
                raise SegmentError(
                    f"TrackerParams.{name} must be a {kind.__name__}, got {nested!r}"
                )
            if floats := _floats(nested):
                object.__setattr__(self, name, replace(nested, **floats))
        for name, number in _floats(self).items():
            object.__setattr__(self, name, number)
        positive = {
            "beta": self.beta,
            "object_cost": self.object_cost,
            "smoothness_sigma_m": self.smoothness_sigma_m,
            "gate_m": self.gate_m,
            "max_hidden_s": self.max_hidden_s,
            "still_s": self.still_s,
            "seed_radius_m": self.seed_radius_m,
            "keep_clear_m": self.keep_clear_m,
            "surface_sigma_m": self.surface_sigma_m,
            "joined_m": self.joined_m,
        }
        for name, value in positive.items():
            if not value > 0:
                raise SegmentError(f"TrackerParams.{name} must be positive, got {value}")
        if self.cloud_points < 1:
            raise SegmentError("cloud_points must be at least 1")
        if self.smoothness < 0 or self.deadband < 0 or self.surface_weight < 0:
            raise SegmentError("smoothness, deadband and surface_weight must not be negative")
        if self.background_cap <= self.object_cost:
            raise SegmentError("background_cap must exceed object_cost, or nothing is ever found")
        if not 0.0 < self.split_share <= 0.5 or self.split_frames < 1 or self.split_pixels < 1:
            raise SegmentError(
                "split_share must be in (0, 0.5], split_frames and split_pixels at least 1"
            )
        if self.confirm_frames < 1 or self.min_pixels < 1:
            raise SegmentError("confirm_frames and min_pixels must be at least 1")
        if not 0.0 < self.whole_fraction <= 1.0:
            raise SegmentError("whole_fraction must be in (0, 1]")

    @property
    def claim_distance(self) -> float:
        """The distance cost (eq. 6, before β) under which a track can win a pixel that stands
        out as far as the background's cost allows: what a track can claim."""
        return (self.background_cap - self.object_cost) / self.beta


def _floats(params: object) -> dict[str, Any]:
    """The float fields of a parameters dataclass given as another kind of number (an int,
    a numpy scalar), as floats: an int would reach the compiled kernels as int64 and compile
    them again, mid-run. SegmentError for a float field that is not a number (or a bool)."""
    hints = get_type_hints(type(params))
    floats: dict[str, Any] = {}
    for f in fields(params):  # type: ignore[arg-type]
        value = getattr(params, f.name)
        if hints[f.name] is not float or type(value) is float:
            continue
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise SegmentError(f"{type(params).__name__}.{f.name} must be a number, got {value!r}")
        try:
            floats[f.name] = float(value)
        except OverflowError:
            raise SegmentError(f"{type(params).__name__}.{f.name} is too large: {value}") from None
    return floats
