"""Bench stage: segmentation of one object per case (the cases of `bench.segment_cases`): the
fast exact cut against the full-frame reference cut (`bench.cut_timing.time_cut`), and
OpenCV's grabCut, the generic tool a user would reach for, on the same frame, with IoU
against ground truth for each.

GrabCut gets an 8-bit colour image of the same frame (intensity, range and amplitude as its
three channels, so it sees the range too) and, as its seed region, the object's true
bounding box grown by a quarter of its size on every side: a box a user would draw.
The cuts and `segment()` are timed in CPU time, fastest of the repeats (`time_cut`: the
reference and the fast cut both from the same built energy to the labels, back to back and
with the caches emptied before each call ("cold"); `segment()` end to end with either);
grabCut in wall time, median of its runs; all on one core.
"""

from __future__ import annotations

import importlib.util
import time
from typing import Any

import numpy as np

from tofcut._types import F64, U8, B
from tofcut.driver.frames import Frame
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tools.bench.cut_timing import time_cut
from tofcut.tools.bench.segment_cases import CASES
from tofcut.tools.experiments.reproduce import deepest_pixel, iou
from tofcut.tracker.paper.segment import Energy, Target, segment

GRABCUT_ITERATIONS = 5
INSTALL_HINT = (
    "grabCut needs OpenCV: `pip install 'tofcut[bench]'` (or `pip install "
    "opencv-python-headless`); `scripts/uv run` installs it with the dev group"
)


def _u8(values: F64, valid: B, invert: bool = False) -> U8:
    lo, hi = np.percentile(values[valid], [1, 99]) if valid.any() else (0.0, 1.0)
    scaled = np.clip((np.nan_to_num(values) - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    if invert:
        scaled = 1.0 - scaled
    out = (scaled * 255).astype(np.uint8)
    out[~valid] = 0
    return out


def grabcut_image(frame: Frame) -> U8:
    """(H, W, 3) uint8: intensity, range (near is bright) and amplitude."""
    v = frame.valid
    channels = (
        _u8(frame.intensity, np.ones_like(v)),
        _u8(frame.range, v, invert=True),
        _u8(frame.amplitude, v),
    )
    return np.ascontiguousarray(np.stack(channels, axis=-1))


def seed_rect(mask: B) -> tuple[int, int, int, int]:
    """(x, y, w, h): the mask's bounding box grown by a quarter of its size on every side."""
    rows, cols = np.nonzero(mask)
    h, w = mask.shape
    u0, u1, v0, v1 = cols.min(), cols.max() + 1, rows.min(), rows.max() + 1
    du, dv = max(2, (u1 - u0) // 4), max(2, (v1 - v0) // 4)
    u0, v0 = max(0, u0 - du), max(0, v0 - dv)
    u1, v1 = min(w, u1 + du), min(h, v1 + dv)
    return (int(u0), int(v0), int(u1 - u0), int(v1 - v0))


def grabcut(image: U8, rect: tuple[int, int, int, int]) -> B:
    """OpenCV's grabCut from a rectangle; the (probable) foreground."""
    import cv2

    cv2.setNumThreads(1)  # one core, as everything else here
    mask = np.zeros(image.shape[:2], np.uint8)
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    cv2.grabCut(image, mask, rect, bgd, fgd, GRABCUT_ITERATIONS, cv2.GC_INIT_WITH_RECT)
    foreground: B = (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)
    return foreground


def timed_grabcut(image: U8, rect: tuple[int, int, int, int], repeats: int) -> tuple[float, B]:
    """Median wall time of grabCut over `repeats` runs after one warm-up, and its mask."""
    mask = grabcut(image, rect)
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        mask = grabcut(image, rect)
        seconds.append(time.perf_counter() - start)
    return float(np.median(seconds)), mask


def have_opencv() -> bool:
    """Whether OpenCV is installed (found without importing it)."""
    return importlib.util.find_spec("cv2") is not None


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
        if energy.seeded:
            target = Target(pixel=deepest_pixel(true_mask))
        else:
            c = obj.centroid
            target = Target(point=(float(c[0]), float(c[1]), float(c[2])))
        repeats = 2 if quick else repeats
        timing = time_cut(frame, target, energy, repeats=repeats)
        fast_mask = segment(frame, target, energy).mask
        ref_mask = segment(frame, target, energy, reference=True).mask
        row: dict[str, Any] = {
            "scene": scene,
            "object": name,
            "energy": energy.value,
            "data_term": energy in (Energy.INTENSITY, Energy.RANGE_DATA, Energy.IMAGE_PLANE),
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
