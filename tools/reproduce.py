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
import numpy.typing as npt
from PIL import Image, ImageDraw

from tofcut.driver.frames import Frame
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.sim.truth import FrameTruth
from tofcut.tracker.energy import energy_of
from tofcut.tracker.segment import (
    Energy,
    SegmentParams,
    Target,
    build_problem,
    estimate_model,
    segment,
)

BOOL = npt.NDArray[np.bool_]
U8 = npt.NDArray[np.uint8]

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
    mask: BOOL
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
    intensity: npt.NDArray[np.float64]
    truth: BOOL
    pixel: tuple[int, int]
    outcomes: tuple[Outcome, ...]

    def outcome(self, label: str) -> Outcome:
        return next(o for o in self.outcomes if o.case.label == label)


@dataclass(frozen=True)
class Verdict:
    claim: str
    supported: bool
    evidence: str


@dataclass(frozen=True, eq=False)
class FigureResult:
    key: str
    title: str
    scene: str
    subjects: tuple[Subject, ...]
    verdicts: tuple[Verdict, ...]
    sweep: tuple[tuple[str, str, float], ...] = ()
    """(parameter setting, subject, IoU) rows of a sensitivity sweep, first seed."""


def iou(a: BOOL, b: BOOL) -> float:
    union = int(np.count_nonzero(a | b))
    return float(np.count_nonzero(a & b)) / union if union else 1.0


def deepest_pixel(mask: BOOL) -> tuple[int, int]:
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


TargetOf = Callable[[FrameTruth, BOOL], Target]


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


def _largest_other_share(mask: BOOL, labels: npt.NDArray[np.int32], own: int) -> float:
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

    def target_of(truth: FrameTruth, mask: BOOL) -> Target:
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


def _seeded_figure(
    key: str,
    title: str,
    scene: str,
    claim: str,
    objects: Sequence[tuple[str, int]],
    extra: Sequence[Case],
    seeds: Sequence[int],
    sweep: bool,
) -> FigureResult:
    base = SegmentParams()
    cases = _seeded_cases(base)

    def target_of(truth: FrameTruth, mask: BOOL) -> Target:
        return Target(pixel=deepest_pixel(mask))

    subjects = tuple(
        run_subject(scene, name, oid, target_of, [*cases, *extra], seeds) for name, oid in objects
    )
    verdicts = []
    for case in cases:
        ok = all(min(s.outcome(case.label).ious) >= GOOD_IOU for s in subjects)
        evidence = "; ".join(
            f"{s.name}: IoU {_span(s.outcome(case.label).ious)}, energy of the found mask "
            f"{s.outcome(case.label).energy_found:.4f} vs the true mask "
            f"{s.outcome(case.label).energy_truth:.4f}"
            for s in subjects
        )
        verdicts.append(Verdict(f"{claim} ({case.label})", ok, evidence))
    rows: list[tuple[str, str, float]] = []
    if sweep:
        frame, _ = frame_at(scene, seeds[0])
        for factor in (0.5, 1.0, 2.0):
            params = replace(base, sigma_s_factor=factor)
            for case in _seeded_cases(params):
                for s in subjects:
                    seg = segment(frame, Target(pixel=s.pixel), case.energy, params)
                    rows.append(
                        (
                            f"{case.label}, σs = {factor:g} × median step",
                            s.name,
                            iou(seg.mask, s.truth),
                        )
                    )
    return FigureResult(key, title, scene, subjects, tuple(verdicts), tuple(rows))


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


def _span(values: Sequence[float]) -> str:
    if len(values) == 1:
        return f"{values[0]:.2f}"
    return f"{np.mean(values):.2f} (min {min(values):.2f}, max {max(values):.2f})"


# --- pictures and the report ------------------------------------------------------------------


def _grey(values: npt.NDArray[np.float64]) -> U8:
    lo, hi = np.percentile(values, [1, 99])
    scaled = np.clip((values - lo) / max(float(hi - lo), 1e-12), 0.0, 1.0)
    return np.repeat((scaled * 255).astype(np.uint8)[..., None], 3, axis=-1)


def _mask_picture(mask: BOOL, truth: BOOL) -> U8:
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
        words = text.replace("β", "beta").split(": ", 1)
        draw.text((x, 2), words[0][: w * scale // 6], fill="black")
        if len(words) > 1:
            draw.text((x, 15), words[1][: w * scale // 6], fill="black")
    return canvas


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
        "µt, µb, σs and σi are estimated from each frame (see `tofcut.tracker.segment`). "
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
        if seeded:
            worse = sum(o.energy_truth > o.energy_found for o in seeded)
            lines += [
                "",
                f"In {worse} of the {len(seeded)} §4.2 runs above the ground-truth mask has a "
                "higher energy than the mask found, so there the minimum of the energy is not "
                "the object and no better minimiser could change the result. Where an object "
                "stands or lies on a surface its range is continuous with that surface at the "
                "contact, so eq. (7) joins them with strong edges.",
            ]
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
    """Figures 1, 4 and 5."""
    return [figure1(seeds, sweep), figure4(seeds, sweep), figure5(seeds, sweep)]
