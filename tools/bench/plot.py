"""The scaling plot of `tofcut bench`, drawn with Pillow (no plotting library needed): cost
against pixels and against objects, log-log, the measured points and the fitted power laws."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from tofcut.tools.bench.report import Fit

PANEL = (520, 400)
MARGIN = (70, 30, 20, 50)
"""Left, top, right, bottom space round each panel's plot area."""
COLOURS = ((31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14))


def _decades(lo: float, hi: float) -> tuple[int, int]:
    return math.floor(math.log10(lo)), math.ceil(math.log10(hi))


def _panel(draw: ImageDraw.ImageDraw, x0: int, fits: list[Fit], against: str) -> None:
    left, top, right, bottom = MARGIN
    w, h = PANEL[0] - left - right, PANEL[1] - top - bottom
    ox, oy = x0 + left, top
    draw.rectangle((ox, oy, ox + w, oy + h), outline="black")
    draw.text((ox, 8), f"cost against {against} (log-log)", fill="black")
    if not fits:
        draw.text((ox + 10, oy + 10), "not measured", fill="black")
        return
    xs = [x for f in fits for x, _ in f.points]
    ys = [y * 1e3 for f in fits for _, y in f.points]
    gx = _decades(min(xs) / 1.3, max(xs) * 1.3)
    gy = _decades(min(ys) / 1.5, max(ys) * 1.5)

    def at(x: float, y_ms: float) -> tuple[float, float]:
        fx = (math.log10(x) - gx[0]) / (gx[1] - gx[0])
        fy = (math.log10(y_ms) - gy[0]) / (gy[1] - gy[0])
        return ox + fx * w, oy + h - fy * h

    for d in range(gx[0], gx[1] + 1):
        px, _ = at(10.0**d, 10.0 ** gy[0])
        draw.line((px, oy, px, oy + h), fill=(225, 225, 225))
        draw.text((px - 12, oy + h + 6), f"1e{d}", fill="black")
    for d in range(gy[0], gy[1] + 1):
        _, py = at(10.0 ** gx[0], 10.0**d)
        draw.line((ox, py, ox + w, py), fill=(225, 225, 225))
        draw.text((x0 + 8, py - 6), f"{10.0**d:g} ms", fill="black")
    draw.text((ox + w // 2 - 20, oy + h + 24), against, fill="black")
    for i, f in enumerate(fits):
        colour = COLOURS[i % len(COLOURS)]
        px_, py_ = zip(*f.points, strict=True)
        slope, icept = np.polyfit(np.log10(px_), np.log10(np.array(py_) * 1e3), 1)
        ends = [at(x, 10 ** (icept + slope * math.log10(x))) for x in (min(px_), max(px_))]
        draw.line((*ends[0], *ends[1]), fill=colour, width=2)
        for x, y in f.points:
            cx, cy = at(x, y * 1e3)
            draw.ellipse((cx - 4, cy - 4, cx + 4, cy + 4), fill=colour)
        draw.text((ox + 8, oy + 8 + 14 * i), f"{f.cost}: k = {f.exponent:.2f}", fill=colour)


def draw_scaling(fits: list[Fit], path: Path) -> None:
    """Write the two panels side by side as a PNG."""
    image = Image.new("RGB", (2 * PANEL[0], PANEL[1]), "white")
    draw = ImageDraw.Draw(image)
    for i, against in enumerate(("pixels", "objects")):
        _panel(draw, i * PANEL[0], [f for f in fits if f.against == against], against)
    image.save(path)
