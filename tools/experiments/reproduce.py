"""The paper's segmentation experiments on the emulator's scenes, and their report.

Figure 1: intensity only, the 3D distance penalty and the image-plane penalty (β = 0.05 and
0.2) segment the box marked "+". Figures 4 and 5: §4.2 with eq. (7), the paper's Experiment
2, from one seed per object. Each claim is stated twice: on a scene where its premise holds
(paper-fig1-premise: the target and its look-alikes of one intensity, the belt of another,
and apart in 3D; paper-fig4, paper-fig5: the objects stand apart in range from what is
behind them) and on the hard one (paper-fig1: the boxes' front faces in shade, the belt's
intensity between those of their faces, look-alikes touching the target; robot, tools: they
stand or lie on their support).
Beyond the paper: the support energy (`Energy.SUPPORT`) on objects touching their support
(robot, tools, table, belt-parts). Every subject is also cut by OpenCV's grabCut from a box
round it. Every energy uses the library's default `SegmentParams` (β of the image plane
excepted, which is the paper's), the same for every scene; masks are scored by IoU against
the renderer's ground truth, over several noise seeds.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from tofcut._types import F64, I32, U8, B
from tofcut.driver.frames import Frame
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.truth import FrameTruth, ObjectTruth
from tofcut.tools.experiments.grabcut import INSTALL_HINT, grabcut_object, have_opencv
from tofcut.tracker.neighbours import OFFSETS, pair_slices
from tofcut.tracker.paper import energy as en
from tofcut.tracker.paper.energy import energy_of
from tofcut.tracker.paper.graphcut import Problem, solve_cropped
from tofcut.tracker.paper.segment import (
    Energy,
    Model,
    SegmentParams,
    Target,
    build_problem,
    estimate_model,
    segment,
)
from tofcut.tracker.stats import robust_sigma

GOOD_IOU = 0.9
"""A target counts as segmented when its IoU is at least this in every noise seed."""
SUPPORT_IOU = 0.8
"""The support energy counts as segmenting an object on its support at this IoU, in every
seed (issue 19's bar)."""
FAILED_IOU = 0.5
"""A segmentation counts as failed when its mean IoU is below this."""
SWALLOWED = 0.5
"""A look-alike counts as segmented too when this share of its pixels is in the mask."""
LEFT_ALONE = 0.1
"""A target is segmented alone when no other object has more than this share in the mask."""


@dataclass(frozen=True)
class Case:
    """One energy (and its parameters) to run on every subject of a figure."""

    label: str
    energy: Energy | None
    """None: OpenCV's grabCut from a box round the object (`experiments.grabcut`)."""
    params: SegmentParams


GRABCUT = Case("grabCut (box round the object)", None, SegmentParams())
SUPPORT = Case("support energy (beyond the paper)", Energy.SUPPORT, SegmentParams())
EQ7 = "§4.2 range, eq. (7)"
EQ8 = "§4.2 range + intensity, eq. (8)"


@dataclass(frozen=True, eq=False)
class Outcome:
    """One case on one subject: the mask of the first noise seed and scores over all seeds."""

    case: Case
    mask: B
    ious: tuple[float, ...]
    others: tuple[float, ...]
    """Largest share of another object's pixels inside the mask, per seed."""
    energy_found: float
    energy_truth: float
    """Energy of the ground-truth mask in the same frame (first seed); NaN for grabCut."""

    @property
    def mean_iou(self) -> float:
        return float(np.mean(self.ious))


@dataclass(frozen=True, eq=False)
class Subject:
    """One object segmented in one scene, and what every case made of it."""

    name: str
    intensity: F64
    truth: B
    pixel: tuple[int, int]
    target: Target
    """What every energy was given (the support energy's sweep gives the same)."""
    outcomes: tuple[Outcome, ...]

    def outcome(self, label: str) -> Outcome:
        return next(o for o in self.outcomes if o.case.label == label)


@dataclass(frozen=True)
class Verdict:
    claim: str
    supported: bool
    evidence: str
    paper: bool = True
    """A claim of the paper (False: a bar of ours, for the support energy)."""


@dataclass(frozen=True)
class BoundaryStats:
    """The range across an object's true outline against inside it, first seed: what eq. (7)
    can see. D is the 3D distance between axial neighbours, millimetres."""

    name: str
    sigma_s_mm: float
    outline_mm: tuple[float, float, float]
    """10th, 50th and 90th percentile of D over the axial edges crossing the outline."""
    inside_mm: tuple[float, float, float]
    """The same over the axial edges inside the object."""
    outline_below_inside: float
    """Share of the outline's axial edges whose D is below the inside's 90th percentile."""
    outline_weight: float
    """Eq. (7) weight of all the edges crossing the true outline (the true mask's cut)."""
    weight_on_smooth: float
    """Share of that weight on edges whose D is below the inside's 90th percentile."""
    noise_mm: float
    """Range noise on the object: the robust σ of measured − true range (`robust_sigma`)."""
    weight_at_bottom: float
    """Share of the true cut's weight on edges in the lowest tenth of the object's rows
    (where a standing object meets the floor)."""


@dataclass(frozen=True, eq=False)
class FigureResult:
    key: str
    title: str
    scene: str
    subjects: tuple[Subject, ...]
    verdicts: tuple[Verdict, ...]
    premise: bool | None = None
    """True on a scene where the paper's premise holds, False on the hard one, None for
    the control and the scenes beyond the paper."""
    sweep: tuple[tuple[str, str, float], ...] = ()
    """(parameter setting, subject, IoU) rows of a sensitivity sweep, first seed."""
    boundaries: tuple[BoundaryStats, ...] = ()
    """How the range looks across each subject's true outline (the §4.2 figures)."""
    notes: tuple[str, ...] = ()
    """Measured evidence the report prints after the verdicts (Figure 1's ball bound)."""


def iou(a: B, b: B) -> float:
    union = int(np.count_nonzero(a | b))
    return float(np.count_nonzero(a & b)) / union if union else 1.0


def boundary_stats(name: str, frame: Frame, truth: FrameTruth, mask: B) -> BoundaryStats:
    """`BoundaryStats` of a true mask in a frame, with the default σs."""
    model = estimate_model(
        frame.intensity,
        frame.xyz,
        frame.valid,
        Target(pixel=deepest_pixel(mask)),
        Energy.RANGE_SMOOTH,
        SegmentParams(),
    )
    weights = en.range_weights(frame.xyz, frame.valid, model.sigma_s)
    outline, inside, crossing, crossing_d, crossing_row = [], [], [], [], []
    rows = np.nonzero(mask.any(axis=1))[0]
    bottom = rows.max() - 0.1 * (rows.max() - rows.min())
    row_of = np.broadcast_to(np.arange(mask.shape[0])[:, None], mask.shape)
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(mask.shape, k)
        both = frame.valid[sp] & frame.valid[sq]
        d = np.sqrt(((frame.xyz[sp] - frame.xyz[sq]) ** 2).sum(axis=-1)) * 1e3
        cross = mask[sp] != mask[sq]
        crossing.append(weights[k][sp][cross])
        crossing_d.append(d[cross])
        crossing_row.append(row_of[sp][cross])
        if k < 2:
            outline.append(d[cross & both])
            inside.append(d[mask[sp] & mask[sq] & both])
    out, ins = np.concatenate(outline), np.concatenate(inside)
    smooth = float(np.percentile(ins, 90))
    cut, cut_d = np.concatenate(crossing), np.concatenate(crossing_d)
    cut_row = np.concatenate(crossing_row)
    total = float(cut.sum())
    return BoundaryStats(
        name,
        model.sigma_s * 1e3,
        _percentiles(out),
        _percentiles(ins),
        float(np.mean(out < smooth)),
        total,
        float(cut[cut_d < smooth].sum()) / total if total > 0 else 0.0,
        _robust_sigma(np.linalg.norm(frame.xyz, axis=-1) - truth.range, mask & frame.valid),
        float(cut[cut_row >= bottom].sum()) / total if total > 0 else 0.0,
    )


def _robust_sigma(error: F64, where: B) -> float:
    """The robust σ of the error over `where` (`stats.robust_sigma`), millimetres."""
    return robust_sigma(error[where]) * 1e3


def _percentiles(values: F64) -> tuple[float, float, float]:
    p10, p50, p90 = (float(x) for x in np.percentile(values, [10, 50, 90]))
    return p10, p50, p90


def deepest_pixel(mask: B) -> tuple[int, int]:
    """(u, v) of a pixel deepest inside a mask (last to go when eroding), nearest its middle."""
    inner = mask
    while True:
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
    return int(cols[i]), int(rows[i])


@functools.cache
def scene_source(scene: str, seed: int = 0) -> SceneSource:
    """The scene with a noise seed, opened once (opening one casts its background)."""
    return open_scene(scene, seed)


@functools.cache
def frame_at(scene: str, seed: int) -> tuple[Frame, FrameTruth]:
    """The scene's frame at t = 0 as the driver decodes it, with a given noise seed (made
    once; every case reads it, none writes it)."""
    source = scene_source(scene, seed)
    return decode(source, scene_exposure(source, 0.0))


def extent_of(obj: ObjectTruth) -> float:
    """An object's extent for `Target.extent_m`: half the diagonal of its own 3D box (what a
    tracker knows of an object it follows), not of its box along the camera's axes, which
    grows as the object turns."""
    return float(np.linalg.norm(obj.size)) / 2.0


def target_of(truth: FrameTruth, object_id: int) -> Target:
    """What every energy is given: a seed pixel deep inside the object, its centroid and its
    extent (each energy reads what it needs; grabCut gets a box round it instead)."""
    obj = truth.object(object_id)
    x, y, z = (float(c) for c in obj.centroid)
    return Target(
        pixel=deepest_pixel(truth.labels == object_id), point=(x, y, z), extent_m=extent_of(obj)
    )


def run_subject(
    scene: str,
    name: str,
    object_id: int,
    cases: Sequence[Case],
    seeds: Sequence[int],
    target: Target | None = None,
) -> Subject:
    """Every case on one object over the noise seeds (grabCut left out without OpenCV)."""
    frames = [frame_at(scene, s) for s in seeds]
    first, first_truth = frames[0]
    truth_mask = first_truth.labels == object_id
    target = target or target_of(first_truth, object_id)
    outcomes = []
    for case in cases:
        if case.energy is None and not have_opencv():
            continue
        ious, others, masks, energies = [], [], [], []
        for frame, truth in frames:
            mask_t = truth.labels == object_id
            if case.energy is None:
                mask, energy = grabcut_object(frame, mask_t), float("nan")
            else:
                seg = segment(frame, target, case.energy, case.params)
                mask, energy = seg.mask, seg.energy
            ious.append(iou(mask, mask_t))
            others.append(_largest_other_share(mask, truth.labels, object_id))
            masks.append(mask)
            energies.append(energy)
        e_truth = float("nan")
        if case.energy is not None:
            model = estimate_model(
                first.intensity, first.xyz, first.valid, target, case.energy, case.params
            )
            problem = build_problem(
                first.intensity, first.xyz, first.valid, case.energy, case.params, model
            )
            e_truth = energy_of(truth_mask, problem.cost1, problem.cost0, problem.weights)
        outcomes.append(Outcome(case, masks[0], tuple(ious), tuple(others), energies[0], e_truth))
    pixel = target.pixel if target.pixel is not None else deepest_pixel(truth_mask)
    return Subject(name, first.intensity, truth_mask, pixel, target, tuple(outcomes))


def _largest_other_share(mask: B, labels: I32, own: int) -> float:
    counts = np.bincount(labels.ravel(), minlength=int(labels.max()) + 1)
    inside = np.bincount(labels[mask].ravel(), minlength=counts.size)
    shares = [inside[i] / counts[i] for i in range(1, counts.size) if i != own and counts[i]]
    return float(max(shares, default=0.0))


@dataclass(frozen=True)
class BallBound:
    """What eq. (6)'s penalty could do with the best β, whatever its intensity term: the
    best IoU of a mask "valid pixels within r of µd" over r (first seed), and why."""

    iou: float
    radius_m: float
    objects_iou: float
    """The same over the objects' pixels only: as if the intensity term told the support
    from every object perfectly."""
    objects_radius_m: float
    extent_m: float
    """R, the target's extent (`Target.extent_m`)."""
    neutral_m: float
    """R + 2σr: where the derived β makes a pixel of the target's grey level neutral."""
    nearer: tuple[tuple[str, int, float], ...]
    """(name, valid pixels nearer µd than `neutral_m`, the nearest one's distance) of the
    target, then of the background ("belt") and each other object that has any."""
    target_grey: tuple[float, float, float]
    """10th, 50th and 90th percentile of the target's grey levels."""
    support_grey: float
    """Median grey level of the background (belt) pixels nearer µd than `neutral_m`."""


def ball_bound(frame: Frame, truth: FrameTruth, object_id: int, model: Model) -> BallBound:
    """`BallBound` of one object round µd (`model.mu_d`, with the extent and range noise
    eq. (6)'s β was derived from), radii in steps of 2.5 mm."""
    mask = truth.labels == object_id
    own = mask & frame.valid
    d = np.linalg.norm(frame.xyz - np.asarray(model.mu_d), axis=-1)
    neutral_m = model.extent_m + 2.0 * model.range_noise_m
    radii = np.arange(0.02, float(d[own].max()) + 0.0025, 0.0025)
    pools = (frame.valid, frame.valid & (truth.labels > 0))
    (a, ra), (b, rb) = (max((iou(pool & (d < r), mask), float(r)) for r in radii) for pool in pools)
    near = frame.valid & (d < neutral_m)
    names = {o.id: o.name for o in truth.objects}
    ids = [object_id, 0, *(i for i in sorted(names) if i != object_id)]
    nearer = tuple(
        (names.get(i, "belt"), int(np.count_nonzero(hit)), float(d[hit].min()))
        for i in ids
        if (hit := near & (truth.labels == i)).any()
    )
    belt = near & (truth.labels == 0)
    grey = en.grey_levels(frame.intensity, frame.valid)
    g10, g50, g90 = (float(g) for g in np.percentile(grey[own], [10, 50, 90]))
    return BallBound(
        a,
        ra,
        b,
        rb,
        model.extent_m,
        neutral_m,
        nearer,
        (g10, g50, g90),
        float(np.median(grey[belt])) if belt.any() else float("nan"),
    )


def ball_note(bound: BallBound) -> str:
    """The report's account of Figure 1's eq. (6) on one scene: the best ball round µd, what
    lies within the derived β's neutral radius, and whether eq. (5) keeps the belt out."""
    (_, own, _), *others = bound.nearer
    listed = ", ".join(f"{name} {n} (nearest {r * 1e3:.0f} mm)" for name, n, r in others)
    g10, _, g90 = bound.target_grey
    grey = f"{_mm(bound.target_grey)} (10th / 50th / 90th percentile"
    if g10 <= bound.support_grey <= g90:
        belt = (
            "Nor does eq. (5) keep the belt out: it gives the target the grey levels on one side "
            f"of (µt + µb)/2, the target's are {grey}: a bright top face, a dark front face) "
            f"and the belt's within that radius {bound.support_grey:.0f}, so every µt, µb that "
            "give the target both its faces give it the belt too."
        )
    else:
        belt = (
            f"Eq. (5) keeps the belt out here: the target's grey levels are {grey}) and the "
            f"belt's within that radius {bound.support_grey:.0f}; "
        )
        # what stands within the target's own extent, no derived β can keep out
        inside = [
            f"{name} (nearest {r * 1e3:.0f} mm)"
            for name, _, r in others
            if name != "belt" and r < bound.extent_m
        ]
        belt += (
            "what eq. (6) cannot keep out is the look-alikes that reach within the target's "
            f"own extent of µd: {', '.join(inside)}."
            if inside
            else "no look-alike reaches within the target's own extent of µd."
        )
    return (
        "What eq. (6) could reach here with the best β: a mask of the valid pixels within r "
        f"of µd reaches at best IoU {bound.iou:.2f} (r = {bound.radius_m * 1e3:.0f} mm), and "
        f"{bound.objects_iou:.2f} (r = {bound.objects_radius_m * 1e3:.0f} mm) even if the "
        "intensity term kept every pixel of the belt out. With the derived β a pixel of the "
        f"target's grey level is neutral at R + 2σr = {bound.neutral_m * 1e3:.0f} mm from µd "
        f"(R = {bound.extent_m * 1e3:.0f} mm the target's extent, σr the range noise); "
        f"nearer than that lie {own} of the target's valid pixels and, of the rest, {listed}. "
        + belt
    )


BETA_FACTORS = (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)
"""β of eq. (6) as multiples of the one derived from the data, in the sensitivity sweep."""


FIG1_PREMISE = "paper-fig1-premise"
"""Figure 1 where its premise holds: the target and its look-alikes of one intensity, the belt
of another (`paper-fig1` is the hard case: the boxes' front faces in shade, the belt's
intensity between those of their faces)."""

FIG1_NOTES = {
    True: "The scene holds the paper's conditions for Figure 1 and no more: the objects of "
    "`paper-fig1`, occluding each other and so apart in depth, no look-alike within the "
    "target's extent of its centre (6 to 11 cm from it, where in `paper-fig1` two touch it), "
    "seen from 45° so that a box's top and front faces return the same light, on a black "
    "belt, their albedos scaled by their distance² from the camera so that they match "
    "(`sim/scenes/paper-fig1-premise.toml`): intensity alone should take the look-alikes and "
    "not the belt, as the paper's Figure 1(a) shows (the first verdict says how much of its "
    "mask is belt), and the distance from the target's centre should part them, as its "
    "Figure 1(b) shows.",
    False: "The camera looks down at 64°: the boxes' tops face its light and their front "
    "faces meet it at a glancing angle, about half as bright, and the belt is of the "
    "objects' albedo.",
}
"""What each Figure 1 scene encodes (True: the premise scene)."""


def figure1(seeds: Sequence[int], sweep: bool, scene: str) -> FigureResult:
    """Figure 1: the marked box among look-alikes; data-term energies; on `FIG1_PREMISE` (the
    premise) or `paper-fig1` (the hard case)."""
    premise = scene == FIG1_PREMISE
    base = SegmentParams()
    cases = [
        Case("intensity only (eq. 5)", Energy.INTENSITY, base),
        Case("3D distance penalty (eq. 6)", Energy.RANGE_DATA, base),
        Case("image plane, β = 0.05", Energy.IMAGE_PLANE, replace(base, beta_image=0.05)),
        Case("image plane, β = 0.2", Energy.IMAGE_PLANE, replace(base, beta_image=0.2)),
        SUPPORT,
        GRABCUT,
    ]
    info = scene_source(scene).target
    assert info is not None
    frame, truth = frame_at(scene, seeds[0])
    target = replace(target_of(truth, info.id), pixel=info.seed_pixel)
    subject = run_subject(scene, info.name, info.id, cases, seeds, target)
    inten, rng3d, img05, img2 = (subject.outcome(c.label) for c in cases[:4])
    taken = max(int(np.count_nonzero(inten.mask)), 1)
    background = int(np.count_nonzero(inten.mask & (truth.labels == 0))) / taken
    verdicts = (
        Verdict(
            "Intensity only segments the look-alike objects too.",
            float(np.mean(inten.others)) >= SWALLOWED,
            f"mean IoU {inten.mean_iou:.2f}; on average {np.mean(inten.others):.0%} of the "
            f"most-swallowed other object lies inside the mask; {background:.0%} of the mask "
            f"(seed {seeds[0]}) is belt or floor",
        ),
        Verdict(
            "The 3D distance penalty segments the target alone.",
            min(rng3d.ious) >= GOOD_IOU and max(rng3d.others) <= LEFT_ALONE,
            f"IoU {_span(rng3d.ious)}; at most {max(rng3d.others):.0%} of any other object "
            "inside the mask",
        ),
        Verdict(
            "The image-plane penalty fails at both β (0.05 and 0.2).",
            img05.mean_iou < FAILED_IOU and img2.mean_iou < FAILED_IOU,
            f"mean IoU {img05.mean_iou:.2f} at β = 0.05 and {img2.mean_iou:.2f} at β = 0.2",
        ),
    )
    model = estimate_model(frame.intensity, frame.xyz, frame.valid, target, Energy.RANGE_DATA, base)
    bound = ball_bound(frame, truth, info.id, model)
    rows: list[tuple[str, str, float]] = []
    if sweep:
        for beta in (0.05, 0.2, 1.0, 5.0, 20.0):
            seg = segment(frame, target, Energy.IMAGE_PLANE, replace(base, beta_image=beta))
            rows.append((f"image plane β = {beta:g}", info.name, iou(seg.mask, subject.truth)))
        for factor in BETA_FACTORS:
            seg = segment(frame, target, Energy.RANGE_DATA, replace(base, beta_factor=factor))
            rows.append(
                (
                    f"3D penalty β = {factor:g} × the derived ({seg.model.beta_range:.2g})",
                    info.name,
                    iou(seg.mask, subject.truth),
                )
            )
        rows += _support_sweep(frame, (subject,))
    where = (
        "the faces lit alike, apart from it, on a dark belt (the premise)"
        if premise
        else "the front faces in shade, touching it, on a belt of their intensity (the hard case)"
    )
    return FigureResult(
        "fig1" if premise else "fig1-hard",
        f"Figure 1: the box marked + among objects of its intensity, {where}",
        scene,
        (subject,),
        verdicts,
        premise,
        tuple(rows),
        notes=(FIG1_NOTES[premise], ball_note(bound)),
    )


def _seeded_cases(base: SegmentParams) -> list[Case]:
    return [
        Case(EQ7, Energy.RANGE_SMOOTH, base),
        Case(EQ8, Energy.RANGE_INTENSITY_SMOOTH, base),
    ]


SIGMA_FACTORS = (0.25, 0.5, 1.0, 2.0, 4.0)
"""σs as multiples of the median neighbour distance in the sensitivity sweeps."""


def _seeded_figure(
    key: str,
    title: str,
    scene: str,
    claim: str | None,
    objects: Sequence[tuple[str, int]],
    extra: Sequence[Case],
    seeds: Sequence[int],
    sweep: bool,
    premise: bool | None,
    support_bar: bool = True,
) -> FigureResult:
    """§4.2 on each object from its deepest pixel, and the support energy and grabCut; the
    paper's claim checked for eq. (7), its Experiment 2, unless `claim` is None (a control
    or a scene beyond the paper); the support energy's bar unless `support_bar` is False."""
    base = SegmentParams()
    cases = [*_seeded_cases(base), SUPPORT, GRABCUT, *extra]
    subjects = tuple(run_subject(scene, name, oid, cases, seeds) for name, oid in objects)
    verdicts = []
    if claim is not None:
        ok = all(min(s.outcome(EQ7).ious) >= GOOD_IOU for s in subjects)
        evidence = "; ".join(
            f"{s.name}: IoU {_span(s.outcome(EQ7).ious)}, energy of the found mask "
            f"{s.outcome(EQ7).energy_found:.4f} vs the true mask "
            f"{s.outcome(EQ7).energy_truth:.4f}"
            for s in subjects
        )
        verdicts.append(Verdict(f"{claim} (eq. (7))", ok, evidence))
    if support_bar:
        verdicts.append(_support_verdict(subjects))
    frame, truth = frame_at(scene, seeds[0])
    rows: list[tuple[str, str, float]] = []
    if sweep:
        rows = _sigma_sweep(frame, subjects)
        if support_bar:
            rows += _support_sweep(frame, subjects)
    boundaries = tuple(boundary_stats(s.name, frame, truth, s.truth) for s in subjects)
    return FigureResult(
        key, title, scene, subjects, tuple(verdicts), premise, tuple(rows), boundaries
    )


def _support_verdict(subjects: Sequence[Subject]) -> Verdict:
    """Issue 19's bar for the support energy: IoU ≥ SUPPORT_IOU in every seed, and a mean
    IoU over the seeds above grabCut's (when grabCut ran)."""
    ok = True
    parts = []
    for s in subjects:
        ours = s.outcome(SUPPORT.label)
        peer = next((o for o in s.outcomes if o.case.energy is None), None)
        ahead = peer is None or ours.mean_iou > peer.mean_iou
        ok &= min(ours.ious) >= SUPPORT_IOU and ahead
        versus = f" vs grabCut {_span(peer.ious)}" if peer is not None else ""
        parts.append(f"{s.name}: IoU {_span(ours.ious)}{versus}")
    return Verdict(
        f"The support energy segments each object (IoU ≥ {SUPPORT_IOU} in every seed) and "
        "beats grabCut on it (mean IoU over the seeds).",
        ok,
        "; ".join(parts),
        paper=False,
    )


SUPPORT_SWEEP = (
    ("support_weight", (2.0, 4.0, 8.0, 16.0, 32.0)),
    ("support_height", (1.0, 1.5, 2.0, 3.0, 4.0)),
    ("connect_factor", (2.0, 3.0, 4.0, 6.0, 8.0)),
    ("crease_scale", (0.1, 0.15, 0.25, 0.4, 0.6)),
    ("inside_cost", (0.1, 0.2, 0.5, 1.0, 2.0)),
)
"""The support energy's parameters and the values the sensitivity sweep tries (the
defaults in the middle)."""


def _support_sweep(frame: Frame, subjects: Sequence[Subject]) -> list[tuple[str, str, float]]:
    """IoU of the support energy over each of its parameters, the others at their default."""
    rows: list[tuple[str, str, float]] = []
    for name, values in SUPPORT_SWEEP:
        for value in values:
            change: dict[str, Any] = {name: value}
            params = replace(SegmentParams(), **change)
            for s in subjects:
                seg = segment(frame, s.target, Energy.SUPPORT, params)
                rows.append((f"support energy, {name} = {value:g}", s.name, iou(seg.mask, s.truth)))
    return rows


def _sigma_sweep(frame: Frame, subjects: Sequence[Subject]) -> list[tuple[str, str, float]]:
    """IoU of §4.2 over σs, with D read squared (the library's) and as the distance itself
    (there 2σs² = 2 × factor × the median neighbour distance, in metres)."""
    base = SegmentParams()
    rows: list[tuple[str, str, float]] = []
    for factor in SIGMA_FACTORS:
        params = replace(base, sigma_s_factor=factor)
        for case in _seeded_cases(params):
            assert case.energy is not None
            for s in subjects:
                seg = segment(frame, Target(pixel=s.pixel), case.energy, params)
                rows.append(
                    (f"{case.label}, σs = {factor:g} × median step", s.name, iou(seg.mask, s.truth))
                )
    for factor in SIGMA_FACTORS:
        for s in subjects:
            target = Target(pixel=s.pixel)
            model = estimate_model(
                frame.intensity, frame.xyz, frame.valid, target, Energy.RANGE_SMOOTH, base
            )
            problem = build_problem(
                frame.intensity, frame.xyz, frame.valid, Energy.RANGE_SMOOTH, base, model
            )
            sigma = float(np.sqrt(factor * model.sigma_s))
            weights = en.range_weights(frame.xyz, frame.valid, sigma, squared=False)
            labels = solve_cropped(Problem(problem.cost1, problem.cost0, weights), s.pixel).labels
            rows.append(
                (
                    f"eq. (7), D not squared, 2σs² = {2 * factor:g} × median step",
                    s.name,
                    iou(labels, s.truth),
                )
            )
    return rows


FIG4_CLAIM = "§4.2 segments the non-convex robot from one seed"
FIG5_CLAIM = "§4.2 segments each thin tool from one seed"


def figure4(seeds: Sequence[int], sweep: bool, scene: str) -> FigureResult:
    """Figure 4: the non-convex robot arm from one seed (§4.2), on `paper-fig4` (the
    premise: it stands apart in range) or `robot` (it stands on the floor); on `robot`
    §4.1 too, for contrast."""
    info = scene_source(scene).target
    assert info is not None
    premise = scene == "paper-fig4"
    base = SegmentParams()
    extra = (
        []
        if premise
        else [
            Case("intensity only (eq. 5)", Energy.INTENSITY, base),
            Case("3D distance penalty (eq. 6)", Energy.RANGE_DATA, base),
        ]
    )
    where = (
        "on a pedestal, apart in range from the wall behind (the premise)"
        if premise
        else "standing on the floor (the hard case)"
    )
    return _seeded_figure(
        "fig4" if premise else "fig4-hard",
        f"Figure 4: the robot arm, whose intensity matches the background, {where}",
        scene,
        FIG4_CLAIM,
        [(info.name, info.id)],
        extra,
        seeds,
        sweep,
        premise,
        support_bar=not premise,
    )


def figure5(seeds: Sequence[int], sweep: bool, scene: str) -> FigureResult:
    """Figure 5: hammer, tripod and wrench, each from one seed (§4.2), held clear of the
    belt (`paper-fig5`, the premise) or lying on it (`tools`)."""
    premise = scene == "paper-fig5"
    objects = [(o.name, o.id) for o in scene_source(scene).objects]
    where = "held clear of the belt (the premise)" if premise else "on the belt (the hard case)"
    return _seeded_figure(
        "fig5" if premise else "fig5-hard",
        f"Figure 5: tools with thin parts, {where}",
        scene,
        FIG5_CLAIM,
        objects,
        [],
        seeds,
        sweep,
        premise,
        support_bar=not premise,
    )


def control(seeds: Sequence[int], sweep: bool) -> FigureResult:
    """Not a claim of the paper: §4.2 on objects that touch the belt at a point or an edge
    (the ball and the marked box of Figure 1's scene), where the range shows their outline."""
    source = scene_source("paper-fig1")
    objects = [(o.name, o.id) for o in source.objects if o.name in ("ball", "target-box")]
    return _seeded_figure(
        "control",
        "Control (not a claim of the paper): §4.2 on Figure 1's ball and marked box",
        "paper-fig1",
        None,
        objects,
        [],
        seeds,
        sweep,
        None,
        support_bar=False,
    )


def on_support(seeds: Sequence[int], sweep: bool, scene: str) -> FigureResult:
    """Beyond the paper: objects touching their support, every object of `scene`."""
    objects = [(o.name, o.id) for o in scene_source(scene).objects]
    return _seeded_figure(
        scene,
        f"Beyond the paper: objects on their support, scene `{scene}`",
        scene,
        None,
        objects,
        [],
        seeds,
        sweep,
        None,
    )


def _mm(values: tuple[float, float, float]) -> str:
    return " / ".join(f"{v:.0f}" for v in values)


def _span(values: Sequence[float]) -> str:
    if len(values) == 1:
        return f"{values[0]:.2f}"
    return f"{np.mean(values):.2f} (min {min(values):.2f}, max {max(values):.2f})"


# --- pictures and the report ------------------------------------------------------------------


def _grey(values: F64) -> U8:
    lo, hi = np.percentile(values, [1, 99])
    scaled = np.clip((values - lo) / max(float(hi - lo), 1e-12), 0.0, 1.0)
    return np.repeat((scaled * 255).astype(np.uint8)[..., None], 3, axis=-1)


def _mask_picture(mask: B, truth: B) -> U8:
    """White: target found; red: found but not target; blue: target missed; grey: neither."""
    img = np.full((*mask.shape, 3), 40, np.uint8)
    img[mask & truth] = (255, 255, 255)
    img[mask & ~truth] = (230, 50, 50)
    img[~mask & truth] = (60, 90, 230)
    return img


def subject_panel(subject: Subject, scale: int = 2) -> Image.Image:
    """Intensity with the seed, the true mask, then every case's mask, side by side."""
    inten = _grey(subject.intensity)
    u, v = subject.pixel
    inten[max(v - 3, 0) : v + 4, u] = (255, 220, 0)
    inten[v, max(u - 3, 0) : u + 4] = (255, 220, 0)
    tiles = [inten, _mask_picture(subject.truth, subject.truth)]
    captions = [f"{subject.name}: intensity, seed", "ground truth"]
    for o in subject.outcomes:
        tiles.append(_mask_picture(o.mask, subject.truth))
        captions.append(f"{o.case.label}: IoU {o.ious[0]:.2f}")
    h, w = subject.truth.shape
    gap = 6
    strip = np.full((h, len(tiles) * (w + gap) - gap, 3), 255, np.uint8)
    for i, tile in enumerate(tiles):
        strip[:, i * (w + gap) : i * (w + gap) + w] = tile
    big = Image.fromarray(strip).resize(
        (strip.shape[1] * scale, h * scale), Image.Resampling.NEAREST
    )
    canvas = Image.new("RGB", (big.width, big.height + 30), "white")
    canvas.paste(big, (0, 30))
    draw = ImageDraw.Draw(canvas)
    for i, text in enumerate(captions):
        x = i * (w + gap) * scale + 2
        words = text.replace("β", "beta").replace("§", "sec. ").split(": ", 1)
        draw.text((x, 2), words[0][: w * scale // 6], fill="black")
        if len(words) > 1:
            draw.text((x, 15), words[1][: w * scale // 6], fill="black")
    return canvas


SCENE_NOTES = {
    "fig4": "The robot stands on a pedestal of its own whose foot is below the view, so that "
    "all round its outline the range jumps to the wall behind it: the true cut's weight is "
    "small, and eq. (7) from one seed finds the robot.",
    "fig4-hard": "Why: the emulated robot's base stands on the floor, and the floor meets the "
    "wall. Where a surface meets another the range is continuous, so across the contact line "
    "D is that of neighbours on one surface, and eq. (7) (or any weight that is a function of "
    "D alone, whatever σs) ties the base to the floor as strongly as to itself. The table "
    "shows it: the true cut's weight is far above 1 and nearly all of it lies on edges that "
    "look like the robot's own surface, almost all at the bottom of the base. In this scene "
    "the claim cannot hold for §4.2's energy, and the sweep over σs and over the two "
    "readings of D finds no setting that segments it. The support energy ties the floor's "
    "pixels to the background and cuts the robot off at its foot.",
    "fig5": "The tools are held 8 cm clear of the belt, so the range jumps all round each of "
    "them; eq. (7) from one seed finds each, thin legs and handle included (their outline "
    "pixels mix tool and belt, which is most of what is missed).",
    "fig5-hard": "Why: the emulated tools lie flat on the belt. The wrench is 12 mm thick and "
    "the hammer's handle 28 mm across, against a range noise of about 8–11 mm (the table's "
    "robust σ of measured minus true range), so across most of their outline D is no larger "
    "than between neighbours on the tool itself; the tripod stands on three feet, and those "
    "contacts carry its cut. In this scene the claim cannot hold for eq. (7). The support "
    "energy weighs each pixel's height above the belt's fitted plane in units of the noise "
    "on it, which a 12 mm wrench still shows over its whole area.",
    "control": "The control shows §4.2 working where the range does show the outline: the "
    "ball touches the belt at a point, and eq. (7) with the default σs segments it. The marked "
    "box sits on the belt along its bottom edges and needs eq. (8)'s intensity term (or a "
    "smaller σs, see the sweep). The support energy finds the ball; a height above the belt "
    "does not tell two boxes apart, but the box's own faces meet at convex edges and the "
    "boxes that touch it meet it at concave creases, where the support energy, given the "
    "box's extent, cuts them off.",
}
"""What the scene does to §4.2's energy, for each figure with outline statistics."""


def _summary(figures: Sequence[FigureResult], seeds: Sequence[int]) -> list[str]:
    """One row per object: each energy's (and grabCut's) IoU over the seeds."""
    columns = [
        ("eq. (6)", "3D distance penalty (eq. 6)"),
        ("§4.2 eq. (7)", EQ7),
        ("§4.2 eq. (8)", EQ8),
        ("support (ours)", SUPPORT.label),
        ("grabCut", GRABCUT.label),
    ]
    lines = [
        f"IoU per object, mean (min) over noise seeds {', '.join(map(str, seeds))}; — where "
        "the energy was not run on it.",
        "",
        "| scene | object | " + " | ".join(c for c, _ in columns) + " |",
        "| --- | --- |" + " --- |" * len(columns),
    ]
    for fig in figures:
        for sub in fig.subjects:
            cells = []
            for _, label in columns:
                o = next((o for o in sub.outcomes if o.case.label == label), None)
                cells.append("—" if o is None else f"{o.mean_iou:.2f} ({min(o.ious):.2f})")
            lines.append(f"| {fig.scene} | {sub.name} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def write_report(out: Path, figures: Sequence[FigureResult], seeds: Sequence[int]) -> Path:
    """report.md and one PNG per subject in `out`; returns the report's path."""
    out.mkdir(parents=True, exist_ok=True)
    base = SegmentParams()
    lines = [
        "# Reproducing Arif et al., §4 on the emulator's scenes",
        "",
        "Written by `tofcut reproduce`. Frames are the scenes at t = 0 rendered by the emulator "
        f"and decoded by the driver, with noise seeds {', '.join(map(str, seeds))}; panels and "
        f"single numbers are seed {seeds[0]}. Every energy runs with the library's default "
        "parameters, the same for every scene (the image-plane β are the paper's):",
        "",
        f"`{base}`",
        "",
        "µt, µb, β, σs, σi and the support plane are estimated from each frame (see "
        "`tofcut.tracker.paper.segment`); every energy is given a seed pixel deep inside the "
        "object, its true centroid and its extent (half the diagonal of its own true 3D box, "
        "the same however it is turned), as a tracker would, and reads what it needs. GrabCut "
        "(OpenCV, 5 iterations) is given a box round the object grown by a quarter on every "
        "side, on an image of intensity, range and amplitude. In the panels white is target "
        "found, red is found but not target, blue is target missed.",
        "",
        f"What the verdicts mean: *segmented* is IoU ≥ {GOOD_IOU} in every seed; *fails* is a "
        f"mean IoU below {FAILED_IOU}; a look-alike is *segmented too* when on average at least "
        f"{SWALLOWED:.0%} of its pixels are in the mask; the target is *alone* when no other "
        f"object has more than {LEFT_ALONE:.0%} of its pixels in the mask. Each claim of "
        "Figures 1, 4 and 5 is stated on a scene where its premise holds (Figure 1: the target "
        "and its look-alikes of one intensity, the belt of another, and apart in 3D; Figures 4 "
        "and 5: the objects stand apart in range from what is behind them) and on the hard one "
        "(Figure 1: the boxes' front faces in shade, the belt's intensity between those of "
        "their faces, look-alikes touching the target; Figures 4 and 5: the objects stand or "
        "lie on their support).",
        "",
    ]
    for premise, where in ((True, "where their premise holds"), (False, "on the hard scenes")):
        claims = [v for f in figures if f.premise is premise for v in f.verdicts if v.paper]
        held = sum(v.supported for v in claims)
        lines.append(f"**{held} of {len(claims)} of the paper's claims hold {where}.**")
        lines.append("")
    ours = [v for f in figures for v in f.verdicts if not v.paper]
    held = sum(v.supported for v in ours)
    lines += [
        f"**The support energy (beyond the paper) meets its bar on {held} of {len(ours)} scenes.**",
        "",
        "## Every object, every energy",
        "",
        *_summary(figures, seeds),
    ]
    for fig in figures:
        lines += [f"## {fig.title}", "", f"Scene `{fig.scene}`.", ""]
        for v in fig.verdicts:
            mark = "supported" if v.supported else "**not supported**"
            lines += [f"- *{v.claim}* — {mark}: {v.evidence}."]
        for note in fig.notes:
            lines += ["", note]
        seeded = [
            o
            for sub in fig.subjects
            for o in sub.outcomes
            if o.case.energy is not None and o.case.energy.seeded
        ]
        missed = [o for o in seeded if o.ious[0] < GOOD_IOU]
        if missed:
            worse = sum(o.energy_truth > o.energy_found for o in missed)
            lines += [
                "",
                f"Of the {len(missed)} §4.2 runs here that miss the object (IoU below "
                f"{GOOD_IOU} in seed {seeds[0]}), in {worse} the ground-truth mask has a higher "
                "energy than the mask found: there the minimum of the energy is not the object, "
                "and no better minimiser could change the result (the found masks are exact "
                "minima: the fast cut equals the full-frame reference).",
            ]
        if fig.boundaries:
            lines += [
                "",
                "What eq. (7) can see: the 3D distance D between axial neighbours across the "
                "true outline and inside the object (mm; 10th / 50th / 90th percentile), the "
                "share of the outline's edges whose D is below the inside's 90th percentile "
                "(edges that look like the object's own surface), the eq. (7) weight of the "
                "true mask's cut with the default σs (a minimum's cut never weighs more than 1, "
                "the seed's link), and the share of that weight on such smooth edges:",
                "",
                "| object | range noise | σs | D across the outline | D inside | outline edges "
                "that look inside | weight of the true cut | of it on those edges | of it in "
                "the lowest tenth of the object's rows |",
                "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
            ]
            for b in fig.boundaries:
                lines.append(
                    f"| {b.name} | {b.noise_mm:.1f} mm | {b.sigma_s_mm:.1f} mm | "
                    f"{_mm(b.outline_mm)} | {_mm(b.inside_mm)} | {b.outline_below_inside:.0%} | "
                    f"{b.outline_weight:.2f} | {b.weight_on_smooth:.0%} | "
                    f"{b.weight_at_bottom:.0%} |"
                )
            if fig.key in SCENE_NOTES:
                lines += ["", SCENE_NOTES[fig.key]]
        lines += ["", "| object | energy | IoU (seed " + str(seeds[0]) + ") | IoU over seeds |"]
        lines += ["| --- | --- | --- | --- |"]
        for s in fig.subjects:
            for o in s.outcomes:
                lines.append(f"| {s.name} | {o.case.label} | {o.ious[0]:.3f} | {_span(o.ious)} |")
        lines.append("")
        for s in fig.subjects:
            name = f"{fig.key}-{s.name}.png"
            subject_panel(s).save(out / name)
            lines += [f"![{fig.key} {s.name}]({name})", ""]
        if fig.sweep:
            lines += [
                "Sensitivity (seed " + str(seeds[0]) + "; not used for the verdicts):",
                "",
                "| setting | object | IoU |",
                "| --- | --- | --- |",
            ]
            lines += [f"| {p} | {n} | {x:.3f} |" for p, n, x in fig.sweep]
            lines.append("")
    if not have_opencv():
        lines += [f"GrabCut was not run: {INSTALL_HINT}.", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


SUPPORT_SCENES = ("table", "belt-parts")
"""Scenes of objects on their support, beyond the paper (with robot and tools)."""


def run_figures(seeds: Sequence[int], sweep: bool) -> list[FigureResult]:
    """Figures 1, 4 and 5 on their premise scenes and on the hard ones; the §4.2 control;
    the support energy on more objects on their support."""
    return [
        figure1(seeds, sweep, FIG1_PREMISE),
        figure1(seeds, sweep, "paper-fig1"),
        figure4(seeds, sweep, "paper-fig4"),
        figure4(seeds, sweep, "robot"),
        figure5(seeds, sweep, "paper-fig5"),
        figure5(seeds, sweep, "tools"),
        control(seeds, sweep),
        *(on_support(seeds, sweep, scene) for scene in SUPPORT_SCENES),
    ]
