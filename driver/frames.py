"""The values that cross layers: a raw frame off the wire, and a demodulated frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from tofcut.driver.protocol import FrameHeader

if TYPE_CHECKING:
    from tofcut.driver.intrinsics import Intrinsics


class _Stamped:
    """What a frame's header says of when it was taken, read from the frame itself."""

    header: FrameHeader

    @property
    def sequence(self) -> int:
        return self.header.sequence

    @property
    def device_time_us(self) -> int:
        return self.header.device_time_us


@dataclass(frozen=True, eq=False)
class RawFrame(_Stamped):
    """One frame exactly as received: header, the four taps, and when the host got it."""

    header: FrameHeader
    taps: npt.NDArray[np.uint16]
    """(4, H, W) raw counts, a read-only view on `wire`."""
    wire: bytes
    """Header and payload as they came over the wire (what a capture stores)."""
    host_time_ns: int
    """Host receive time, ns since the Unix epoch."""


@dataclass(frozen=True, eq=False)
class Frame(_Stamped):
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
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return (self.header.height, self.header.width)

    @property
    def rays(self) -> npt.NDArray[np.float64]:
        """(H, W, 3) each pixel's unit ray, its point over its range (not finite where the
        range is 0): what a surface's range along the pixel is measured on."""
        with np.errstate(invalid="ignore", divide="ignore"):
            rays: npt.NDArray[np.float64] = self.xyz / self.range[..., None]
        return rays

    @classmethod
    def from_arrays(
        cls,
        *,
        time_s: float,
        range_m: npt.ArrayLike | None = None,
        depth_m: npt.ArrayLike | None = None,
        xyz: npt.ArrayLike | None = None,
        intrinsics: Intrinsics | None = None,
        amplitude: npt.ArrayLike | None = None,
        intensity: npt.ArrayLike | None = None,
        valid: npt.ArrayLike | None = None,
        sequence: int = 0,
        host_time_ns: int | None = None,
    ) -> Frame:
        """A frame from any depth camera's arrays, for the tracker (docs/other-cameras.md);
        a size or value it cannot use is a `FrameInputError`, in one line.

        The geometry: `range_m` (H, W: metres along each pixel's ray), `depth_m` (H, W: z,
        as depth images hold it) or `xyz` (H, W, 3: camera-frame points, x right, y down,
        z forward, metres), or `range_m` with `xyz` (as `tofcut convert`'s npz holds them;
        they must agree). `intrinsics` gives the size and, for a range or depth, the rays
        (optional with `xyz`). `amplitude` (H, W, ≥ 0) is the signal's strength A and
        `intensity` the mean brightness B (default: even, the amplitude's median): the
        tracker takes a pixel's range noise as ∝ √B / A, so without an amplitude every
        pixel is taken as equally noisy. `valid` (H, W, bool; default: where the range or z
        is finite and positive) marks the pixels to use. `time_s` is the exposure's time on
        the source's clock (seconds, ≥ 0: the tracker's velocities come from it),
        `sequence` its frame counter, `host_time_ns` when it reached the host (default:
        now). There is no phase: `phase` is zeros.
        """
        # the arguments are repeated on purpose: this is the signature a user reads and a
        # type checker checks, and the checks live in frame_input, which imports this module
        from tofcut.driver.frame_input import frame_from_arrays

        return frame_from_arrays(
            time_s=time_s, range_m=range_m, depth_m=depth_m, xyz=xyz, intrinsics=intrinsics,
            amplitude=amplitude, intensity=intensity, valid=valid, sequence=sequence,
            host_time_ns=host_time_ns,
        )  # fmt: skip
