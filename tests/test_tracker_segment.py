"""segment(): the energies on synthetic and emulated frames, estimation, invalid pixels,
errors, fast == reference, the benchmark and `tofcut reproduce`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tofcut.driver.errors import TofcutError
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tools.bench.cut_timing import time_cut
from tofcut.tools.experiments.reproduce import deepest_pixel, extent_of, iou
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.paper.segment import Energy, SegmentParams, Target, segment, segment_arrays

H, W = 40, 50


def two_plane_scene(rng: np.random.Generator):
    """A bright square at 1 m in front of a darker wall at 2 m, pinhole rays, mild noise."""
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - W / 2) / 60.0, (v - H / 2) / 60.0, np.ones((H, W))], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    square = (v >= 12) & (v < 28) & (u >= 15) & (u < 33)
    rng_m = np.where(square, 1.0, 2.0) + rng.normal(0, 0.003, (H, W))
    intensity = np.where(square, 2000.0, 1000.0) + rng.normal(0, 10, (H, W))
    xyz = rays * rng_m[..., None]
    return intensity, xyz, np.ones((H, W), bool), square


ALL = list(Energy)


@pytest.mark.parametrize("energy", ALL)
def test_every_energy_finds_an_isolated_square(energy):
    intensity, xyz, valid, square = two_plane_scene(np.random.default_rng(0))
    seg = segment_arrays(intensity, xyz, valid, Target(pixel=(24, 20)), energy)
    assert iou(seg.mask, square) > 0.95
    assert seg.seconds > 0
    assert seg.kind is energy
    ref = segment_arrays(intensity, xyz, valid, Target(pixel=(24, 20)), energy, reference=True)
    assert np.array_equal(seg.mask, ref.mask)
    assert seg.energy == pytest.approx(ref.energy, rel=1e-12)
    assert ref.graph_nodes == H * W


def test_the_model_is_estimated_from_the_frame():
    intensity, xyz, valid, _ = two_plane_scene(np.random.default_rng(1))
    seg = segment_arrays(intensity, xyz, valid, Target(pixel=(24, 20)), Energy.RANGE_DATA)
    m = seg.model
    ref = m.intensity_ref
    assert 2000 < ref < 2050  # the 99th percentile: the bright square
    assert m.mu_target * ref / 255 == pytest.approx(2000, abs=15)
    assert m.mu_background * ref / 255 == pytest.approx(1000, abs=15)
    assert np.linalg.norm(np.array(m.mu_d) - xyz[20, 24]) < 0.01
    seeded = segment_arrays(intensity, xyz, valid, Target(pixel=(24, 20)), Energy.RANGE_SMOOTH)
    # σs: the median neighbour step on the wall (2 m / 60 px per ray unit) dominates
    assert seeded.model.sigma_s == pytest.approx(2.0 / 60, rel=0.2)
    # given values win over estimates
    given = SegmentParams(mu_target=1500.0, mu_background=500.0, sigma_s=0.05, sigma_i=30.0)
    seg2 = segment_arrays(
        intensity, xyz, valid, Target(pixel=(24, 20)), Energy.RANGE_INTENSITY_SMOOTH, given
    )
    assert seg2.model.mu_target * ref / 255 == pytest.approx(1500)
    assert seg2.model.sigma_s == 0.05
    assert seg2.model.sigma_i * ref / 255 == pytest.approx(30.0)


def test_a_point_target_finds_its_pixel_and_a_pixel_target_its_point():
    intensity, xyz, valid, square = two_plane_scene(np.random.default_rng(2))
    point = tuple(float(c) for c in xyz[18, 22])
    seg = segment_arrays(intensity, xyz, valid, Target(point=point), Energy.IMAGE_PLANE)
    assert seg.model.pixel == (22, 18)
    seg = segment_arrays(intensity, xyz, valid, Target(point=point), Energy.RANGE_SMOOTH)
    assert iou(seg.mask, square) > 0.95


@pytest.mark.parametrize("energy", ALL)
def test_invalid_pixels_neither_pull_nor_push(energy):
    rng = np.random.default_rng(3)
    intensity, xyz, valid, square = two_plane_scene(rng)
    invalid = rng.random((H, W)) < 0.15
    invalid[20, 24] = False  # the seed
    valid = ~invalid
    base = segment_arrays(intensity, xyz, valid, Target(pixel=(24, 20)), energy)
    # whatever an invalid pixel holds, nothing changes
    wild_i = intensity.copy()
    wild_i[invalid] = rng.choice([0.0, 1e5, 2000.0], invalid.sum())
    wild_x = xyz.copy()
    wild_x[invalid] = rng.normal(0, 5, (invalid.sum(), 3))
    again = segment_arrays(wild_i, wild_x, valid, Target(pixel=(24, 20)), energy)
    assert np.array_equal(base.mask, again.mask)
    assert base.energy == pytest.approx(again.energy)
    # and valid pixels still find the square
    assert iou(base.mask & valid, square & valid) > 0.9


def test_bad_input_is_reported_clearly():
    intensity, xyz, valid, _ = two_plane_scene(np.random.default_rng(4))
    with pytest.raises(SegmentError, match="seed pixel"):
        Target()
    with pytest.raises(SegmentError, match="two integers"):
        Target(pixel=(1.5, 2))  # type: ignore[arg-type]
    with pytest.raises(SegmentError, match="finite"):
        Target(point=(0.0, float("nan"), 1.0))
    with pytest.raises(SegmentError, match="outside the 50×40 frame"):
        segment_arrays(intensity, xyz, valid, Target(pixel=(50, 3)), Energy.INTENSITY)
    with pytest.raises(SegmentError, match="outside"):
        segment_arrays(intensity, xyz, valid, Target(pixel=(-1, 3)), Energy.RANGE_SMOOTH)
    bad = valid.copy()
    bad[20, 24] = False
    with pytest.raises(SegmentError, match="invalid"):
        segment_arrays(intensity, xyz, bad, Target(pixel=(24, 20)), Energy.RANGE_SMOOTH)
    with pytest.raises(SegmentError, match="no valid pixel"):
        segment_arrays(intensity, xyz, np.zeros_like(valid), Target(pixel=(1, 1)), Energy.INTENSITY)
    with pytest.raises(SegmentError, match="do not match"):
        segment_arrays(intensity, xyz[:, :-1], valid, Target(pixel=(1, 1)), Energy.INTENSITY)
    with pytest.raises(SegmentError, match="Energy"):
        segment_arrays(intensity, xyz, valid, Target(pixel=(1, 1)), "intensity")  # type: ignore[arg-type]
    with pytest.raises(SegmentError, match="beta_range"):
        SegmentParams(beta_range=-1.0)
    with pytest.raises(SegmentError, match="sigma_s"):
        SegmentParams(sigma_s=0.0)
    assert issubclass(SegmentError, TofcutError)


@pytest.fixture(scope="module")
def fig1():
    source = open_scene("paper-fig1", 0)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    return source, frame, truth


@pytest.mark.parametrize("energy", ALL)
@pytest.mark.parametrize("seed", [0, 1])
def test_fast_equals_reference_on_emulated_frames(energy, seed):
    source = open_scene("paper-fig1" if seed == 0 else "paper-fig3", seed)
    frame, truth = decode(source, scene_exposure(source, 0.3 * seed))
    info = source.target
    assert info is not None
    obj = truth.object(info.id)
    target = Target(pixel=deepest_pixel(truth.labels == info.id), point=tuple(obj.centroid))
    params = SegmentParams()
    fast = segment(frame, target, energy, params)
    ref = segment(frame, target, energy, params, reference=True)
    assert fast.energy == pytest.approx(ref.energy, rel=1e-9)
    assert np.array_equal(fast.mask, ref.mask)


@pytest.mark.parametrize(
    ("scene", "name", "energy"),
    [
        ("robot", "robot", Energy.RANGE_SMOOTH),
        ("tools", "wrench", Energy.RANGE_SMOOTH),
        ("tools", "tripod", Energy.RANGE_INTENSITY_SMOOTH),
    ],
)
def test_seeded_fast_equals_reference_where_the_weights_join_whole_surfaces(scene, name, energy):
    # the cases where the window grows to the whole frame and merging does the work
    source = open_scene(scene, 0)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    obj = next(o for o in truth.objects if o.name == name)
    target = Target(pixel=deepest_pixel(truth.labels == obj.id))
    fast = segment(frame, target, energy)
    ref = segment(frame, target, energy, reference=True)
    assert fast.energy == pytest.approx(ref.energy, rel=1e-9)
    assert np.array_equal(fast.mask, ref.mask)
    assert fast.graph_nodes < frame.valid.size


def test_range_penalty_separates_the_look_alikes_that_intensity_cannot(fig1):
    source, frame, truth = fig1
    info = source.target
    extent = extent_of(truth.object(info.id))
    target = Target(pixel=info.seed_pixel, point=tuple(info.centroid), extent_m=extent)
    mask = truth.labels == info.id
    by_range = segment(frame, target, Energy.RANGE_DATA)
    by_intensity = segment(frame, target, Energy.INTENSITY)
    assert iou(by_range.mask, mask) > 0.7
    assert iou(by_intensity.mask, mask) < 0.3
    loose = segment(frame, target, Energy.RANGE_DATA, replace(SegmentParams(), beta_range=0.0))
    assert np.array_equal(loose.mask, by_intensity.mask)  # β = 0 is eq. (5)


def test_a_seed_on_a_highlight_gives_way_to_the_targets_own_intensity():
    # a bright patch on the square (a highlight: 20 of its 288 pixels); the seed on it
    intensity, xyz, valid, square = two_plane_scene(np.random.default_rng(2))
    v, u = np.mgrid[0:H, 0:W]
    patch = (v >= 18) & (v < 23) & (u >= 16) & (u < 20)
    dim = np.where(square & ~patch, intensity - 300.0, intensity)
    target = Target(pixel=(18, 20))
    seed_only = segment_arrays(dim, xyz, valid, target, Energy.RANGE_DATA)
    own = segment_arrays(dim, xyz, valid, replace(target, extent_m=0.3), Energy.RANGE_DATA)
    grey = 255.0 / own.model.intensity_ref
    assert seed_only.model.mu_target == pytest.approx(2000 * grey, abs=15 * grey)
    # the square's median, not its brightest tenth's (the wall's 1000 is out of reach)
    assert own.model.mu_target == pytest.approx(1700 * grey, abs=15 * grey)
    assert iou(own.mask, square) > 0.95
    # a seed on a face that is a third of the target is typical of it: its own stands
    halves = np.where(square & (u >= 21), intensity - 300.0, intensity)
    typical = segment_arrays(halves, xyz, valid, replace(target, extent_m=0.3), Energy.RANGE_DATA)
    assert typical.model.mu_target == pytest.approx(
        segment_arrays(halves, xyz, valid, target, Energy.RANGE_DATA).model.mu_target
    )


def test_figure1_premise_gives_the_3d_penalty_the_target_alone():
    """paper-fig1-premise: eq. (6) with the defaults holds the marked box alone (the paper's
    Fig. 1(b)); on paper-fig1, where two look-alikes touch it and the shading breaks eq. (5),
    it does not."""
    for name in ("paper-fig1-premise", "paper-fig1"):
        source = open_scene(name, 0)
        frame, truth = decode(source, scene_exposure(source, 0.0))
        info = source.target
        extent = extent_of(truth.object(info.id))
        target = Target(pixel=info.seed_pixel, point=tuple(info.centroid), extent_m=extent)
        seg = segment(frame, target, Energy.RANGE_DATA)
        mask = truth.labels == info.id
        if name == "paper-fig1-premise":
            assert iou(seg.mask, mask) > 0.9
            for o in truth.objects:
                other = truth.labels == o.id
                assert o.id == info.id or (seg.mask & other).sum() < 0.1 * other.sum()
        else:
            assert iou(seg.mask, mask) < 0.85


def test_the_benchmark_runs_and_its_labels_agree(fig1):
    source, frame, _truth = fig1
    info = source.target
    for energy, target in (
        (Energy.RANGE_DATA, Target(point=tuple(info.centroid))),
        (Energy.RANGE_INTENSITY_SMOOTH, Target(pixel=info.seed_pixel)),
    ):
        timing = time_cut(frame, target, energy, repeats=1)
        assert timing.identical
        assert timing.pixels == 176 * 144
        assert timing.ratio > 0
        assert timing.cold_ratio > 0
        assert timing.segment_ratio > 0


def test_reproduce_writes_a_report(tmp_path, capsys):
    from tofcut.tools.cli import main

    assert main(["reproduce", "--out", str(tmp_path), "--seeds", "1", "--no-sweep"]) == 0
    out = capsys.readouterr().out
    assert "report:" in out
    text = (tmp_path / "report.md").read_text()
    for heading in ("Figure 1", "Figure 4", "Figure 5"):
        assert heading in text
    assert "of the paper's claims hold where their premise holds" in text
    assert "of the paper's claims hold on the hard scenes" in text
    assert "| support (ours) | grabCut |" in text
    premise, hard, *_ = text.split("Scene `paper-fig1-premise`.")[1].split("Scene `paper-fig1`.")
    assert "Eq. (5) keeps the belt out here" in premise
    assert "Nor does eq. (5) keep the belt out" in hard
    pngs = ("fig1-target-box.png", "fig1-hard-target-box.png", "fig4-robot.png")
    for png in (*pngs, "fig4-hard-robot.png", "fig5-wrench.png"):
        assert (tmp_path / png).stat().st_size > 1000
        assert f"({png})" in text
    assert main(["reproduce", "--out", str(tmp_path), "--seeds", "0"]) == 1
