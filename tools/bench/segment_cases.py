"""The segmentation benchmark on emulated 176×144 frames: one object per cut, reference
against fast (see `tofcut.tools.bench.cut_timing`); `tofcut bench` reports it."""

from __future__ import annotations

from dataclasses import dataclass

from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tools.bench.cut_timing import CutTiming, time_cut
from tofcut.tools.experiments.reproduce import deepest_pixel
from tofcut.tracker.paper.segment import Energy, Target

CASES: tuple[tuple[str, str, Energy, int], ...] = (
    ("paper-fig1", "target-box", Energy.RANGE_DATA, 21),
    ("paper-fig1", "ball", Energy.RANGE_DATA, 21),
    ("paper-fig3", "box", Energy.RANGE_DATA, 21),
    ("paper-fig1", "target-box", Energy.RANGE_INTENSITY_SMOOTH, 11),
    ("paper-fig1", "ball", Energy.RANGE_SMOOTH, 11),
    ("tools", "wrench", Energy.RANGE_INTENSITY_SMOOTH, 11),
    ("tools", "hammer", Energy.RANGE_SMOOTH, 3),
)
"""(scene, object, energy, repetitions): the data-term cut around the object's true centroid
(what the tracker does with its prediction), the §4.2 cuts from a seed deep inside it. The
last one is the worst case: the weights join the hammer to the whole belt."""


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
        if energy.seeded:
            target = Target(pixel=deepest_pixel(truth.labels == obj.id))
        else:
            target = Target(
                point=(float(obj.centroid[0]), float(obj.centroid[1]), float(obj.centroid[2]))
            )
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
