"""The range noise model: each pixel's noise from its amplitude and intensity."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from tofcut.sim import open_scene
from tofcut.sim.preview import decoded_frames
from tofcut.tracker.noise import range_noise
from tofcut.tracker.tracker import Tracker, TrackerParams


def _frames(name: str, count: int):
    src = open_scene(name, 0)
    return src, list(decoded_frames(src, count))


@pytest.mark.parametrize("name", ["conveyor", "person"])
def test_the_noise_model_matches_the_scatter_of_ranges_over_frames(name):
    # conveyor: ~8 mm at 1.4 m and 30 MHz; person: ~3 cm at 3-5 m and 15 MHz
    _, run = _frames(name, 30)
    first, _ = run[0]
    model = range_noise(first, 0.001)
    ranges = np.stack([f.range for f, _ in run])
    still = first.valid & np.all(np.stack([t.labels == 0 for _, t in run]), axis=0)
    ratio = (ranges.std(axis=0) / model)[still]
    low, mid, high = np.percentile(ratio, [10, 50, 90])
    assert 0.8 < mid < 1.2, (low, mid, high)
    assert low > 0.6, (low, mid, high)
    assert high < 1.5, (low, mid, high)


def test_the_noise_model_has_its_floor_and_no_value_for_invalid_pixels():
    _, [(frame, _)] = _frames("conveyor", 1)
    noise = range_noise(frame, 0.05)
    assert noise[frame.valid].min() == pytest.approx(0.05)
    assert np.isinf(noise[~frame.valid]).all()


def test_a_noisy_scene_does_not_stand_out_of_its_own_scenery():
    # three learning frames alone make many pixels look quieter than they are; the model's
    # noise floor keeps the far wall of the person scene from speckling (without it, 16%
    # of the scenery away from the person stood out in every frame)
    src, run = _frames("person", 30)
    tracker = Tracker(TrackerParams(rigid=False))
    tracker.add_target(pixel=src.target.seed_pixel)
    speckle = []
    for frame, truth in run:
        tracker.update(frame)
        if tracker.background and tracker.background.ready:
            away = ~ndimage.binary_dilation(truth.labels > 0, iterations=15)
            speckle.append(tracker.background.standing_out(frame)[away].mean())
    assert max(speckle) < 0.01, max(speckle)
