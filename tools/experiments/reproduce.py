"""The paper's segmentation experiments on the emulator's scenes, and their report.

Figure 1 (paper-fig1): intensity only, the 3D distance penalty and the image-plane penalty
(β = 0.05 and 0.2) segment the box marked "+". Figures 4 and 5 (robot, tools): §4.2 with
eq. (7) and eq. (8) from one seed per object. Every energy uses the library's default
`SegmentParams` (β of the image plane excepted, which is the paper's), the same for every
scene; masks are scored by IoU against the renderer's ground truth, over several noise seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from tofcut._types import F64, I32, U8, B
from tofcut.driver.frames import Frame
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.sim.truth import FrameTruth
from tofcut.tracker.neighbours import OFFSETS, pair_slices
from tofcut.tracker.paper import energy as en
from tofcut.tracker.paper.energy import energy_of
from tofcut.tracker.paper.graphcut import Problem, solve_cropped
from tofcut.tracker.paper.segment import (
    Energy,
    SegmentParams,
    Target,
    build_problem,
    estimate_model,
    segment,
)
from tofcut.tracker.stats import robust_sigma

GOOD_IOU = 0.7
"""A target counts as segmented when its IoU is at least this in every noise seed."""
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
    energy: Energy
    params: SegmentParams


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
    """Energy of the ground-truth mask in the same frame (first seed)."""

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
    outcomes: tuple[Outcome, ...]

    def outcome(self, label: str) -> Outcome:
        return next(o for o in self.outcomes if o.case.label == label)


@dataclass(frozen=True)
class Verdict:
    claim: str
    supported: bool
    evidence: str


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
    sweep: tuple[tuple[str, str, float], ...] = ()
    """(parameter setting, subject, IoU) rows of a sensitivity sweep, first seed."""
    boundaries: tuple[BoundaryStats, ...] = ()
    """How the range looks across each subject's true outline (the §4.2 figures)."""


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


def frame_at(scene: str, seed: int) -> tuple[Frame, FrameTruth]:
    """The scene's frame at t = 0 as the driver decodes it, with a given noise seed."""
    source = open_scene(scene, seed)
    return decode(source, scene_exposure(source, 0.0))


TargetOf = Callable[[FrameTruth, B], Target]


def run_subject(
    scene: str,
    name: str,
    object_id: int,
    target_of: TargetOf,
    cases: Sequence[Case],
    seeds: Sequence[int],
) -> Subject:
    """Every case on one object over the noise seeds."""
    frames = [frame_at(scene, s) for s in seeds]
    first, first_truth = frames[0]
    truth_mask = first_truth.labels == object_id
    target = target_of(first_truth, truth_mask)
    outcomes = []
    for case in cases:
        ious, others, masks, energies = [], [], [], []
        for frame, truth in frames:
            mask_t = truth.labels == object_id
            seg = segment(frame, target, case.energy, case.params)
            ious.append(iou(seg.mask, mask_t))
            others.append(_largest_other_share(seg.mask, truth.labels, object_id))
            masks.append(seg.mask)
            energies.append(seg.energy)
        model = estimate_model(
            first.intensity, first.xyz, first.valid, target, case.energy, case.params
        )
        problem = build_problem(
            first.intensity, first.xyz, first.valid, case.energy, case.params, model
        )
        e_truth = energy_of(truth_mask, problem.cost1, problem.cost0, problem.weights)
        outcomes.append(Outcome(case, masks[0], tuple(ious), tuple(others), energies[0], e_truth))
    pixel = target.pixel if target.pixel is not None else deepest_pixel(truth_mask)
    return Subject(name, first.intensity, truth_mask, pixel, tuple(outcomes))


def _largest_other_share(mask: B, labels: I32, own: int) -> float:
    counts = np.bincount(labels.ravel(), minlength=int(labels.max()) + 1)
    inside = np.bincount(labels[mask].ravel(), minlength=counts.size)
    shares = [inside[i] / counts[i] for i in range(1, counts.size) if i != own and counts[i]]
    return float(max(shares, default=0.0))


def figure1(seeds: Sequence[int], sweep: bool) -> FigureResult:
    """Figure 1: the marked box among look-alikes; data-term energies."""
    base = SegmentParams()
    cases = [
        Case("intensity only (eq. 5)", Energy.INTENSITY, base),
        Case("3D distance penalty (eq. 6)", Energy.RANGE_DATA, base),
        Case("image plane, β = 0.05", Energy.IMAGE_PLANE, replace(base, beta_image=0.05)),
        Case("image plane, β = 0.2", Energy.IMAGE_PLANE, replace(base, beta_image=0.2)),
    ]
    source = open_scene("paper-fig1")
    info = source.target
    assert info is not None

    def target_of(truth: FrameTruth, mask: B) -> Target:
        x, y, z = (float(c) for c in info.centroid)
        return Target(pixel=info.seed_pixel, point=(x, y, z))

    subject = run_subject("paper-fig1", info.name, info.id, target_of, cases, seeds)
    inten, rng3d, img05, img2 = (subject.outcome(c.label) for c in cases)
    verdicts = (
        Verdict(
            "Intensity only segments the look-alike objects too.",
            float(np.mean(inten.others)) >= SWALLOWED,
            f"mean IoU {inten.mean_iou:.2f}; on average {np.mean(inten.others):.0%} of the "
            "most-swallowed other object lies inside the mask",
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
    rows: list[tuple[str, str, float]] = []
    if sweep:
        frame, truth = frame_at("paper-fig1", seeds[0])
        target = target_of(truth, subject.truth)
        for beta in (0.05, 0.2, 1.0, 5.0, 20.0):
            seg = segment(frame, target, Energy.IMAGE_PLANE, replace(base, beta_image=beta))
            rows.append((f"image plane β = {beta:g}", info.name, iou(seg.mask, subject.truth)))
        for beta in (5e4, 1e5, 2e5, 4e5, 8e5):
            seg = segment(frame, target, Energy.RANGE_DATA, replace(base, beta_range=beta))
            rows.append((f"3D penalty β = {beta:.0e}", info.name, iou(seg.mask, subject.truth)))
    return FigureResult(
        "fig1",
        "Figure 1: the box marked + among objects of its intensity",
        "paper-fig1",
        (subject,),
        verdicts,
        tuple(rows),
    )


def _seeded_cases(base: SegmentParams) -> list[Case]:
    return [
        Case("§4.2 range, eq. (7)", Energy.RANGE_SMOOTH, base),
        Case("§4.2 range + intensity, eq. (8)", Energy.RANGE_INTENSITY_SMOOTH, base),
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
) -> FigureResult:
    """§4.2 on each object from its deepest pixel; a verdict per energy unless `claim` is
    None (a control, not a claim of the paper)."""
    base = SegmentParams()
    cases = _seeded_cases(base)

    def target_of(truth: FrameTruth, mask: B) -> Target:
        return Target(pixel=deepest_pixel(mask))

    subjects = tuple(
        run_subject(scene, name, oid, target_of, [*cases, *extra], seeds) for name, oid in objects
    )
    verdicts = []
    for case in cases if claim is not None else []:
        ok = all(min(s.outcome(case.label).ious) >= GOOD_IOU for s in subjects)
        evidence = "; ".join(
            f"{s.name}: IoU {_span(s.outcome(case.label).ious)}, energy of the found mask "
            f"{s.outcome(case.label).energy_found:.4f} vs the true mask "
            f"{s.outcome(case.label).energy_truth:.4f}"
            for s in subjects
        )
        verdicts.append(Verdict(f"{claim} ({case.label})", ok, evidence))
    frame, truth = frame_at(scene, seeds[0])
    rows: list[tuple[str, str, float]] = []
    if sweep:
        rows = _sigma_sweep(frame, subjects)
    boundaries = tuple(boundary_stats(s.name, frame, truth, s.truth) for s in subjects)
    return FigureResult(key, title, scene, subjects, tuple(verdicts), tuple(rows), boundaries)


def _sigma_sweep(frame: Frame, subjects: Sequence[Subject]) -> list[tuple[str, str, float]]:
    """IoU of §4.2 over σs, with D read squared (the library's) and as the distance itself
    (there 2σs² = 2 × factor × the median neighbour distance, in metres)."""
    base = SegmentParams()
    rows: list[tuple[str, str, float]] = []
    for factor in SIGMA_FACTORS:
        params = replace(base, sigma_s_factor=factor)
        for case in _seeded_cases(params):
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


def figure4(seeds: Sequence[int], sweep: bool) -> FigureResult:
    """Figure 4: the non-convex robot arm from one seed (§4.2); §4.1 shown for contrast."""
    source = open_scene("robot")
    info = source.target
    assert info is not None
    base = SegmentParams()
    extra = [
        Case("intensity only (eq. 5)", Energy.INTENSITY, base),
        Case("3D distance penalty (eq. 6)", Energy.RANGE_DATA, base),
    ]
    return _seeded_figure(
        "fig4",
        "Figure 4: the robot arm, whose intensity matches the background",
        "robot",
        "§4.2 segments the non-convex robot from one seed",
        [(info.name, info.id)],
        extra,
        seeds,
        sweep,
    )


def figure5(seeds: Sequence[int], sweep: bool) -> FigureResult:
    """Figure 5: hammer, tripod and wrench, each from one seed (§4.2)."""
    source = open_scene("tools")
    objects = [(o.name, o.id) for o in source.objects]
    return _seeded_figure(
        "fig5",
        "Figure 5: tools with thin parts",
        "tools",
        "§4.2 segments each thin tool from one seed",
        objects,
        [],
        seeds,
        sweep,
    )


def control(seeds: Sequence[int], sweep: bool) -> FigureResult:
    """Not a claim of the paper: §4.2 on objects that touch the belt at a point or an edge
    (the ball and the marked box of Figure 1's scene), where the range shows their outline."""
    source = open_scene("paper-fig1")
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
    "fig4": "Why: the emulated robot's base stands on the floor, and the floor meets the wall. "
    "Where a surface meets another the range is continuous, so across the contact line D is "
    "that of neighbours on one surface, and eq. (7) (or any weight that is a function of D "
    "alone, whatever σs) ties the base to the floor as strongly as to itself. The table shows "
    "it: the true cut's weight is far above 1 and nearly all of it lies on edges that look "
    "like the robot's own surface, almost all at the bottom of the base. The paper's robot "
    "(Figure 4) is segmented, but "
    "we cannot see how it met its support; in this scene the claim cannot hold for §4.2's "
    "energy, and the sweep over σs and over the two readings of D finds no setting that "
    "segments it.",
    "fig5": "Why: the emulated tools lie flat on the belt. The wrench is 12 mm thick and the "
    "hammer's handle 28 mm across, against a range noise of 8–11 mm (the table's robust σ "
    "of measured minus true range), so across most of their outline D is no larger than "
    "between neighbours on the tool itself; the tripod stands on three feet, and those "
    "contacts carry its cut. The paper's Figure 5 shows the tools as point clouds and does not "
    "say how they were placed; in this scene the claim cannot hold for eq. (7). Eq. (8)'s "
    "intensity term helps where the tool's albedo differs from the belt's (the wrench).",
    "control": "The control shows the energy working where the range does show the outline: "
    "the ball touches the belt at a point, and eq. (7) with the default σs segments it. The "
    "marked box sits on the belt along its bottom edges and needs eq. (8)'s intensity term (or "
    "a smaller σs, see the sweep).",
}
"""What the scene does to §4.2's energy, for each figure with outline statistics."""


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
        "µt, µb, σs and σi are estimated from each frame (see `tofcut.tracker.paper.segment`). "
        "In the panels white is target found, red is found but not target, blue is target "
        "missed.",
        "",
        f"What the verdicts mean: *segmented* is IoU ≥ {GOOD_IOU} in every seed; *fails* is a "
        f"mean IoU below {FAILED_IOU}; a look-alike is *segmented too* when on average at least "
        f"{SWALLOWED:.0%} of its pixels are in the mask; the target is *alone* when no other "
        f"object has more than {LEFT_ALONE:.0%} of its pixels in the mask.",
        "",
    ]
    supported = sum(v.supported for f in figures for v in f.verdicts)
    total = sum(len(f.verdicts) for f in figures)
    lines += [f"**{supported} of {total} claims are supported by the numbers.**", ""]
    for fig in figures:
        lines += [f"## {fig.title}", "", f"Scene `{fig.scene}`.", ""]
        for v in fig.verdicts:
            mark = "supported" if v.supported else "**not supported**"
            lines += [f"- *{v.claim}* — {mark}: {v.evidence}."]
        seeded = [o for sub in fig.subjects for o in sub.outcomes if o.case.energy.seeded]
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
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def run_figures(seeds: Sequence[int], sweep: bool) -> list[FigureResult]:
    """Figures 1, 4 and 5, and the §4.2 control."""
    return [
        figure1(seeds, sweep),
        figure4(seeds, sweep),
        figure5(seeds, sweep),
        control(seeds, sweep),
    ]
