"""Ground truth of rendered frames, and its file beside a capture (`NAME.truth.npz`).

Labels: 0 is the background (belt, floor, stand, walls); objects are numbered from 1 in
the order of the scene file. Range is the true radial distance of each pixel centre at the
frame's mid time, metres (inf where the ray hits nothing). Poses, centroids and extents are
in camera coordinates (x right, y down, z forward) at that time; an object's size is in its
own frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from tofcut._types import F64


@dataclass(frozen=True, eq=False)
class ObjectTruth:
    """Where one object is in one frame."""

    id: int
    name: str
    pose: F64
    """4×4 camera-from-object transform."""
    centroid: F64
    """Volume-weighted centre of the object's parts, (3,)."""
    extent_min: F64
    """Axis-aligned 3D box around the object in camera coordinates: lower corner, (3,)."""
    extent_max: F64
    size: F64
    """Edges of the object's own 3D box: the box round its parts in its body frame, so the
    same however the object is turned (nan in files written before it was kept), (3,)."""
    pixels: int
    """How many pixels show the object (0: out of view or hidden)."""


@dataclass(frozen=True, eq=False)
class FrameTruth:
    """What a frame really showed: per-pixel object ids and range, and each object's place."""

    sequence: int
    time_s: float
    """Device time of the middle of the frame (between taps 1 and 2), seconds."""
    tap_times_s: tuple[float, float, float, float]
    labels: npt.NDArray[np.int32]
    """(H, W) object id per pixel, 0 = background."""
    range: npt.NDArray[np.float32]
    """(H, W) true radial distance, metres."""
    objects: tuple[ObjectTruth, ...]

    def object(self, object_id: int) -> ObjectTruth:
        """The truth of one object by id."""
        for obj in self.objects:
            if obj.id == object_id:
                return obj
        raise KeyError(object_id)


def truth_path(capture: str | Path) -> Path:
    """Where the truth of a capture lives: `NAME.tofcap` → `NAME.truth.npz`."""
    p = Path(capture)
    return p.with_name(p.name.removesuffix(".tofcap") + ".truth.npz")


def save_truth(path: str | Path, truths: Sequence[FrameTruth]) -> None:
    """Write frames' truth as one compressed npz (objects flattened with per-frame counts)."""
    if not truths:
        raise ValueError("no frames to save")
    objs = [o for t in truths for o in t.objects]
    np.savez_compressed(
        path,
        version=np.array(2),
        sequence=np.array([t.sequence for t in truths], np.int64),
        time_s=np.array([t.time_s for t in truths], np.float64),
        tap_times_s=np.array([t.tap_times_s for t in truths], np.float64),
        labels=np.stack([t.labels for t in truths]).astype(np.int32),
        range=np.stack([t.range for t in truths]).astype(np.float32),
        object_count=np.array([len(t.objects) for t in truths], np.int64),
        object_id=np.array([o.id for o in objs], np.int64),
        object_name=np.array([o.name for o in objs], dtype=str),
        object_pose=np.array([o.pose for o in objs], np.float64).reshape(-1, 4, 4),
        object_centroid=np.array([o.centroid for o in objs], np.float64).reshape(-1, 3),
        object_extent_min=np.array([o.extent_min for o in objs], np.float64).reshape(-1, 3),
        object_extent_max=np.array([o.extent_max for o in objs], np.float64).reshape(-1, 3),
        object_size=np.array([o.size for o in objs], np.float64).reshape(-1, 3),
        object_pixels=np.array([o.pixels for o in objs], np.int64),
    )


def load_truth(path: str | Path) -> list[FrameTruth]:
    """Read what `save_truth` wrote."""
    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    d.setdefault("object_size", np.full((len(d["object_id"]), 3), np.nan))  # version 1
    ends = np.cumsum(d["object_count"])
    starts = ends - d["object_count"]
    frames = []
    for i, (a, b) in enumerate(zip(starts, ends, strict=True)):
        objects = tuple(
            ObjectTruth(
                int(d["object_id"][j]),
                str(d["object_name"][j]),
                d["object_pose"][j],
                d["object_centroid"][j],
                d["object_extent_min"][j],
                d["object_extent_max"][j],
                d["object_size"][j],
                int(d["object_pixels"][j]),
            )
            for j in range(a, b)
        )
        taps = tuple(float(x) for x in d["tap_times_s"][i])
        frames.append(
            FrameTruth(
                int(d["sequence"][i]),
                float(d["time_s"][i]),
                (taps[0], taps[1], taps[2], taps[3]),
                d["labels"][i],
                d["range"][i],
                objects,
            )
        )
    return frames
