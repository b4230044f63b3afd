"""The values that cross layers: a raw frame off the wire, and a demodulated frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tofcut.driver.protocol import FrameHeader


@dataclass(frozen=True, eq=False)
class RawFrame:
    """One frame exactly as received: header, the four taps, and when the host got it."""

    header: FrameHeader
    taps: npt.NDArray[np.uint16]
    """(4, H, W) raw counts, a read-only view on `wire`."""
    wire: bytes
    """Header and payload as they came over the wire (what a capture stores)."""
    host_time_ns: int
    """Host receive time, ns since the Unix epoch."""

    @property
    def sequence(self) -> int:
        return self.header.sequence

    @property
    def device_time_us(self) -> int:
        return self.header.device_time_us


@dataclass(frozen=True, eq=False)
class Frame:
    """A demodulated frame (spec §7); every array is (H, W) or (H, W, 3), row-major."""

    header: FrameHeader
    host_time_ns: int
    phase: npt.NDArray[np.float64]
    """Raw phase φ in [0, 2π), before the per-pixel offset."""
    amplitude: npt.NDArray[np.float64]
    intensity: npt.NDArray[np.float64]
    """B, the mean of the four taps: the paper's I_p."""
    range: npt.NDArray[np.float64]
    """Radial distance along the pixel's ray, metres."""
    valid: npt.NDArray[np.bool_]
    """False where a tap saturated or the amplitude is below the threshold."""
    xyz: npt.NDArray[np.float64]
    """Camera-frame points (x right, y down, z forward), metres, (H, W, 3)."""

    @property
    def sequence(self) -> int:
        return self.header.sequence

    @property
    def device_time_us(self) -> int:
        return self.header.device_time_us

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return (self.header.height, self.header.width)
