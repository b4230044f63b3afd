"""A plain baseline tracker: depth background subtraction, 3D-cut components, Norfair.

`python -m tofcut.tools.evaluation.baseline CAPTURE.tofcap --tracks-out T.jsonl --masks-out M.npz`
writes the formats `tofcut track` writes, so `tofcut evaluate` scores both alike: each row
and mask stamped with the run-wide frame index, the camera's sequence and time and the
host time (`tofcut.tools.pipeline.frame_stamp`). It reads
nothing but the camera's stream (no metadata) and its parameters are the same on every line:
it is the number a graph cut has to beat.

Per frame: the empty scene is the per-pixel median range of the first `LEARN_FRAMES` frames
(nothing is reported for them), followed at `RATE` a frame wherever nothing stands out, and
moved back where the scene reads farther for `REVEAL_FRAMES` frames in a row (an object
stood there while it was learned), to the nearest of those readings (a far one may be a
mixed pixel at a moving edge). A
valid pixel stands out when it is nearer than that by `STAND_OUT_M` or `NOISE_SIGMAS` of the
pixel's own spread over the learning frames, whichever is more. What stands out is split
into 4-connected components, cut wherever two neighbours' 3D points are `STEP_M` or more
apart; components under `MIN_PIXELS` are dropped. Norfair follows their 3D centroids (its
Kalman filter; a track is reported from its second detection and lives `HIT_MAX` frames
unseen); a component is labelled with the id of the track it was matched to this frame.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tofcut._types import F64
from tofcut.driver.capture import CaptureReader
from tofcut.driver.errors import TofcutError
from tofcut.driver.frames import Frame
from tofcut.tools.pipeline.frame_stamp import FrameStamp
from tofcut.tracker.stats import MAD_TO_SIGMA

LEARN_FRAMES = 10
RATE = 0.05
REVEAL_FRAMES = 5
STAND_OUT_M = 0.03
NOISE_SIGMAS = 4.0
STEP_M = 0.03
MIN_PIXELS = 50
MATCH_M = 0.1
"""Norfair's distance threshold: a detection this far from a track's prediction is another."""
HIT_MAX = 15


def components(stands_out: npt.NDArray[np.bool_], xyz: F64) -> tuple[npt.NDArray[np.int64], int]:
    """Per-pixel component index (-1: none) of 4-neighbours closer in 3D than `STEP_M`."""
    index = np.full(stands_out.shape, -1, np.int64)
    index[stands_out] = np.arange(int(stands_out.sum()))
    rows, cols = [], []
    for a, b in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                 ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):  # fmt: skip
        near = np.linalg.norm(xyz[a] - xyz[b], axis=-1) < STEP_M
        edge = stands_out[a] & stands_out[b] & near
        rows.append(index[a][edge])
        cols.append(index[b][edge])
    n = int(stands_out.sum())
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(r.size), (r, c)), shape=(n, n))
    count, which = connected_components(graph, directed=False)
    sizes = np.bincount(which, minlength=count)
    keep = np.cumsum(sizes >= MIN_PIXELS) - 1  # kept components renumbered from 0
    index[stands_out] = np.where(sizes[which] >= MIN_PIXELS, keep[which], -1)
    return index, int((sizes >= MIN_PIXELS).sum())


class EmptyScene:
    """The range each pixel sees when nothing stands in front of it, from the frames alone."""

    def __init__(self) -> None:
        self._learning: list[F64] = []
        self.model = self._spread = self._nearest = np.zeros(0)
        self._farther = np.zeros(0, np.int64)

    def stands_out(self, frame: Frame) -> npt.NDArray[np.bool_] | None:
        """Where `frame` stands out of the empty scene (None while it is learned); then the
        model follows the frame where nothing stands out (see the module's docstring)."""
        seen = np.where(frame.valid, frame.range, np.nan)
        if len(self._learning) < LEARN_FRAMES:
            self._learning.append(seen)
            if len(self._learning) < LEARN_FRAMES:
                return None
            stack = np.array(self._learning)
            self.model = np.nanmedian(stack, axis=0)
            mad = np.nanmedian(np.abs(stack - self.model), axis=0)
            self._spread = np.fmax(STAND_OUT_M, NOISE_SIGMAS * MAD_TO_SIGMA * mad)
            self._farther = np.zeros(seen.shape, np.int64)
            self._nearest = np.full(seen.shape, np.inf)
            return None
        model, spread = self.model, self._spread
        stands_out = frame.valid & (model - seen > spread)  # False where the model is nan
        behind = frame.valid & (seen - model > spread)
        self._farther = np.where(behind, self._farther + 1, 0)
        self._nearest = np.where(behind, np.fmin(self._nearest, seen), np.inf)
        quiet = frame.valid & ~stands_out & ~behind
        model[quiet] += RATE * (seen[quiet] - model[quiet])
        revealed = self._farther >= REVEAL_FRAMES
        model[revealed] = self._nearest[revealed]  # the run's nearest: not an edge's outlier
        self._farther[revealed], self._nearest[revealed] = 0, np.inf
        unknown = frame.valid & np.isnan(model)
        model[unknown] = seen[unknown]
        return stands_out


def track(frames: Iterable[Frame]) -> tuple[list[dict[str, Any]], list[npt.NDArray[np.uint16]]]:
    """Track every frame: its `--tracks-out` record and its label image."""
    from norfair import Detection, OptimizedKalmanFilterFactory, Tracker

    # Norfair's defaults are in pixels; the same filter in metres (variances × 1e-4)
    kalman = OptimizedKalmanFilterFactory(R=4e-4, Q=1e-5, pos_variance=1e-3, vel_variance=1e-4)
    norfair = Tracker("mean_euclidean", MATCH_M, hit_counter_max=HIT_MAX,
                      initialization_delay=1, filter_factory=kalman)  # fmt: skip
    scene = EmptyScene()
    last: dict[int, tuple[float, F64]] = {}
    records, masks = [], []
    for n, frame in enumerate(frames):
        labels = np.zeros(frame.shape, np.uint16)
        tracks: list[dict[str, Any]] = []
        stands_out = scene.stands_out(frame)
        if stands_out is not None:
            index, count = components(stands_out, frame.xyz)
            flat = index.ravel()
            sums = np.zeros((count, 3))
            np.add.at(sums, flat[flat >= 0], frame.xyz.reshape(-1, 3)[flat >= 0])
            centres = sums / np.bincount(flat[flat >= 0], minlength=count)[:, None]
            found = [Detection(points=c[None, :], data=k) for k, c in enumerate(centres)]
            t = frame.device_time_us * 1e-6
            for obj in norfair.update(found):
                k = obj.last_detection.data
                if k >= len(found) or obj.last_detection is not found[k]:
                    continue  # not seen in this frame
                mine = index == k
                labels[mine] = obj.id
                v, u = np.nonzero(mine)
                then = last.get(obj.id)
                velocity = np.zeros(3)
                if then is not None and t > then[0]:
                    velocity = (centres[k] - then[1]) / (t - then[0])
                last[obj.id] = (t, centres[k])
                tracks.append({"id": int(obj.id), "centroid": centres[k].tolist(),
                               "velocity": velocity.tolist(),
                               "bbox": [int(u.min()), int(v.min()), int(u.max()) + 1,
                                        int(v.max()) + 1], "pixels": int(mine.sum())})  # fmt: skip
        stamp = FrameStamp(n, frame.sequence, frame.device_time_us, frame.host_time_ns)
        records.append({**stamp.to_json(), "tracks": tracks})
        masks.append(labels)
    return records, masks


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m tofcut.tools.evaluation.baseline", description=__doc__
    )
    p.add_argument("capture", type=Path, metavar="CAPTURE.tofcap")
    p.add_argument("--tracks-out", type=Path, required=True, metavar="FILE.jsonl")
    p.add_argument("--masks-out", type=Path, required=True, metavar="FILE.npz")
    p.add_argument("--frames", type=int, help="stop after this many frames")
    args = p.parse_args(argv)
    try:
        import norfair  # noqa: F401
    except ImportError:
        print("baseline: error: needs norfair, a dev dependency (scripts/uv sync)", file=sys.stderr)
        return 1
    try:
        reader = CaptureReader(args.capture)
        records, masks = track(reader.frames(args.frames))
    except (TofcutError, OSError) as exc:
        print(f"baseline: error: {args.capture}: {exc}", file=sys.stderr)
        return 1
    with args.tracks_out.open("w", encoding="utf-8") as f:
        f.writelines(json.dumps(r, separators=(",", ":")) + "\n" for r in records)
    shape = (reader.info.height, reader.info.width)
    labels = np.array(masks, np.uint16).reshape(-1, *shape)
    seqs = np.array([r["seq"] for r in records], np.int64)
    index = np.array([r["frame"] for r in records], np.int64)
    np.savez_compressed(args.masks_out, labels=labels, seq=seqs, frame=index)
    ids = {t["id"] for r in records for t in r["tracks"]}
    print(f"baseline: tracked {len(records)} frames: {len(ids)} tracks; wrote {args.tracks_out}, "
          f"{args.masks_out}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
