"""What the emulated camera asks of a scene: the taps of one exposure, and its ground truth;
and of a recording it replays (`Recording`): which recorded frame an exposure takes."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from tofcut.driver.calibration import Calibration
from tofcut.driver.protocol import Register


@dataclass(frozen=True)
class Exposure:
    """When and how the sensor takes one frame; times are device time in seconds."""

    sequence: int
    t0_s: float
    """Start of tap 0."""
    tap_interval_s: float
    """From the start of one tap to the start of the next."""
    integration_s: float
    """Exposure time of each tap."""
    mod_code: int
    recorded: int | None = None
    """A replay's: the recorded frame this exposure takes (`Recording.take`); else None."""

    def tap_time_s(self, k: int) -> float:
        """Middle of tap k's exposure: where a moving scene is sampled for that tap."""
        return self.t0_s + k * self.tap_interval_s + 0.5 * self.integration_s


@dataclass(frozen=True, eq=False)
class Rendered:
    """One exposure as the sensor saw it."""

    taps: npt.NDArray[np.uint16]
    """(4, H, W) raw counts, 14-bit, 16383 = saturated."""
    truth: Any = None
    """The scene's ground truth for this exposure (see `tofcut.sim` scenes), or None."""
    wire: bytes | None = None
    """A replay's: the recorded frame as it was on the wire (header and payload, or a
    damaged record as it is); the camera sends it with its own sequence and time."""


class TapSource(Protocol):
    """A scene the emulated camera can look at."""

    @property
    def calibration(self) -> Calibration:
        """The true lens, phase offsets and distance offset; the camera's flash holds this."""
        ...

    def render(self, exposure: Exposure) -> Rendered:
        """Taps for one exposure; deterministic for a given source seed and sequence number."""
        ...


@dataclass(frozen=True)
class Take:
    """What a recording gives the sensor for one exposure."""

    frame: int | None
    """The recorded frame it takes, or None: the recording lost the frame of that time
    (the camera numbers it, and never sends it)."""
    ended: bool = False
    """The recording is over: the sensor takes no more frames."""


@runtime_checkable
class Recording(TapSource, Protocol):
    """A recording the emulated camera replays in place of a scene (`tofcut.sim.replay`):
    the flash, registers and frames it was made with."""

    @property
    def calibration_block(self) -> bytes:
        """The calibration block exactly as recorded (the camera's flash)."""
        ...

    @property
    def registers(self) -> dict[Register, int]:
        """The writable registers it was recorded with."""
        ...

    def take(self, line_us: int) -> Take:
        """The frame an exposure starting at `line_us` takes: µs on a clock that starts
        with the emulated camera and runs on through its reboots (the line never stops)."""
        ...

    def refusal(self, register: Register, value: int, registers: dict[Register, int]) -> str:
        """Why a host's write of `value` to `register` (the registers being `registers`)
        cannot be replayed, or '' when it can."""
        ...
