"""Scenes: the built-in files, the TOML format, ground truth against geometry, and its file."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from tofcut.driver.calibration import pixel_rays, project
from tofcut.sim import load_truth, open_scene, save_truth, scene_names
from tofcut.sim.preview import scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import SceneError, parse_scene
from tofcut.sim.truth import truth_path

BUILT_IN = ["conveyor", "paper-fig1", "paper-fig3", "person", "robot", "tools"]
PAPER = ["paper-fig1", "paper-fig3", "person", "robot"]

ROOM = """
duration_s = 10.0
[camera]
position = [0.0, 0.0, 0.0]
look_at = [0.0, 1.0, 0.0]
[[surface]]
shape = "plane"
position = [0.0, 3.0, 0.0]
rotation_deg = [90, 0, 0]
"""


def source_from(text: str) -> SceneSource:
    return SceneSource(parse_scene(tomllib.loads(text)))


def test_the_built_in_scenes_are_listed():
    assert scene_names() == BUILT_IN


@pytest.mark.parametrize("name", BUILT_IN)
def test_every_built_in_scene_renders_with_truth(name):
    src = open_scene(name)
    rendered = src.render(scene_exposure(src, 0.0))
    h, w = src.calibration.height, src.calibration.width
    assert (w, h) == (176, 144)
    assert rendered.taps.shape == (4, h, w)
    assert rendered.taps.dtype == np.uint16
    truth = rendered.truth
    assert truth.labels.shape == (h, w)
    assert np.isfinite(truth.range).all()
    assert [o.id for o in truth.objects] == [o.id for o in src.objects]
    assert any(o.pixels > 50 for o in truth.objects)
    assert src.settings.registers
    assert src.duration_s > 0


@pytest.mark.parametrize("name", PAPER)
def test_paper_scenes_mark_a_target_with_a_seed_inside_it(name):
    src = open_scene(name)
    target = src.target
    assert target is not None
    u, v = target.seed_pixel
    truth = src.truth_at(0.0)
    assert truth.labels[v, u] == target.id
    assert np.linalg.norm(target.seed_point - target.centroid) < 0.5


def test_labels_and_range_match_the_geometry_of_a_sphere():
    src = source_from(
        ROOM + '[[object]]\nshape = "sphere"\nradius = 0.3\nposition = [0.2, 2.0, 0.1]\n'
    )
    truth = src.truth_at(0.0)
    rays = pixel_rays(src.calibration)  # the driver's rays, not the renderer's
    centre = src.scene.camera_from_world.apply(np.array([0.2, 2.0, 0.1]))
    b = rays @ centre
    disc = b * b - (centre @ centre - 0.09)
    inside = disc > 1e-4
    outside = disc < -1e-4
    assert inside.sum() > 500
    assert (truth.labels[inside] == 1).all()
    assert (truth.labels[outside] == 0).all()
    r = b - np.sqrt(np.where(inside, disc, 0.0))
    assert np.allclose(truth.range[inside], r[inside], atol=1e-5)
    ball = truth.object(1)
    assert np.allclose(ball.centroid, centre)
    assert np.allclose(ball.pose[:3, 3], centre)
    assert np.allclose(ball.extent_min, centre - 0.3)
    assert np.allclose(ball.extent_max, centre + 0.3)
    assert ball.pixels == (truth.labels == 1).sum()


def test_labels_of_a_box_cover_its_projected_corners():
    src = source_from(
        ROOM + '[[object]]\nshape = "box"\nsize = [0.4, 0.3, 0.5]\nposition = [-0.3, 2.0, 0.2]\n'
        "rotation_deg = [10, 20, 30]\n"
    )
    truth = src.truth_at(0.0)
    box = truth.object(1)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    corners = (box.pose[:3, :3] @ (signs * [0.2, 0.15, 0.25]).T).T + box.pose[:3, 3]
    uv = project(src.calibration, corners)
    rows, cols = np.nonzero(truth.labels == 1)
    for got, corner in ((cols, uv[:, 0]), (rows, uv[:, 1])):
        # labelled pixel centres lie inside the silhouette, and reach to near its corners
        assert -0.5 < got.min() - corner.min() < 1.5
        assert -0.5 < corner.max() - got.max() < 1.5
    assert np.allclose(box.extent_min, corners.min(axis=0))
    assert np.allclose(box.extent_max, corners.max(axis=0))


def test_boxes_ride_the_belt_enter_and_leave_and_the_scene_loops():
    src = open_scene("conveyor")
    belt = src.belt
    assert belt is not None
    assert belt.speed_mps == 0.25
    a, b = src.truth_at(1.0), src.truth_at(2.0)
    moved = b.object(1).pose[:3, 3] - a.object(1).pose[:3, 3]
    assert np.allclose(moved, belt.geometry.direction * belt.speed_mps)
    seen = np.array(
        [[o.pixels for o in src.truth_at(t).objects] for t in np.arange(0.0, 16.0, 1.0)]
    )
    assert ((seen == 0).any(axis=0) & (seen > 0).any(axis=0)).sum() >= 8
    assert (seen > 0).sum(axis=1).max() >= 3
    assert np.array_equal(src.truth_at(3.0).labels, src.truth_at(3.0 + src.duration_s).labels)


def test_truth_file_round_trips(tmp_path):
    src = open_scene("paper-fig1")
    truths = [src.render(scene_exposure(src, i * 0.02, i)).truth for i in range(3)]
    path = truth_path(tmp_path / "run.tofcap")
    assert path.name == "run.truth.npz"
    save_truth(path, truths)
    back = load_truth(path)
    assert [t.sequence for t in back] == [0, 1, 2]
    for t, u in zip(truths, back, strict=True):
        assert np.array_equal(t.labels, u.labels)
        assert np.array_equal(t.range, u.range)
        assert t.time_s == u.time_s
        assert t.tap_times_s == u.tap_times_s
        for o, p in zip(t.objects, u.objects, strict=True):
            assert (o.id, o.name, o.pixels) == (p.id, p.name, p.pixels)
            assert np.array_equal(o.pose, p.pose)
            assert np.array_equal(o.extent_max, p.extent_max)


def test_scene_file_mistakes_are_reported():
    with pytest.raises(SceneError, match="unknown keys"):
        parse_scene(
            tomllib.loads(ROOM + '[[object]]\nshape = "box"\nsize = [1, 1, 1]\ncolour = 3\n')
        )
    with pytest.raises(SceneError, match="belt"):
        parse_scene(
            tomllib.loads(ROOM + '[[object]]\nshape = "sphere"\nradius = 1\nmotion = "belt"\n')
        )
    with pytest.raises(SceneError):
        open_scene("no-such-scene")


def test_scenes_command_writes_pictures(tmp_path, capsys):
    from tofcut.tools.cli import main

    assert main(["scenes", "--out", str(tmp_path), "paper-fig3"]) == 0
    assert (tmp_path / "paper-fig3.png").stat().st_size > 1000
    assert "paper-fig3" in capsys.readouterr().out
