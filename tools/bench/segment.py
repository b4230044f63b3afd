"""Bench stage: segmentation of one object per case (the cases of `bench.segment_cases`): the
fast exact cut against the full-frame reference cut (`bench.cut_timing.time_cut`), and
OpenCV's grabCut (`experiments.grabcut`), the generic tool a user would reach for, on the
same frame, with IoU against ground truth for each.

The cuts and `segment()` are timed in CPU time, fastest of the repeats (`time_cut`: the
reference and the fast cut both from the same built energy to the labels, back to back and
with the caches emptied before each call ("cold"); `segment()` end to end with either);
grabCut in wall time, median of its runs; all on one core.
"""

from __future__ import annotations

from typing import Any

from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tools.bench.cut_timing import time_cut
from tofcut.tools.bench.segment_cases import CASES, case_target, kind_of
from tofcut.tools.experiments.grabcut import (
    INSTALL_HINT,
    grabcut_image,
    have_opencv,
    seed_rect,
    timed_grabcut,
)
from tofcut.tools.experiments.reproduce import iou
from tofcut.tracker.paper.segment import segment


def run(quick: bool) -> dict[str, Any]:
    """{"rows": [...], "grabcut": bool, "note": str}: one row per case."""
    opencv = have_opencv()
    cases = [c for c in CASES if c[3] >= 11] if quick else list(CASES)
    rows = []
    for scene, name, energy, repeats in cases:
        source = open_scene(scene, 0)
        frame, truth = decode(source, scene_exposure(source, 0.0))
        obj = next(o for o in truth.objects if o.name == name)
        true_mask = truth.labels == obj.id
        target = case_target(truth, obj, energy)
        repeats = 2 if quick else repeats
        timing = time_cut(frame, target, energy, repeats=repeats)
        fast_mask = segment(frame, target, energy).mask
        ref_mask = segment(frame, target, energy, reference=True).mask
        row: dict[str, Any] = {
            "scene": scene,
            "object": name,
            "energy": energy.value,
            "kind": kind_of(energy),
            "data_term": kind_of(energy) == "data-term",
            "reference_cut_s": timing.reference_s,
            "fast_cut_s": timing.fast_s,
            "cut_ratio": timing.ratio,
            "reference_cut_cold_s": timing.reference_cold_s,
            "fast_cut_cold_s": timing.fast_cold_s,
            "cut_cold_ratio": timing.cold_ratio,
            "segment_reference_s": timing.segment_reference_s,
            "segment_fast_s": timing.segment_fast_s,
            "identical": timing.identical,
            "iou_fast": iou(fast_mask, true_mask),
            "iou_reference": iou(ref_mask, true_mask),
        }
        if opencv:
            image, rect = grabcut_image(frame), seed_rect(true_mask)
            seconds, mask = timed_grabcut(image, rect, min(repeats, 5))
            row["grabcut_s"] = seconds
            row["iou_grabcut"] = iou(mask, true_mask)
            row["grabcut_over_fast"] = seconds / timing.segment_fast_s
        rows.append(row)
    return {"rows": rows, "grabcut": opencv, "note": "" if opencv else INSTALL_HINT}
