"""The tracker's output values: one track in one frame, and one frame's tracking result."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tofcut._types import F64
from tofcut.driver.frames import Frame


@dataclass(frozen=True, eq=False)
class Track:
    """Where one tracked object is in one frame; camera coordinates, metres."""

    id: int
    """Stable over the object's life, ≥ 1 (0 is the background in label images)."""
    centroid: F64
    """(3,) mean of the object's points (`points`)."""
    velocity: F64
    """(3,) m/s, from the track's filter."""
    box_min: F64
    """(3,) lower corner of the axis-aligned 3D box around the points."""
    box_max: F64
    bbox: tuple[int, int, int, int]
    """(u0, v0, u1, v1): image box, inclusive-exclusive."""
    pixels: int
    """Pixels in the mask this frame (0 while the object is hidden and only predicted)."""
    points: npt.NDArray[np.float32]
    """(N, 3) the object's point cloud this frame: its mask's points but those of the outline
    given back to it (`tofcut.tracker.rims`), read between the object and the scenery."""
    hidden_frames: int = 0
    """Frames in a row the object was not seen (it is being predicted through occlusion)."""

    @property
    def visible(self) -> bool:
        return self.hidden_frames == 0

    def to_json(self) -> dict[str, object]:
        """The per-track record of `--tracks-out` (a stable format; see the README)."""
        return {
            "id": self.id,
            "centroid": [round(float(x), 6) for x in self.centroid],
            "velocity": [round(float(x), 6) for x in self.velocity],
            "bbox": list(self.bbox),
            "pixels": self.pixels,
        }


@dataclass(frozen=True, eq=False)
class TrackedFrame:
    """One frame and what the tracker made of it."""

    frame: Frame
    labels: npt.NDArray[np.uint16]
    """(H, W): 0 background, else the id of the track that owns the pixel (disjoint masks)."""
    tracks: tuple[Track, ...]
    """Every live track, visible or predicted through occlusion."""
    born: tuple[int, ...] = ()
    """Ids of tracks started in this frame."""
    ended: tuple[int, ...] = ()
    """Ids of tracks that ended in this frame (left the view or lost for too long)."""

    @property
    def sequence(self) -> int:
        return self.frame.sequence

    def to_json(self) -> dict[str, object]:
        """The per-frame record of `--tracks-out` (a stable format; see the README)."""
        return {
            "seq": self.frame.sequence,
            "device_time_us": self.frame.device_time_us,
            "tracks": [t.to_json() for t in self.tracks if t.visible],
        }
