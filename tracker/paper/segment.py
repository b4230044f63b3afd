"""Segmenting one target in one frame: `segment(frame, target, energy, params)`.

    from tofcut.tracker.paper.segment import Energy, Target, segment
    seg = segment(frame, Target(pixel=(88, 60)), Energy.RANGE_SMOOTH)
    seg.mask, seg.energy, seg.seconds

The energies are those of Arif et al. §4 (see `tofcut.tracker.paper.energy` for the formulas and
units); the minimum is found by graph cut, by default with the fast exact solvers of
`tofcut.tracker.paper.graphcut`, or with the full-frame reference graph on request.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass

import numpy as np

from tofcut._types import F64, B
from tofcut.driver.frames import Frame
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.paper import energy as en
from tofcut.tracker.paper import support as sp
from tofcut.tracker.paper.graphcut import Problem, solve_cropped, solve_reduced, solve_reference
from tofcut.tracker.paper.support import Plane

NOISE_WINDOW = 4
"""Half-size of the window round the target's pixel whose range noise σr is measured."""


class Energy(enum.Enum):
    """Which energy of the paper to minimise."""

    INTENSITY = "intensity"
    """Eq. (5) with Potts smoothness: intensity only, the paper's baseline."""
    RANGE_DATA = "range-data"
    """Eq. (6): eq. (5) plus β‖D_p − µd‖² on the target label (3D distance from the camera)."""
    IMAGE_PLANE = "image-plane"
    """Malcolm et al.: eq. (5) plus β‖x_p − µx‖² on the target label, in image pixels."""
    RANGE_SMOOTH = "range-smooth"
    """§4.2 with eq. (7): one seed, 1/n to the background, range-weighted 8-neighbour edges."""
    RANGE_INTENSITY_SMOOTH = "range-intensity-smooth"
    """§4.2 with eq. (8): as RANGE_SMOOTH, edges weighted by range and intensity."""
    SUPPORT = "support"
    """Beyond the paper: eq. (8)'s edges and a unary cost from the height above the plane
    the seed stands on (`tofcut.tracker.paper.support`), for objects touching a support;
    given the target's extent, objects touching the target are cut off at concave creases."""

    @property
    def seeded(self) -> bool:
        """True for the §4.2 energies (a seed pixel, no data term)."""
        return self in (Energy.RANGE_SMOOTH, Energy.RANGE_INTENSITY_SMOOTH)

    @property
    def from_seed(self) -> bool:
        """True for the energies grown from a seed pixel: §4.2's and SUPPORT."""
        return self.seeded or self is Energy.SUPPORT


@dataclass(frozen=True)
class Target:
    """What to segment: a seed pixel inside it, its expected 3D position, or both.

    The data-term energies need µd (RANGE_DATA) or the image centre µx (IMAGE_PLANE); a
    missing one is taken from the other: µd as the 3D point at the pixel, µx as the pixel
    whose ray passes closest to the point. The §4.2 energies need a seed pixel, likewise.
    """

    pixel: tuple[int, int] | None = None
    """(u, v): column and row of a pixel on the target."""
    point: tuple[float, float, float] | None = None
    """Expected 3D position (camera frame, metres), e.g. the centroid predicted by a tracker."""
    extent_m: float | None = None
    """Expected extent: the radius round `point` the target fills (half its size), metres;
    it scales eq. (6)'s β. None: `SegmentParams.default_extent_m`."""

    def __post_init__(self) -> None:
        if self.pixel is None and self.point is None:
            raise SegmentError("a target needs a seed pixel (u, v), a 3D point, or both")
        if self.pixel is not None and (
            len(self.pixel) != 2 or not all(isinstance(c, int | np.integer) for c in self.pixel)
        ):
            raise SegmentError(f"a target's pixel is two integers (u, v), not {self.pixel!r}")
        if self.point is not None and (
            len(self.point) != 3 or not all(math.isfinite(float(c)) for c in self.point)
        ):
            raise SegmentError(f"a target's point is three finite numbers, not {self.point!r}")
        if self.extent_m is not None and not (math.isfinite(self.extent_m) and self.extent_m > 0.0):
            raise SegmentError(f"a target's extent is a finite number > 0, not {self.extent_m!r}")


@dataclass(frozen=True)
class SegmentParams:
    """Parameters of the energies; None means "estimate from the frame and the target".

    Intensities are in the frame's own units (`Frame.intensity`); energies see them as grey
    levels 255·I/I_ref (see `tofcut.tracker.paper.energy`), which is the unit of the weights below.
    The defaults were set once for the emulator's scenes at 176×144 and are used unchanged for
    every scene.
    """

    smoothness: float = 200.0
    """Potts weight λ per axial neighbour pair (λ/√2 diagonally), grey levels²."""
    beta_range: float | None = None
    """β of eq. (6), grey levels² per m²; default: `beta_factor` × (µt − µb)² / (R + 2σr)²,
    R the target's extent and σr the range noise round it, so that a pixel of the target's
    intensity at the edge of its extent (plus twice the noise) is neutral: β follows the
    object's size, the noise and the contrast the intensity term pays with."""
    beta_factor: float = 1.0
    """The multiple of the derived β used when `beta_range` is None (the sensitivity sweep's)."""
    beta_image: float = 0.05
    """β of the image-plane penalty, grey levels² per pixel² (the paper shows 0.05 and 0.2)."""
    mu_target: float | None = None
    """µt; default: the median valid intensity in the prior window around the target's pixel;
    for a target that gives its extent, the target's own median where the window's is not
    typical of it (`energy.target_intensity`: a box's faces, nearer and farther from the
    light, differ)."""
    mu_background: float | None = None
    """µb; default: the median valid intensity farther than the target's extent (plus twice
    the range noise) from µd."""
    sigma_s: float | None = None
    """σs of eqs. (7) and (8), metres; default: `sigma_s_factor` × the median distance between
    valid neighbours' 3D points."""
    sigma_i: float | None = None
    """σi of eq. (8), frame intensity units; default: `sigma_i_factor` × the median intensity
    step between valid neighbours."""
    sigma_s_factor: float = 1.0
    sigma_i_factor: float = 3.0
    prior_window: int = 2
    """Half-size of the window around the target's pixel that µt and µd are taken from."""
    default_extent_m: float = 0.2
    """The extent assumed for a target that gives none (`Target.extent_m`), metres: half the
    diagonal of a box of about 23 cm."""
    support_weight: float = 8.0
    """SUPPORT: the factor of eq. (8)'s edge weights, in the unit of the height costs."""
    support_cap: float = 8.0
    """SUPPORT: the largest height cost of a pixel (a few wild ranges cannot force a label)."""
    support_height: float = 2.0
    """SUPPORT: the largest target height z_t, in σ of the support's range noise (a pixel
    z_t/2 above the support is neutral)."""
    connect_factor: float = 4.0
    """SUPPORT: neighbours closer than this × σs in 3D join the seed's part of the mask."""
    crease_scale: float = 0.25
    """SUPPORT with a target's extent: the concavity τ at which an edge of the seed's part
    weighs e^−½ of a flat one (`tofcut.tracker.paper.support.apart_at_creases`)."""
    inside_cost: float = 0.5
    """SUPPORT with a target's extent: the cost of cutting off a pixel of the seed's part
    within the extent of the target's centre (one beyond twice the extent costs 1 to keep)."""

    def __post_init__(self) -> None:
        for name in (
            "smoothness",
            "beta_image",
            "default_extent_m",
            "support_weight",
            "support_cap",
            "support_height",
            "connect_factor",
            "inside_cost",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise SegmentError(f"{name} must be a finite number ≥ 0, not {value!r}")
        if self.beta_range is not None and not (
            math.isfinite(self.beta_range) and self.beta_range >= 0.0
        ):
            raise SegmentError(f"beta_range must be a finite number ≥ 0, not {self.beta_range!r}")
        names = ("sigma_s", "sigma_i", "sigma_s_factor", "sigma_i_factor", "beta_factor")
        for name in (*names, "crease_scale"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0.0):
                raise SegmentError(f"{name} must be a finite number > 0, not {value!r}")
        if self.prior_window < 0:
            raise SegmentError(f"prior_window must be ≥ 0, not {self.prior_window}")


@dataclass(frozen=True)
class Model:
    """The quantities an energy was built from, after estimation (grey levels are 255·I/I_ref)."""

    intensity_ref: float
    """I_ref: the frame intensity shown as grey level 255."""
    pixel: tuple[int, int]
    """(u, v): the seed (§4.2) or image centre µx (IMAGE_PLANE)."""
    mu_d: tuple[float, float, float]
    mu_target: float
    """µt, grey levels."""
    mu_background: float
    """µb, grey levels."""
    sigma_s: float
    """metres."""
    sigma_i: float
    """grey levels."""
    beta_range: float = 0.0
    """β of eq. (6), grey levels² per m²."""
    extent_m: float = 0.0
    """The target's extent R, metres."""
    range_noise_m: float = 0.0
    """σr: the range noise round the target's pixel, metres."""
    supports: tuple[Plane, ...] = ()
    """SUPPORT: the planes the seed stands in front of (none: every pixel is off them)."""
    support_height: float = 0.0
    """SUPPORT: the target height z_t, in σ of the support's noise."""


@dataclass(frozen=True, eq=False)
class Segmentation:
    """The minimum found: the target's mask, its energy, and how long it took."""

    mask: B
    """(H, W), True on the target."""
    energy: float
    """E of the mask: the minimum of the energy (SUPPORT: of the minimum's part kept)."""
    seconds: float
    """Wall time of `segment`: estimation, building the energy, and the cut."""
    kind: Energy
    model: Model
    graph_nodes: int
    """Nodes of the graph cut(s): pixels, or groups of merged pixels for §4.2 (H·W for the
    reference solver)."""


def segment(
    frame: Frame,
    target: Target,
    energy: Energy,
    params: SegmentParams | None = None,
    *,
    reference: bool = False,
) -> Segmentation:
    """Segment one target in one frame by minimising `energy` (full-frame graph if
    `reference`, else the fast exact solver)."""
    return segment_arrays(
        frame.intensity,
        frame.xyz,
        frame.valid,
        target,
        energy,
        params,
        reference=reference,
        amplitude=frame.amplitude,
    )


def segment_arrays(
    intensity: F64,
    xyz: F64,
    valid: B,
    target: Target,
    energy: Energy,
    params: SegmentParams | None = None,
    *,
    reference: bool = False,
    amplitude: F64 | None = None,
) -> Segmentation:
    """`segment` on bare arrays: intensity (H, W), camera points (H, W, 3), valid (H, W);
    SUPPORT reads the amplitude (H, W) on the outline (None: the intensity stands in)."""
    start = time.perf_counter()
    params = params or SegmentParams()
    if not isinstance(energy, Energy):
        raise SegmentError(f"energy must be an Energy, not {energy!r}")
    _check_arrays(intensity, xyz, valid)
    if amplitude is not None and amplitude.shape != intensity.shape:
        raise SegmentError(
            f"amplitude {amplitude.shape} does not match the intensity {intensity.shape}"
        )
    model = estimate_model(intensity, xyz, valid, target, energy, params)
    problem = build_problem(intensity, xyz, valid, energy, params, model)
    if reference:
        solution = solve_reference(problem)
    elif energy.seeded:
        solution = solve_cropped(problem, model.pixel)
    else:
        solution = solve_reduced(problem)
    labels = solution.labels
    if energy is Energy.SUPPORT:
        reach = params.connect_factor * model.sigma_s
        part = sp.reached(labels, xyz, valid, model.pixel, reach)
        if target.extent_m is not None:
            part = sp.apart_at_creases(
                part,
                xyz,
                model.pixel,
                np.asarray(model.mu_d),
                model.extent_m + 2.0 * model.range_noise_m,
                reach,
                params.crease_scale,
                params.support_weight,
                params.inside_cost,
            )
        strength = intensity if amplitude is None else amplitude
        labels = sp.with_mixed_outline(part, labels, xyz, valid, strength)
    value = en.energy_of(labels, problem.cost1, problem.cost0, problem.weights)
    return Segmentation(
        labels,
        value,
        time.perf_counter() - start,
        energy,
        model,
        solution.graph_nodes,
    )


def _check_arrays(intensity: F64, xyz: F64, valid: B) -> None:
    if intensity.ndim != 2 or intensity.size == 0:
        raise SegmentError(f"intensity must be a non-empty (H, W) array, not {intensity.shape}")
    if valid.shape != intensity.shape or xyz.shape != (*intensity.shape, 3):
        raise SegmentError(
            f"intensity {intensity.shape}, valid {valid.shape} and xyz {xyz.shape} do not "
            "match (H, W), (H, W), (H, W, 3)"
        )
    if not valid.any():
        raise SegmentError("the frame has no valid pixel")


def estimate_model(
    intensity: F64,
    xyz: F64,
    valid: B,
    target: Target,
    energy: Energy,
    params: SegmentParams,
) -> Model:
    """Fill in µx or the seed, µd, µt, µb, σs and σi from the frame and the target."""
    h, w = valid.shape
    ref = en.intensity_reference(intensity, valid)
    scale = 255.0 / ref
    grey = intensity * scale
    window = params.prior_window
    if target.pixel is not None:
        u, v = int(target.pixel[0]), int(target.pixel[1])
        if not (0 <= u < w and 0 <= v < h):
            raise SegmentError(
                f"the target's pixel (u, v) = ({u}, {v}) is outside the {w}×{h} frame"
            )
        if energy.from_seed and not valid[v, u]:
            raise SegmentError(f"the seed pixel ({u}, {v}) is invalid (saturated or too dark)")
    else:
        assert target.point is not None
        u, v = en.nearest_pixel(xyz, valid, np.asarray(target.point, dtype=np.float64))
    if target.point is not None:
        mu_d = np.asarray(target.point, dtype=np.float64)
    else:
        near = en.window_median_point(xyz, valid, (u, v), window)
        if near is None:
            raise SegmentError(f"no valid pixel near the target's pixel ({u}, {v})")
        mu_d = near
    if params.mu_target is not None:
        mu_t = params.mu_target * scale
    else:
        near_t = en.window_median(grey, valid, (u, v), window)
        if near_t is None:
            raise SegmentError(f"no valid pixel near the target's pixel ({u}, {v})")
        mu_t = near_t
    extent = target.extent_m if target.extent_m is not None else params.default_extent_m
    noise = en.window_range_noise(xyz, valid, (u, v), NOISE_WINDOW)
    margin = extent + 2.0 * noise
    if params.mu_background is not None:
        mu_b = params.mu_background * scale
    else:
        mu_b = en.background_intensity(grey, valid, xyz, mu_d, margin)
    if params.mu_target is None and target.extent_m is not None:
        # the target's own intensity, where its extent says which pixels are its
        mu_t = en.target_intensity(grey, valid, xyz, mu_d, extent, mu_t, mu_b)
    if params.beta_range is not None:
        beta = params.beta_range
    else:
        beta = params.beta_factor * (mu_t - mu_b) ** 2 / margin**2
    sigma_s = params.sigma_s
    sigma_i = params.sigma_i * scale if params.sigma_i is not None else None
    if energy.from_seed and sigma_s is None:
        sigma_s = params.sigma_s_factor * en.neighbour_distance(xyz, valid)
    if energy in (Energy.RANGE_INTENSITY_SMOOTH, Energy.SUPPORT) and sigma_i is None:
        sigma_i = params.sigma_i_factor * en.neighbour_step(grey, valid)
    supports: tuple[Plane, ...] = ()
    z_target = 0.0
    if energy is Energy.SUPPORT:
        planes = sp.find_planes(xyz, valid, en.neighbour_distance(xyz, valid))
        supports = sp.supports_of(planes, xyz[v, u])
        if supports:
            z = sp.heights(xyz, supports)
            near_z = en.window_median(z, valid, (u, v), window)
            z_target = min(near_z if near_z is not None else 0.0, params.support_height)
    return Model(
        ref,
        (u, v),
        (float(mu_d[0]), float(mu_d[1]), float(mu_d[2])),
        float(mu_t),
        float(mu_b),
        max(float(sigma_s or 0.0), 1e-9),
        max(float(sigma_i or 0.0), 1e-9),
        float(beta),
        float(extent),
        float(noise),
        supports,
        z_target,
    )


def build_problem(
    intensity: F64,
    xyz: F64,
    valid: B,
    energy: Energy,
    params: SegmentParams,
    model: Model,
) -> Problem:
    """The unary costs and edge weights of `energy` for this frame."""
    grey = intensity * (255.0 / model.intensity_ref)
    if energy is Energy.SUPPORT:
        z = sp.heights(xyz, model.supports)
        cost1, cost0 = sp.support_costs(
            z, valid, model.pixel, model.support_height, params.support_cap
        )
        weights = en.range_weights(xyz, valid, model.sigma_s, grey, model.sigma_i)
        return Problem(cost1, cost0, weights * params.support_weight)
    if energy.seeded:
        cost1, cost0 = en.seed_costs(valid.shape, model.pixel)
        if energy is Energy.RANGE_SMOOTH:
            weights = en.range_weights(xyz, valid, model.sigma_s)
        else:
            weights = en.range_weights(xyz, valid, model.sigma_s, grey, model.sigma_i)
        return Problem(cost1, cost0, weights)
    cost1, cost0 = en.intensity_costs(grey, valid, model.mu_target, model.mu_background)
    if energy is Energy.RANGE_DATA:
        cost1 = cost1 + en.range_penalty(xyz, valid, np.array(model.mu_d), model.beta_range)
    elif energy is Energy.IMAGE_PLANE:
        cost1 = cost1 + en.image_penalty(valid, model.pixel, params.beta_image)
    weights = en.potts_weights(valid.shape, params.smoothness)
    return Problem(cost1, cost0, weights, en.potts_bound(params.smoothness))
