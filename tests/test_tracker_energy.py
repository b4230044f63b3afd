"""The compiled energy terms and frame statistics against their plain numpy formulas, on
emulated frames and random arrays (invalid pixels, edges, odd and even counts)."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tracker.neighbours import OFFSETS, pair_slices
from tofcut.tracker.paper import energy as en

# --- the formulas in plain numpy ------------------------------------------------------------


def numpy_range_penalty(xyz, valid, mu_d, beta):
    d2 = ((xyz - mu_d) ** 2).sum(axis=-1)
    return np.where(valid, beta * d2, 0.0)


def numpy_range_weights(xyz, valid, sigma_s, grey=None, sigma_i=None, squared=True):
    weights = np.zeros((len(OFFSETS), *valid.shape))
    for k in range(len(OFFSETS)):
        sp, sq = pair_slices(valid.shape, k)
        d2 = ((xyz[sp] - xyz[sq]) ** 2).sum(axis=-1)
        exponent = (d2 if squared else np.sqrt(d2)) / (-2.0 * sigma_s**2)
        if grey is not None:
            exponent -= (grey[sp] - grey[sq]) ** 2 / (2.0 * sigma_i**2)
        both = valid[sp] & valid[sq]
        weights[k][sp] = np.where(both, np.exp(np.where(both, exponent, 0.0)), 0.0)
    return weights


def numpy_background_intensity(grey, valid, xyz, mu_d, margin_m):
    points = np.atleast_2d(mu_d)
    d2 = ((xyz[..., None, :] - points) ** 2).sum(axis=-1)
    far = valid & (d2 > margin_m**2).all(axis=-1)
    return float(np.median(grey[far if far.any() else valid]))


def numpy_nearest_pixel(xyz, valid, point):
    norm = np.linalg.norm(xyz, axis=-1)
    cosine = (xyz @ point) / np.maximum(norm * float(np.linalg.norm(point)), 1e-12)
    cosine = np.where(valid & (norm > 0), cosine, -np.inf)
    v, u = np.unravel_index(int(np.argmax(cosine)), cosine.shape)
    return int(u), int(v)


def numpy_neighbour_steps(values, valid):
    """|a_p − a_q| (the 3D distance for (H, W, 3) values) of valid east and south pairs."""
    steps = []
    for k in (0, 1):
        sp, sq = pair_slices(valid.shape, k)
        diff = values[sp] - values[sq]
        size = np.sqrt((diff**2).sum(axis=-1)) if values.ndim == 3 else np.abs(diff)
        steps.append(size[valid[sp] & valid[sq]])
    return np.concatenate(steps)


# --- frames -----------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=[("paper-fig1", 0), ("tools", 1)])
def frame(request):
    scene, seed = request.param
    source = open_scene(scene, seed)
    frame, _ = decode(source, scene_exposure(source, 0.0))
    return frame


def random_frame(seed: int):
    rng = np.random.default_rng(seed)
    h, w = (int(x) for x in rng.integers(1, 30, 2))
    xyz = rng.normal(size=(h, w, 3)) * rng.uniform(0.01, 3.0)
    grey = rng.random((h, w)) * 255
    valid = rng.random((h, w)) < rng.uniform(0.0, 1.0)
    return xyz, grey, valid


def test_range_terms_match_numpy_on_emulated_frames(frame):
    xyz, valid = frame.xyz, frame.valid
    grey = en.grey_levels(frame.intensity, valid)
    mu_d = xyz[70, 90].copy()
    assert np.array_equal(
        en.range_penalty(xyz, valid, mu_d, 2e5), numpy_range_penalty(xyz, valid, mu_d, 2e5)
    )
    sigma_s = en.neighbour_distance(xyz, valid)
    sigma_i = 3 * en.neighbour_step(grey, valid)
    for args in ((), (grey, sigma_i)):
        for squared in (True, False):
            got = en.range_weights(xyz, valid, sigma_s, *args, squared=squared)
            want = numpy_range_weights(xyz, valid, sigma_s, *args, squared=squared)
            assert np.array_equal(got == 0, want == 0)
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)


def test_frame_statistics_match_numpy_on_emulated_frames(frame):
    xyz, valid = frame.xyz, frame.valid
    grey = en.grey_levels(frame.intensity, valid)
    assert en.neighbour_distance(xyz, valid) == np.median(numpy_neighbour_steps(xyz, valid))
    assert en.neighbour_step(grey, valid) == np.median(numpy_neighbour_steps(grey, valid))
    for point in (xyz[70, 90], xyz[10, 150], np.array([0.3, -0.2, 1.0])):
        assert en.nearest_pixel(xyz, valid, point) == numpy_nearest_pixel(xyz, valid, point)
        for margin in (0.0, 0.3, 100.0):  # 100 m: no pixel is far, all valid ones count
            assert en.background_intensity(
                grey, valid, xyz, point, margin
            ) == numpy_background_intensity(grey, valid, xyz, point, margin)
    points = np.stack([xyz[70, 90], xyz[10, 150]])
    assert en.background_intensity(grey, valid, xyz, points, 0.3) == (
        numpy_background_intensity(grey, valid, xyz, points, 0.3)
    )


@pytest.mark.parametrize("seed", range(30))
def test_energy_terms_match_numpy_on_random_frames(seed):
    xyz, grey, valid = random_frame(seed)
    point = xyz.reshape(-1, 3)[0] + 0.1
    assert np.array_equal(
        en.range_penalty(xyz, valid, point, 3.0), numpy_range_penalty(xyz, valid, point, 3.0)
    )
    np.testing.assert_allclose(
        en.range_weights(xyz, valid, 0.7, grey, 20.0),
        numpy_range_weights(xyz, valid, 0.7, grey, 20.0),
        rtol=1e-12,
        atol=0,
    )
    steps = numpy_neighbour_steps(xyz, valid)
    assert en.neighbour_distance(xyz, valid) == (np.median(steps) if steps.size else 0.0)
    steps = numpy_neighbour_steps(grey, valid)
    assert en.neighbour_step(grey, valid) == (np.median(steps) if steps.size else 0.0)
    if valid.any():
        assert en.nearest_pixel(xyz, valid, point) == numpy_nearest_pixel(xyz, valid, point)
        assert en.background_intensity(grey, valid, xyz, point, 1.0) == (
            numpy_background_intensity(grey, valid, xyz, point, 1.0)
        )


@pytest.mark.parametrize("n", [1, 2, 3, 4, 255, 256, 257, 1000, 30001])
def test_median_is_numpys_bit_for_bit(n):
    rng = np.random.default_rng(n)
    cases = [
        rng.random(n),
        rng.random(n) ** 12,  # most values in the first histogram bin
        np.exp(rng.normal(size=n) * 30),  # spread over hundreds of orders of magnitude
        rng.integers(0, 4, n).astype(float),  # ties
        np.full(n, -2.5),
        np.append(np.full(n, 1.0), 1e300),
    ]
    for values in cases:
        assert en.median(values) == np.median(values)
    with_inf = rng.random(n + 2)
    with_inf[0], with_inf[-1] = np.inf, -np.inf
    assert en.median(with_inf) == np.median(with_inf)
    with_inf[n // 2] = np.nan
    assert np.isnan(en.median(with_inf))


@pytest.mark.parametrize("n", [1, 2, 3, 99, 100, 101, 2000, 30001])
def test_percentile_is_numpys_bit_for_bit(n):
    rng = np.random.default_rng(100 + n)
    cases = [
        rng.random(n),
        rng.random(n) ** 12,
        np.exp(rng.normal(size=n) * 30),
        rng.integers(0, 3, n).astype(float),
    ]
    for values in cases:
        for q in (0.0, 37.3, 50.0, en.GREY_PERCENTILE, 100.0):
            assert en.percentile(values, q) == np.percentile(values, q)


def test_intensity_costs_match_numpy():
    rng = np.random.default_rng(8)
    grey, valid = rng.random((13, 17)) * 255, rng.random((13, 17)) < 0.7
    cost1, cost0 = en.intensity_costs(grey, valid, 200.0, 40.0)
    assert np.array_equal(cost1, np.where(valid, (grey - 200.0) ** 2, 0.0))
    assert np.array_equal(cost0, np.where(valid, (grey - 40.0) ** 2, 0.0))
