"""OpenCV's grabCut, the generic tool a user would reach for, as the peer the paper's
energies are compared with (`tofcut reproduce`, `tofcut bench`).

GrabCut gets an 8-bit colour image of the frame (intensity, range and amplitude as its
three channels, so it sees the range too) and, as its seed region, the object's true
bounding box grown by a quarter of its size on every side: a box a user would draw.
"""

from __future__ import annotations

import importlib.util
import time

import numpy as np

from tofcut._types import F64, U8, B
from tofcut.driver.frames import Frame

GRABCUT_ITERATIONS = 5
INSTALL_HINT = (
    "grabCut needs OpenCV: `pip install 'tofcut[bench]'` (or `pip install "
    "opencv-python-headless`); `scripts/uv run` installs it with the dev group"
)


def have_opencv() -> bool:
    """Whether OpenCV is installed (found without importing it)."""
    return importlib.util.find_spec("cv2") is not None


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
    cv2.setRNGSeed(0)  # its GMMs start from k-means: the same frame, the same mask
    mask = np.zeros(image.shape[:2], np.uint8)
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    cv2.grabCut(image, mask, rect, bgd, fgd, GRABCUT_ITERATIONS, cv2.GC_INIT_WITH_RECT)
    foreground: B = (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)
    return foreground


def grabcut_object(frame: Frame, truth_mask: B) -> B:
    """GrabCut of one object of a frame, from the box round its true mask."""
    return grabcut(grabcut_image(frame), seed_rect(truth_mask))


def timed_grabcut(image: U8, rect: tuple[int, int, int, int], repeats: int) -> tuple[float, B]:
    """Median wall time of grabCut over `repeats` runs after one warm-up, and its mask."""
    mask = grabcut(image, rect)
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        mask = grabcut(image, rect)
        seconds.append(time.perf_counter() - start)
    return float(np.median(seconds)), mask
