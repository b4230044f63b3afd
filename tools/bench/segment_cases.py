"""The segmentation benchmark on emulated 176×144 frames: one object per cut, reference
against fast (see `tofcut.tools.bench.cut_timing`); `tofcut bench` reports it."""

from __future__ import annotations

from dataclasses import dataclass

from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.sim.truth import FrameTruth, ObjectTruth
from tofcut.tools.bench.cut_timing import CutTiming, time_cut
from tofcut.tools.experiments.reproduce import deepest_pixel, extent_of
from tofcut.tracker.paper.segment import Energy, Target

CASES: tuple[tuple[str, str, Energy, int], ...] = (
    ("paper-fig1", "target-box", Energy.RANGE_DATA, 21),
    ("paper-fig1", "ball", Energy.RANGE_DATA, 21),
    ("paper-fig3", "box", Energy.RANGE_DATA, 21),
    ("paper-fig1", "target-box", Energy.RANGE_INTENSITY_SMOOTH, 11),
    ("paper-fig1", "ball", Energy.RANGE_SMOOTH, 11),
    ("tools", "wrench", Energy.RANGE_INTENSITY_SMOOTH, 11),
    ("tools", "hammer", Energy.RANGE_SMOOTH, 3),
    ("paper-fig1", "target-box", Energy.SUPPORT, 5),
    ("paper-fig1", "ball", Energy.SUPPORT, 5),
    ("paper-fig3", "box", Energy.SUPPORT, 5),
    ("tools", "wrench", Energy.SUPPORT, 5),
    ("tools", "hammer", Energy.SUPPORT, 5),
    ("tools", "tripod", Energy.SUPPORT, 5),
    ("robot", "robot", Energy.SUPPORT, 5),
)
"""(scene, object, energy, repetitions): the data-term cut around the object's true centroid
and extent (what the tracker does with its prediction), the §4.2 cuts and the support
energy from a seed deep inside it. The hammer's §4.2 cut is the worst case: the weights
join the hammer to the whole belt."""


def kind_of(energy: Energy) -> str:
    """ "data-term", "§4.2" or "support": the family of an energy and of its fast solver."""
    if energy is Energy.SUPPORT:
        return "support"
    return "§4.2" if energy.seeded else "data-term"


def case_target(truth: FrameTruth, obj: ObjectTruth, energy: Energy) -> Target:
    """A case's target: a seed deep inside the object for the energies grown from one, its
    true centroid and extent for the data terms."""
    if energy.from_seed:
        return Target(pixel=deepest_pixel(truth.labels == obj.id))
    x, y, z = (float(c) for c in obj.centroid)
    return Target(point=(x, y, z), extent_m=extent_of(obj))


@dataclass(frozen=True)
class BenchRow:
    scene: str
    name: str
    timing: CutTiming


def segmentation_bench(scale: float = 1.0) -> list[BenchRow]:
    """Time every case (repetitions scaled by `scale`, at least 1) at t = 0, noise seed 0."""
    rows = []
    for scene, name, energy, repeats in CASES:
        source = open_scene(scene, 0)
        frame, truth = decode(source, scene_exposure(source, 0.0))
        obj = next(o for o in truth.objects if o.name == name)
        target = case_target(truth, obj, energy)
        timing = time_cut(frame, target, energy, repeats=max(1, round(repeats * scale)))
        rows.append(BenchRow(scene, name, timing))
    return rows


def format_rows(rows: list[BenchRow]) -> list[str]:
    """One line per case, for a terminal or a README."""
    lines = [
        "| scene | object | energy | reference cut | fast cut | ratio | cold: reference / fast "
        "(ratio) | graph nodes | identical | segment() reference / fast |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        t = r.timing
        lines.append(
            f"| {r.scene} | {r.name} | {t.energy.value} | {t.reference_s * 1e3:.2f} ms "
            f"| {t.fast_s * 1e3:.3f} ms | {t.ratio:.1f}× | {t.reference_cold_s * 1e3:.2f} / "
            f"{t.fast_cold_s * 1e3:.3f} ms ({t.cold_ratio:.1f}×) | {t.graph_nodes} / {t.pixels} "
            f"| {'yes' if t.identical else 'NO'} | {t.segment_reference_s * 1e3:.2f} / "
            f"{t.segment_fast_s * 1e3:.2f} ms ({t.segment_ratio:.1f}×) |"
        )
    return lines
