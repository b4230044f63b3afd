"""MOTS text files: each frame's instance masks as COCO run-length encodings (`--mots-out`).

The format of MOTS and KITTI MOTS (Voigtlaender et al., *MOTS: Multi-Object Tracking and
Segmentation*, 2019), which TrackEval and the MOTS tools read: one line per object per
frame, space separated,

    time_frame id class_id img_height img_width rle

where `rle` is the object's mask as COCO's compressed RLE, exactly as pycocotools'
`mask.encode` writes it (runs down the columns, starting with a run of 0s, as printable
characters). Masks in one frame never overlap.

As tofcut writes it: `time_frame` is the run-wide frame index from 0 (KITTI MOTS counts from
0; MOTSChallenge counts from 1, like `--mot-out`'s frame, which is this + 1); `id` is the
track's; `class_id` is 1 (KITTI MOTS's "car", its rigid-object class) or, when the run
tracks deformable targets (`--deformable`), 2 ("pedestrian"). Lines come in frame order, a
frame's tracks in `--tracks-out`'s order; a frame with no track has no line.

Read back (`read_mots`), class 10 is KITTI MOTS's ignore region; any other class is an
object.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
import numpy.typing as npt
from pycocotools import mask as coco_mask

from tofcut.tools.pipeline.frame_stamp import frame_index
from tofcut.tools.pipeline.mot import read_lines
from tofcut.tools.pipeline.sources import SourceError
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import TrackedFrame

RIGID_CLASS = 1
"""KITTI MOTS's car: the class written for rigid objects."""
DEFORMABLE_CLASS = 2
"""KITTI MOTS's pedestrian: the class written for deformable targets (`--deformable`)."""
IGNORE_CLASS = 10
"""KITTI MOTS's ignore region (ground truth only)."""


def encode(mask: npt.NDArray[np.bool_]) -> str:
    """A mask (H, W) as COCO's compressed RLE string (pycocotools' `mask.encode`)."""
    rle = coco_mask.encode(np.asfortranarray(mask, dtype=np.uint8))
    counts: bytes = rle["counts"]
    return counts.decode("ascii")


def decode(counts: str, height: int, width: int) -> npt.NDArray[np.bool_]:
    """A COCO compressed RLE string back to its mask (H, W)."""
    rle = {"size": [height, width], "counts": counts.encode("ascii")}
    with warnings.catch_warnings():  # pycocotools' own array, not ours: numpy 2's `copy`
        warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
        return np.asarray(coco_mask.decode(rle), dtype=bool)


@dataclass(frozen=True)
class MotsObject:
    """One line of a MOTS file: one object's mask in one frame."""

    frame: int
    """`time_frame` as the file has it."""
    id: int
    class_id: int
    height: int
    width: int
    counts: str
    """The mask as COCO compressed RLE."""

    @property
    def rle(self) -> dict[str, object]:
        """The mask as pycocotools takes it."""
        return {"size": [self.height, self.width], "counts": self.counts.encode("ascii")}

    def line(self) -> str:
        return f"{self.frame} {self.id} {self.class_id} {self.height} {self.width} {self.counts}"


def frame_objects(
    tracked: TrackedFrame, frame: int, class_id: int = RIGID_CLASS
) -> list[MotsObject]:
    """A tracked frame's visible tracks as MOTS objects (tracks with no pixel left out)."""
    height, width = tracked.labels.shape
    out = []
    for track in tracked.tracks:
        if not track.visible:
            continue
        mask = tracked.labels == track.id
        if mask.any():
            out.append(MotsObject(frame, track.id, class_id, height, width, encode(mask)))
    return out


class MotsWriter:
    """`--mots-out FILE.txt`: MOTS lines (see the module's docstring), written as frames come,
    so a run that fails at its end has lost none."""

    def __init__(self, path: Path, class_id: int = RIGID_CLASS) -> None:
        self._file: IO[str] = path.open("w", encoding="utf-8")
        self._class_id = class_id

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        objects = frame_objects(tracked, frame_index(status), self._class_id)
        if objects:
            self._file.write("".join(o.line() + "\n" for o in objects))
            self._file.flush()

    def close(self) -> None:
        self._file.close()


def parse_line(text: str) -> MotsObject | None:
    """One MOTS line (None for a blank one); ValueError says what is wrong with it."""
    fields = text.split()
    if not fields:
        return None
    if len(fields) != 6:
        raise ValueError(
            f"{len(fields)} fields, not 6 (time_frame id class_id img_height img_width rle)"
        )
    try:
        frame, ident, class_id, height, width = (int(f) for f in fields[:5])
    except ValueError:
        raise ValueError("time_frame, id, class_id, img_height and img_width must be whole "
                         "numbers") from None  # fmt: skip
    if frame < 0 or height < 1 or width < 1:
        raise ValueError("time_frame must be 0 or more, img_height and img_width at least 1")
    obj = MotsObject(frame, ident, class_id, height, width, fields[5])
    try:
        area = int(coco_mask.area(obj.rle))
    except Exception:  # pycocotools raises what its C code meets
        raise ValueError(f"{fields[5][:20]!r} is not a COCO RLE mask") from None
    if area > height * width:
        raise ValueError(f"the RLE mask covers more than {height}x{width} pixels")
    return obj


def read_mots(path: Path) -> list[MotsObject]:
    """Every line of a MOTS file, in file order; a bad line is a one-line SourceError."""
    out = read_lines(path, parse_line, "MOTS line")
    sizes = {(o.height, o.width) for o in out}
    if len(sizes) > 1:
        raise SourceError(f"{path}: masks of more than one size: {sorted(sizes)}")
    return out
