"""A scene's frames decoded as a host would see them, and a picture of a scene for people:
decoded intensity, range and truth labels side by side."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from PIL import Image, ImageDraw

from tofcut._types import F64, I32, U8
from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.protocol import FrameHeader, integration_us
from tofcut.sim.device import READOUT_US
from tofcut.sim.renderer import SceneSource
from tofcut.sim.source import Exposure
from tofcut.sim.truth import FrameTruth


def scene_exposure(source: SceneSource, t0_s: float, sequence: int = 0) -> Exposure:
    """The exposure the emulated camera would take at device time t0 with the scene's settings."""
    st = source.settings
    integration = integration_us(st.integration)
    return Exposure(
        sequence, t0_s, (integration + READOUT_US) / 1e6, integration / 1e6, st.mod_code
    )


def decode(source: SceneSource, exposure: Exposure) -> tuple[Frame, FrameTruth]:
    """Render one exposure and decode it with the driver, as a host would see it."""
    rendered = source.render(exposure)
    calib = source.calibration
    header = FrameHeader(
        sequence=exposure.sequence, device_time_us=round(exposure.t0_s * 1e6), width=calib.width,
        height=calib.height, mod_code=exposure.mod_code, integration=source.settings.integration,
        flags=0, temperature_c=36.5, tap_interval_us=round(exposure.tap_interval_s * 1e6),
        payload_size=rendered.taps.nbytes, payload_crc=0,
    )  # fmt: skip
    raw = RawFrame(header=header, taps=rendered.taps, wire=b"", host_time_ns=0)
    return demodulate(raw, Optics.from_calibration(calib)), rendered.truth


def decoded_frames(source: SceneSource, count: int) -> Iterator[tuple[Frame, FrameTruth]]:
    """The scene's first `count` frames at its frame rate, each decoded (`decode`) with its
    truth."""
    period = source.settings.frame_period * 1e-4
    for i in range(count):
        yield decode(source, scene_exposure(source, i * period, i))


def _gray(values: F64, lo: float, hi: float) -> U8:
    scaled = (np.nan_to_num(values, nan=lo) - lo) / max(hi - lo, 1e-12)
    return (np.clip(scaled, 0.0, 1.0) * 255).astype(np.uint8)


def _turbo(x: U8) -> U8:
    """A blue→green→red ramp for range (near is red)."""
    t = x.astype(np.float64) / 255.0
    r = np.clip(1.5 - np.abs(4 * t - 3), 0, 1)
    g = np.clip(1.5 - np.abs(4 * t - 2), 0, 1)
    b = np.clip(1.5 - np.abs(4 * t - 1), 0, 1)
    return (np.stack([r, g, b], axis=-1) * 255).astype(np.uint8)


def _label_colours(labels: I32, target: int | None) -> U8:
    rng = np.random.default_rng(7)
    palette = rng.integers(60, 256, (int(labels.max()) + 1, 3)).astype(np.uint8)
    palette[0] = (40, 40, 40)
    if target is not None and target <= labels.max():
        palette[target] = (255, 40, 40)
    return palette[labels]


def scene_picture(source: SceneSource, t0_s: float = 0.0, scale: int = 3) -> Image.Image:
    """Intensity, range and truth labels of the frame at device time t0, side by side."""
    frame, truth = decode(source, scene_exposure(source, t0_s))
    valid = frame.valid
    lo, hi = np.percentile(frame.intensity, [1, 99])
    inten = np.repeat(_gray(frame.intensity, float(lo), float(hi))[..., None], 3, axis=-1)
    rlo, rhi = np.percentile(frame.range[valid], [1, 99]) if valid.any() else (0.0, 1.0)
    rng_img = _turbo(255 - _gray(frame.range, float(rlo), float(rhi)))
    rng_img[~valid] = 0
    target = source.target
    labels = _label_colours(truth.labels, target.id if target else None)
    if target is not None:
        u, v = target.seed_pixel
        for img in (inten, rng_img, labels):
            img[max(v - 3, 0) : v + 4, u] = (255, 255, 0)
            img[v, max(u - 3, 0) : u + 4] = (255, 255, 0)
    h, w = truth.labels.shape
    gap = 4
    strip = np.full((h, 3 * w + 2 * gap, 3), 255, np.uint8)
    for i, img in enumerate((inten, rng_img, labels)):
        strip[:, i * (w + gap) : i * (w + gap) + w] = img
    size = (strip.shape[1] * scale, h * scale)
    big = Image.fromarray(strip).resize(size, Image.Resampling.NEAREST)
    canvas = Image.new("RGB", (big.width, big.height + 22), "white")
    canvas.paste(big, (0, 22))
    draw = ImageDraw.Draw(canvas)
    captions = (
        f"{source.name}: intensity",
        f"range {rlo:.2f}-{rhi:.2f} m",
        f"truth labels ({sum(o.pixels > 0 for o in truth.objects)} objects)",
    )
    for i, text in enumerate(captions):
        draw.text((i * (w + gap) * scale + 4, 5), text, fill="black")
    return canvas
