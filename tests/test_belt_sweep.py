"""Which layer is the belt, told by what moves over it (`tofcut.tracker.belt_sweep`): heights
over time made by hand, with a floor below, a belt that boxes pass over, and box tops."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.tracker.belt_sweep import (
    SweepParams,
    SweepWindow,
    SweptLayer,
    choose_swept,
    median_heights,
    swept_layers,
)

FLOOR, BELT, TOP = -2.7, -2.2, -2.0
"""Offsets n·p of the layers (the camera 2.7 m above the floor, 2.2 m above the belt)."""


def _line(samples: int = 20, pixels: int = 300, seed: int = 0) -> np.ndarray:
    """(samples, pixels) heights: pixels 0-99 floor, 100-299 belt, with a 0.2 m box 50 pixels
    long passing over the belt 5 pixels a sample; noise 1 cm."""
    rng = np.random.default_rng(seed)
    h = np.empty((samples, pixels), np.float32)
    h[:, :100] = FLOOR
    h[:, 100:] = BELT
    for t in range(samples):
        start = 100 + 5 * t
        h[t, start : start + 50] = TOP
    return h + rng.normal(0, 0.01, h.shape).astype(np.float32)


def _score(h: np.ndarray, layers: list[float]) -> list[SweptLayer]:
    ok = np.ones(h.shape, bool)
    sigma = np.full(h.shape, 0.01, np.float32)
    band = np.full(h.shape, 0.02, np.float32)
    return swept_layers(h, ok, sigma, layers, band, SweepParams())


def test_the_belt_is_swept_the_floor_and_the_box_top_are_not():
    floor, belt, top = _score(_line(), [FLOOR, BELT, TOP])
    assert floor.swept == 0  # never covered
    assert top.swept == 0  # the belt is seen below the box top once the box moves on
    # every belt pixel the box went over and left again: on, above, never below
    assert 120 <= belt.swept <= 200
    assert belt.rms_m == pytest.approx(0.01, rel=0.2)
    chosen = choose_swept([floor, belt, top], 300, SweepParams())
    assert chosen is belt


def test_in_loud_noise_a_layer_of_low_tops_is_not_the_belt():
    # a packed line in 6 cm of noise: low boxes (13 cm) and tall ones (35 cm) by turns, the
    # belt between them; the heights are 3x3 medians (noise 0.418 of a reading's). The belt
    # seen 13 cm below a low top parts that top from the belt, though not 3 readings' sigmas
    rng = np.random.default_rng(2)
    samples, pixels = 40, 300
    h = np.full((samples, pixels), BELT, np.float32)
    for t in range(samples):
        for k, start in enumerate(range(-400, 300, 50)):
            a, b = max(0, start + 3 * t), max(0, start + 3 * t + 44)
            h[t, a:b] = BELT + (0.13 if k % 2 else 0.35)
    h += rng.normal(0, 0.06 * 0.418, h.shape).astype(np.float32)
    ok = np.ones(h.shape, bool)
    sigma = np.full(h.shape, 0.06, np.float32)
    band = np.full(h.shape, 0.03, np.float32)
    belt, low = swept_layers(h, ok, sigma, [BELT, BELT + 0.13], band, SweepParams())
    assert low.swept < 0.1 * belt.swept
    assert choose_swept([belt, low], pixels, SweepParams()) is belt


def test_a_layer_of_tops_that_went_over_the_belt_is_not_the_belt():
    # a line that starts full: a big low box (15 cm, 150 pixels) with a taller one (30 cm)
    # nose to tail behind it. In the first second the pixels the low top leaves are covered by
    # the tall one, never showing the belt: the low tops are swept nearly as much as the belt
    rng = np.random.default_rng(3)
    samples, pixels, low, tall = 10, 300, BELT + 0.15, BELT + 0.3
    h = np.full((samples, pixels), BELT, np.float32)
    for t in range(samples):
        front = 100 + 5 * t
        h[t, front : front + 150] = low
        h[t, max(0, front - 200) : front] = tall
    h += rng.normal(0, 0.01, h.shape).astype(np.float32)
    belt, tops = _score(h, [BELT, low])
    assert tops.swept >= SweepParams().nearer_share * belt.swept
    # but the belt's swept pixels were seen on the low tops as well: those went over it
    assert belt.shared[low] >= 0.9 * belt.swept
    assert tops.shared[BELT] == 0
    assert choose_swept([belt, tops], pixels, SweepParams()) is belt
    assert choose_swept([belt, tops], pixels, SweepParams(max_shared=1.0)) is tops


def test_a_far_surface_read_near_by_its_wrapped_phase_is_not_swept():
    # the floor's far pixels lie near the unambiguous range: noise throws their phase round
    # and back, so by turns they read the floor and a point 10 cm from the camera. Nothing
    # stands that high on a layer; before a box came by, such a floor outscored the belt
    # (line 1783)
    h = _line(samples=30)
    flicker = np.random.default_rng(4).random((30, 100)) < 0.3
    h[:, :100][flicker] = -0.1
    floor, belt, _ = _score(h, [FLOOR, BELT, TOP])
    assert floor.swept == 0
    assert choose_swept([floor, belt], 300, SweepParams()) is belt


def test_noise_alone_sweeps_nothing():
    h = _line()
    h[:, 100:] = BELT + np.random.default_rng(1).normal(0, 0.01, h[:, 100:].shape)
    scored = _score(h, [FLOOR, BELT, TOP])
    assert all(lay.swept == 0 for lay in scored)
    assert choose_swept(scored, 300, SweepParams()) is None


def test_a_nearer_layer_half_as_swept_wins_only_when_clearly_apart():
    p = SweepParams()
    floor = SweptLayer(FLOOR, 1000, 0.01, 5000)
    belt = SweptLayer(BELT, 600, 0.01, 3000)
    assert choose_swept([floor, belt], 10_000, p) is belt  # occlusion at a tilt: floor first
    twin = SweptLayer(BELT + 0.03, 900, 0.01, 3000)  # a second peak of one layer
    assert choose_swept([SweptLayer(BELT, 1000, 0.01, 3000), twin], 10_000, p).offset_m == BELT
    weak = SweptLayer(BELT, 400, 0.01, 3000)
    assert choose_swept([floor, weak], 10_000, p) is floor
    assert choose_swept([floor], 200_000, p) is None  # too little swept to say
    assert choose_swept([], 100, p) is None


def test_median_heights_leave_out_unusable_pixels_and_lone_outliers():
    xyz = np.zeros((5, 5, 3))
    xyz[..., 2] = 2.0
    xyz[2, 2, 2] = 7.0  # a wrapped reading
    ok = np.ones((5, 5), bool)
    ok[0, 0] = False
    h, usable = median_heights(xyz, ok, np.array([0.0, 0.0, -1.0]))
    assert h[2, 2] == pytest.approx(-2.0)
    assert not usable[0, 0]
    assert usable[1, 1]


def test_the_window_samples_at_its_pace_and_keeps_its_last_seconds():
    p = SweepParams(every_s=0.1, window_s=0.5, first_s=0.3, judge_every_s=0.2, max_pixels=16)
    w = SweepWindow((8, 8), np.array([0.0, 0.0, -1.0]), p)
    assert w.pixels == 16  # an even grid of at most max_pixels
    xyz = np.zeros((8, 8, 3))
    xyz[..., 2] = 2.0
    ok = np.ones((8, 8), bool)
    sigma = np.full((8, 8), 0.01)
    taken = [w.add(xyz, ok, sigma, t) for t in np.arange(0, 1.0, 0.05)]
    assert sum(taken) == 10
    assert w.filled == 5
    assert not SweepWindow((8, 8), np.array([0.0, 0.0, -1.0]), p).due(10.0)
    assert w.due(1.0)
    heights, usable, noise = w.judged(1.0)
    assert heights.shape == usable.shape == noise.shape == (5, 16)
    assert not w.due(1.1)
    assert w.due(1.2)


@pytest.mark.parametrize(
    "bad",
    [
        {"every_s": 0},
        {"min_share": 1.5},
        {"nearer_share": 0},
        {"max_pixels": 0},
        {"min_times": 0},
        {"max_shared": 1.5},
    ],
)
def test_the_parameters_are_checked(bad):
    with pytest.raises(ValueError, match=r"must|share|>= 1"):
        SweepParams(**bad)
