"""What enters the tracker is checked at its door: the kernels behind it index with it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tofcut.driver.errors import TofcutError
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tracker.tracker import Tracker


def _frames(n: int):
    source = open_scene("conveyor", 0)
    period = source.settings.frame_period * 1e-4
    return source, [decode(source, scene_exposure(source, i * period, i))[0] for i in range(n)]


def test_a_frame_of_another_size_mid_run_is_a_one_line_error():
    source, frames = _frames(4)
    tracker = Tracker(belt=source.belt.geometry)
    for frame in frames[:3]:
        tracker.update(frame)
    header = dataclasses.replace(frames[3].header, width=frames[3].header.width - 1)
    small = dataclasses.replace(
        frames[3], header=header, **{
            name: getattr(frames[3], name)[:, :-1]
            for name in ("phase", "amplitude", "intensity", "range", "valid", "xyz")
        },
    )  # fmt: skip
    with pytest.raises(TofcutError, match="frame in a run of"):
        tracker.update(small)


def test_valid_pixels_with_nan_range_are_taken_as_invalid():
    """Marked valid but not finite, a pixel is tracked exactly as one marked invalid."""
    source, frames = _frames(12)
    with_nan, invalid = Tracker(belt=source.belt.geometry), Tracker(belt=source.belt.geometry)
    for frame in frames:
        rng, xyz, valid = frame.range.copy(), frame.xyz.copy(), frame.valid.copy()
        rng[40:60, 50:90] = np.nan
        xyz[40:60, 50:90] = np.nan
        xyz[10, 10] = np.inf
        valid[40:60, 50:90] = False
        valid[10, 10] = False
        a = with_nan.update(dataclasses.replace(frame, range=rng, xyz=xyz))
        b = invalid.update(dataclasses.replace(frame, range=rng, xyz=xyz, valid=valid))
        np.testing.assert_array_equal(a.labels, b.labels)
        assert all(np.isfinite(t.centroid).all() for t in a.tracks)
    assert a.tracks
