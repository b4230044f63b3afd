"""The support energy (beyond the paper) and the data-driven scale of eq. (6): planes found
in a frame, heights above them, the seed's range-connected part, β from the target's extent
and the range noise; and the scenes where the paper's premises hold."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tools.experiments.reproduce import deepest_pixel, iou
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.paper import energy as en
from tofcut.tracker.paper import support as sp
from tofcut.tracker.paper.segment import Energy, SegmentParams, Target, segment_arrays

H, W = 60, 80
NOISE = 0.004


def box_on_floor(rng: np.random.Generator, height: float = 0.05):
    """A camera 1.2 m above a floor, looking down at 40°, a 20 × 20 cm box of `height` on it;
    range noise NOISE; intensity the same everywhere (only the range can tell)."""
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - W / 2) / 70.0, (v - H / 2) / 70.0, np.ones((H, W))], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    tilt = np.deg2rad(40.0)  # camera y down, z forward; world up is (0, -cos, -sin)·...
    up = np.array([0.0, -np.cos(tilt), -np.sin(tilt)])
    eye_height = 1.2
    centre = eye_height / np.sin(tilt) * np.array([0.0, 0.0, 1.0])  # where the axis meets it
    along = np.array([0.0, np.sin(tilt), -np.cos(tilt)])  # on the floor, away from the camera
    side = np.array([1.0, 0.0, 0.0])

    def hit(offset: float) -> np.ndarray:
        # distance along each ray to the plane up·p = up·centre + offset
        return (up @ centre + offset) / (rays @ up)

    floor_t = hit(0.0)
    top_t = hit(height)
    top = rays * top_t[..., None] - centre
    on_top = (np.abs(top @ side) < 0.1) & (np.abs(top @ along) < 0.1)
    t = np.where(on_top, top_t, floor_t) + rng.normal(0.0, NOISE, (H, W))
    xyz = rays * t[..., None]
    intensity = np.full((H, W), 1000.0) + rng.normal(0.0, 5.0, (H, W))
    return intensity, xyz, np.ones((H, W), bool), on_top


def test_the_floor_is_found_with_its_noise_and_the_box_stands_above_it():
    _intensity, xyz, valid, box = box_on_floor(np.random.default_rng(0))
    planes = sp.find_planes(xyz, valid, en.neighbour_distance(xyz, valid))
    assert len(planes) == 1
    floor = planes[0]
    # the noise along the rays, seen along the normal: σ·cos(ray, normal), about 0.6 σ here
    assert 0.4 * NOISE < floor.sigma_m < 0.8 * NOISE
    assert floor.share == pytest.approx(1.0 - box.mean(), abs=0.02)
    z = sp.heights(xyz, planes)
    assert np.median(z[box]) * floor.sigma_m == pytest.approx(0.05, abs=0.01)
    assert abs(np.median(z[~box])) < 1.0
    assert sp.supports_of(planes, xyz[box][0]) == (floor,)
    assert sp.supports_of(planes, 1.5 * xyz[box][0]) == ()  # behind it: not a support


def test_the_support_energy_cuts_a_box_off_the_floor_it_stands_on():
    intensity, xyz, valid, box = box_on_floor(np.random.default_rng(1))
    seed = deepest_pixel(box)
    seg = segment_arrays(intensity, xyz, valid, Target(pixel=seed), Energy.SUPPORT)
    assert iou(seg.mask, box) > 0.9
    assert seg.model.supports
    assert seg.model.support_height == pytest.approx(2.0)
    # the range alone (§4.2) cannot: the box's sides are continuous with the floor
    plain = segment_arrays(intensity, xyz, valid, Target(pixel=seed), Energy.RANGE_SMOOTH)
    assert iou(plain.mask, box) < 0.5


def test_only_the_part_of_the_minimum_that_reaches_the_seed_is_kept():
    mask = np.zeros((10, 12), bool)
    mask[2:8, 1:5] = True  # the seed's part
    mask[2:8, 5:9] = True  # touching it in the image, 1 m behind
    mask[0, 11] = True  # an island
    xyz = np.zeros((10, 12, 3))
    xyz[..., 2] = 1.0
    xyz[:, 5:, 2] = 2.0
    xyz[..., 0] = np.arange(12) * 0.01
    kept = sp.reached(mask, xyz, np.ones((10, 12), bool), (2, 4), 0.05)
    expected = np.zeros_like(mask)
    expected[2:8, 1:5] = True
    assert np.array_equal(kept, expected)


def mixed(share: float, strength_in: float, strength_out: float) -> tuple[float, float]:
    """Range and strength of a pixel `share` of which sees a bar 1 m away (of strength
    `strength_in` there) and the rest a wall 2 m away: the two returns summed."""
    a_in, a_out = share * strength_in, (1.0 - share) * strength_out
    return (a_in * 1.0 + a_out * 2.0) / (a_in + a_out), a_in + a_out


def bar_before_wall(shares: list[float], strength_in: float, strength_out: float):
    """Three rows: the bar in columns 0-2, mixed pixels of the given bar shares in column 3,
    the wall behind in 4-5; the strength is 1 on the bar, `strength_out` on the wall."""
    xyz = np.zeros((3, 6, 3))
    xyz[..., 2] = 2.0
    xyz[:, :3, 2] = 1.0
    strength = np.ones((3, 6))
    strength[:, 4:] = strength_out
    for row, share in enumerate(shares):
        xyz[row, 3, 2], strength[row, 3] = mixed(share, strength_in, strength_out)
    part = np.zeros((3, 6), bool)
    part[:, :3] = True
    return xyz, strength, part


def test_a_mixed_pixel_on_the_outline_goes_to_the_side_that_fills_most_of_it():
    shares = [0.7, 0.6, 0.4]
    valid = np.ones((3, 6), bool)
    for strength_in, strength_out in ((1.0, 1.0), (1.0, 4.0), (0.2, 1.0)):
        # the wall as strong as the bar, four times stronger, or the bar's surface turned
        # away at its outline so that it returns a fifth of what its inside does: the
        # pixel's own strength tells the shares apart whatever the bar returns there
        xyz, strength, part = bar_before_wall(shares, strength_in, strength_out)
        mask = part.copy()
        mask[:, 3] = True  # the cut took the whole column
        kept = sp.with_mixed_outline(part, mask, xyz, valid, strength)
        assert kept[:, 3].tolist() == [True, True, False], (strength_in, strength_out)
        assert kept[:, :3].all()
        assert not kept[:, 4:].any()
        # the cut took the wall next to the column too: what is behind is read two steps off
        mask[:, 4] = True
        assert np.array_equal(sp.with_mixed_outline(part, mask, xyz, valid, strength), kept)
        # nothing valid seen behind: no evidence the column is the bar's
        hidden = valid.copy()
        hidden[:, 4:] = False
        assert np.array_equal(sp.with_mixed_outline(part, mask, xyz, hidden, strength), part)


def test_beta_follows_the_extent_the_noise_and_the_contrast():
    rng = np.random.default_rng(2)
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - W / 2) / 70.0, (v - H / 2) / 70.0, np.ones((H, W))], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    square = (abs(v - 30) < 10) & (abs(u - 40) < 10)
    xyz = rays * (np.where(square, 1.0, 2.0) + rng.normal(0.0, 0.005, (H, W)))[..., None]
    intensity = np.where(square, 2000.0, 1000.0)
    valid = np.ones((H, W), bool)
    assert en.window_range_noise(xyz, valid, (40, 30), 4) == pytest.approx(0.005, rel=0.3)
    betas = []
    for extent in (0.1, 0.2):
        target = Target(pixel=(40, 30), extent_m=extent)
        m = segment_arrays(intensity, xyz, valid, target, Energy.RANGE_DATA).model
        assert m.extent_m == extent
        margin = extent + 2.0 * m.range_noise_m
        assert m.beta_range * margin**2 == pytest.approx((m.mu_target - m.mu_background) ** 2)
        betas.append(m.beta_range)
    assert betas[0] > 3.0 * betas[1]  # twice the size, about a quarter of β
    given = segment_arrays(
        intensity,
        xyz,
        valid,
        Target(pixel=(40, 30)),
        Energy.RANGE_DATA,
        SegmentParams(beta_range=7.0),
    )
    assert given.model.beta_range == 7.0
    assert given.model.extent_m == SegmentParams().default_extent_m
    with pytest.raises(SegmentError, match="extent"):
        Target(pixel=(1, 1), extent_m=0.0)
    with pytest.raises(SegmentError, match="beta_factor"):
        SegmentParams(beta_factor=0.0)
    with pytest.raises(SegmentError, match="connect_factor"):
        SegmentParams(connect_factor=-1.0)


@pytest.mark.parametrize(
    ("scene", "name"), [("paper-fig4", "robot"), ("paper-fig5", "tripod"), ("robot", "robot")]
)
def test_premise_scenes_give_the_paper_its_result_and_the_hard_ones_need_the_support(scene, name):
    source = open_scene(scene, 0)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    mask = truth.labels == next(o.id for o in truth.objects if o.name == name)
    target = Target(pixel=deepest_pixel(mask))
    paper = segment_arrays(frame.intensity, frame.xyz, frame.valid, target, Energy.RANGE_SMOOTH)
    ours = segment_arrays(frame.intensity, frame.xyz, frame.valid, target, Energy.SUPPORT)
    assert iou(ours.mask, mask) > 0.85
    if scene.startswith("paper-"):
        assert iou(paper.mask, mask) > 0.9
    else:
        assert iou(paper.mask, mask) < 0.2


def test_an_amplitude_of_another_size_is_refused():
    intensity, xyz, valid, _ = box_on_floor(np.random.default_rng(0))
    with pytest.raises(SegmentError, match="amplitude"):
        segment_arrays(
            intensity, xyz, valid, Target(pixel=(40, 30)), Energy.SUPPORT, amplitude=np.ones((2, 2))
        )
