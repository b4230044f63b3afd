"""Frames for `tofcut bench`, rendered before anything is timed: rendering is the camera's
work, not the host's, so every stage times its part on frames that already exist."""

from __future__ import annotations

import numpy as np

from tofcut.driver.calibration import Calibration
from tofcut.driver.frames import RawFrame
from tofcut.driver.protocol import FrameHeader, crc32
from tofcut.sim.preview import scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.source import Exposure, Rendered
from tofcut.sim.truth import FrameTruth


def render_run(source: SceneSource, count: int, start_s: float = 0.0) -> list[Rendered]:
    """`count` consecutive exposures at the scene's frame rate, from device time `start_s`."""
    period = source.settings.frame_period * 1e-4 or 0.02
    return [source.render(scene_exposure(source, start_s + i * period, i)) for i in range(count)]


def raw_frame(source: SceneSource, rendered: Rendered, sequence: int, t0_s: float) -> RawFrame:
    """A rendered exposure as the driver hands it over (no USB: the header the camera sends)."""
    taps = np.ascontiguousarray(rendered.taps, dtype="<u2")
    st = source.settings
    exposure = scene_exposure(source, t0_s, sequence)
    header = FrameHeader(
        sequence=sequence, device_time_us=round(t0_s * 1e6), width=taps.shape[2],
        height=taps.shape[1], mod_code=st.mod_code, integration=st.integration, flags=0,
        temperature_c=36.5, tap_interval_us=round(exposure.tap_interval_s * 1e6),
        payload_size=taps.nbytes, payload_crc=crc32(taps.tobytes()),
    )  # fmt: skip
    return RawFrame(header, taps, b"", 0)


def raw_run(source: SceneSource, count: int) -> tuple[list[RawFrame], list[FrameTruth]]:
    """Raw frames and their truth for `count` consecutive exposures from t = 0."""
    period = source.settings.frame_period * 1e-4 or 0.02
    rendered = render_run(source, count)
    raws = [raw_frame(source, r, i, i * period) for i, r in enumerate(rendered)]
    return raws, [r.truth for r in rendered]


class ReplaySource:
    """A `TapSource` that hands out frames rendered beforehand, in order, round and round:
    the emulated camera then costs what its firmware costs, not what the renderer does."""

    def __init__(self, calibration: Calibration, frames: list[Rendered]) -> None:
        if not frames:
            raise ValueError("a replay needs at least one frame")
        self._calibration = calibration
        self._frames = frames

    @property
    def calibration(self) -> Calibration:
        return self._calibration

    def render(self, exposure: Exposure) -> Rendered:
        return self._frames[exposure.sequence % len(self._frames)]
