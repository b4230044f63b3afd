"""Frames for `tofcut bench`, rendered before anything is timed: rendering is the camera's
work, not the host's, so every stage times its part on frames that already exist."""

from __future__ import annotations

import numpy as np

from tofcut.driver.calibration import Calibration
from tofcut.driver.frames import RawFrame
from tofcut.driver.protocol import DeviceInfo, FrameHeader, crc32, pack_header
from tofcut.driver.stream import FrameParser
from tofcut.sim.device import EmulatedCamera
from tofcut.sim.preview import scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.source import Exposure, Rendered
from tofcut.sim.truth import FrameTruth


def render_run(source: SceneSource, count: int, start_s: float = 0.0) -> list[Rendered]:
    """`count` consecutive exposures at the scene's frame rate, from device time `start_s`."""
    period = source.settings.frame_period * 1e-4 or 0.02
    return [source.render(scene_exposure(source, start_s + i * period, i)) for i in range(count)]


def wire_frame(source: SceneSource, rendered: Rendered, sequence: int, t0_s: float) -> bytes:
    """A rendered exposure as the camera puts it on the wire: header and payload (spec §5)."""
    payload = np.ascontiguousarray(rendered.taps, dtype="<u2").tobytes()
    st = source.settings
    calib = source.calibration
    exposure = scene_exposure(source, t0_s, sequence)
    header = FrameHeader(
        sequence=sequence, device_time_us=round(t0_s * 1e6), width=calib.width,
        height=calib.height, mod_code=st.mod_code, integration=st.integration, flags=0,
        temperature_c=36.5, tap_interval_us=round(exposure.tap_interval_s * 1e6),
        payload_size=len(payload), payload_crc=crc32(payload),
    )  # fmt: skip
    return pack_header(header) + payload


def wire_run(source: SceneSource, count: int) -> tuple[list[bytes], list[FrameTruth]]:
    """The bytes of `count` consecutive frames from t = 0, and their truth."""
    period = source.settings.frame_period * 1e-4 or 0.02
    rendered = render_run(source, count)
    wires = [wire_frame(source, r, i, i * period) for i, r in enumerate(rendered)]
    return wires, [r.truth for r in rendered]


def raw_run(source: SceneSource, count: int) -> tuple[list[RawFrame], list[FrameTruth]]:
    """Raw frames, parsed from their bytes by the driver, and their truth for `count`
    consecutive exposures from t = 0."""
    wires, truths = wire_run(source, count)
    parser = FrameParser(device_info(source))
    return [raw for wire in wires for raw in parser.feed(wire, 0)], truths


def device_info(source: SceneSource) -> DeviceInfo:
    """What GET_INFO would say of an emulated camera looking at `source`."""
    return EmulatedCamera(source).info


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
