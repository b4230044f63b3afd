"""What enters the tracker is checked at its door: the kernels behind it index with it."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
import pytest

from tofcut.driver.errors import TofcutError
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decoded_frames
from tofcut.tracker import compiled
from tofcut.tracker.background import BackgroundParams
from tofcut.tracker.motion import MotionParams
from tofcut.tracker.tracker import Tracker, TrackerParams


def _frames(n: int):
    source = open_scene("conveyor", 0)
    return source, [frame for frame, _ in decoded_frames(source, n)]


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


def _compiled_signatures() -> dict[str, list[object]]:
    every = {name: f for name, (f, _) in compiled.KERNELS.items()} | compiled.HELPERS
    return {name: list(f.signatures) for name, f in every.items()}


def test_a_float_parameter_given_as_a_whole_number_compiles_no_kernel_again():
    """`TrackerParams(object_cost=8)`: an int reaching the compiled kernels would compile them
    again for int64, mid-run; the parameters take it as 8.0, and the run is the same."""
    whole = {
        "object_cost": 8, "deadband": 1, "background_cap": 40, "unknown_cost": 30,
        "max_hidden_s": 2, "still_s": np.int64(2), "seed_radius_m": 1,
        "background": BackgroundParams(noise_factor=4, min_height_sigmas=np.float32(2.5)),
        "motion": MotionParams(accel_sigma=np.float64(0.5)),
    }  # fmt: skip
    params = TrackerParams(**whole)
    for part in (params, params.background, params.motion):
        hints = typing.get_type_hints(type(part))
        for f in dataclasses.fields(part):
            if hints[f.name] is float:
                assert type(getattr(part, f.name)) is float, f.name
    assert params == TrackerParams(
        **{k: float(v) for k, v in whole.items() if k not in ("background", "motion")}
    )
    source, frames = _frames(8)
    as_floats, as_given = (Tracker(p, belt=source.belt.geometry) for p in (TrackerParams(), params))
    warm = _compiled_signatures()
    for frame in frames:
        a, b = as_floats.update(frame), as_given.update(frame)
        np.testing.assert_array_equal(a.labels, b.labels)
    assert b.tracks
    assert _compiled_signatures() == warm


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"beta": True}, "TrackerParams.beta must be a number, got True"),
        ({"smoothness": "0.8"}, "TrackerParams.smoothness must be a number"),
        ({"motion": {"accel_sigma": 1.0}}, "TrackerParams.motion must be a MotionParams"),
        ({"gate_m": 10**400}, "TrackerParams.gate_m is too large"),
    ],
)
def test_a_parameter_that_is_not_a_number_is_a_one_line_error(given, message):
    with pytest.raises(TofcutError, match=message):
        TrackerParams(**given)


@pytest.mark.parametrize("value", [True, None, "0.02"])
def test_a_background_parameter_that_is_not_a_number_is_a_one_line_error(value):
    with pytest.raises(TofcutError, match=r"BackgroundParams\.rate must be a number"):
        BackgroundParams(rate=value)
