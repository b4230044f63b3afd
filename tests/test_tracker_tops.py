"""Touching objects on a belt told apart by their tops (`tofcut.tracker.tops`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from tofcut.driver.belt import BeltGeometry
from tofcut.sim.preview import decode, scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import parse_scene
from tofcut.tracker import components_kernels, measure_kernels, tops_kernels
from tofcut.tracker.noise import range_noise
from tofcut.tracker.roster import _box_of, _on_level
from tofcut.tracker.tops import (
    BASELINE,
    MAX_SLOPE,
    MAX_SLOPE_NOISE,
    facing_up,
    one_object,
    sides_of,
    split_by_tops,
)


def _pair(first_h: float, second_h: float, side_by_side: bool) -> SceneSource:
    """Two boxes pressed together on a belt, seen from above and to one side."""
    a, b = ([0.0, -0.1], [0.0, 0.1]) if side_by_side else ([-0.1, 0.0], [0.1, 0.0])
    doc = {
        "name": "pair",
        "duration_s": 10.0,
        "camera": {"position": [-0.5, -0.4, 1.3], "look_at": [0.0, 0.0, 0.0], "fps": 50},
        "belt": {"width": 0.6, "speed": 0.0, "albedo": 0.45},
        "object": [
            {"name": "a", "shape": "box", "size": [0.2, 0.2, first_h], "albedo": 0.45,
             "position": [*a, first_h / 2], "motion": "static"},
            {"name": "b", "shape": "box", "size": [0.2, 0.2, second_h], "albedo": 0.45,
             "position": [*b, second_h / 2], "motion": "static"},
        ],
    }  # fmt: skip
    return SceneSource(parse_scene(doc), seed=3)


def _split(source: SceneSource) -> tuple[np.ndarray, np.ndarray]:
    frame, truth = decode(source, scene_exposure(source, 0.0))
    body = (truth.labels > 0) & frame.valid
    noise = range_noise(frame, 0.004)
    pieces = components_kernels.label_pieces(body)
    belt = source.belt
    assert belt is not None
    up = facing_up(body, frame.xyz, noise, belt.geometry)
    assert up is not None
    return split_by_tops(pieces, up, frame.xyz, noise, belt.geometry, 30), truth.labels


@pytest.mark.parametrize("side_by_side", [True, False])
def test_touching_boxes_of_different_heights_are_two_pieces(side_by_side):
    pieces, truth = _split(_pair(0.12, 0.18, side_by_side))
    assert pieces.max() == 2
    for obj in (1, 2):
        # each piece is mostly one box
        owner = np.bincount(pieces[truth == obj]).argmax()
        assert owner > 0
        assert np.mean(pieces[truth == obj] == owner) > 0.8


@pytest.mark.parametrize("side_by_side", [True, False])
def test_the_face_a_tall_box_rises_from_a_low_ones_top_goes_to_the_tall_one(side_by_side):
    # 20 cm of the tall box's face stand over the low box's top, nearer it in the image than
    # its own top: dealt by nearness alone, a sixth of the tall box went to the low one
    pieces, truth = _split(_pair(0.10, 0.30, side_by_side))
    tall = pieces[truth == 2]
    owner = np.bincount(tall).argmax()
    assert np.mean(tall == owner) > 0.9
    assert np.mean(truth[pieces == owner] == 2) > 0.95


def test_what_is_no_piece_stays_0_when_a_piece_holds_the_first_pixel():
    # an object at the frame's top left corner: numbering by first appearance must not
    # give the background a piece's number (it once made all the scenery one piece)
    source = _pair(0.12, 0.18, True)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    rows, cols = np.nonzero((truth.labels > 0) & frame.valid)
    k = np.argmin(rows + cols)  # the boxes' pixel nearest the top left: the window starts there
    v, u = int(rows[k]), int(cols[k])
    window = (slice(v, None), slice(u, None))
    body = (truth.labels[window] > 0) & frame.valid[window]
    xyz = np.ascontiguousarray(frame.xyz[window])
    noise = range_noise(frame, 0.004)[window]
    belt = source.belt.geometry
    up = facing_up(body, xyz, noise, belt)
    assert up is not None
    assert body[0, 0]
    pieces = split_by_tops(components_kernels.label_pieces(body), up, xyz, noise, belt, 30)
    assert pieces.max() == 2
    np.testing.assert_array_equal(pieces > 0, body)
    assert pieces[0, 0] == 1


def test_flush_boxes_of_one_height_stay_one_piece():
    # range cannot tell them apart: no guess
    pieces, _ = _split(_pair(0.15, 0.15, True))
    assert pieces.max() == 1


@pytest.mark.parametrize(("side_by_side", "second_h", "goes_on"), [
    (False, 0.18, False),  # nose to tail, 6 cm taller: another object
    (True, 0.06, False),  # side by side, 6 cm lower: another object
    (False, 0.12, True),  # one height, flush: one surface, as range shows it
])  # fmt: skip
def test_what_stands_beside_a_track_goes_on_from_it_only_with_its_top_at_one_height(
    side_by_side, second_h, goes_on
):
    # the track holds box 1; box 2, pressed against it, meets it with no step (its side face
    # runs into the other's top), so only the tops' heights tell it is not more of box 1
    source = _pair(0.12, second_h, side_by_side)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    held = (truth.labels == 1) & frame.valid
    box = _box_of(held)
    pieces = components_kernels.label_pieces((truth.labels == 2) & frame.valid)
    assert pieces.max() == 1
    belt = source.belt.geometry
    kept = _on_level(
        frame, held[box], box, pieces, [1], measure_kernels.piece_boxes(pieces),
        range_noise(frame, 0.004), belt,
    )  # fmt: skip
    assert kept == ([1] if goes_on else [])


def test_in_loud_noise_the_tops_are_told_over_a_longer_span():
    # 2 cm of range noise: over BASELINE pixels a flat top's slope is lost in it, over a
    # longer span it is not, and the two boxes still come apart
    source = _pair(0.12, 0.18, True)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    rays = frame.xyz / np.linalg.norm(frame.xyz, axis=-1, keepdims=True)
    xyz = frame.xyz + rays * np.random.default_rng(4).normal(0, 0.02, frame.range.shape)[..., None]
    noise = np.full(frame.range.shape, 0.02)
    body = (truth.labels > 0) & frame.valid
    belt = source.belt.geometry
    _, *ratios = tops_kernels.facing_pixels(body, xyz, noise, belt.normal, BASELINE, MAX_SLOPE)
    assert max(np.median(r) for r in ratios) > MAX_SLOPE_NOISE  # too loud at BASELINE
    up = facing_up(body, xyz, noise, belt)
    assert up is not None
    pieces = split_by_tops(components_kernels.label_pieces(body), up, xyz, noise, belt, 30)
    assert pieces.max() == 2
    for obj in (1, 2):
        owner = np.bincount(pieces[truth.labels == obj]).argmax()
        assert owner > 0
        assert np.mean(pieces[truth.labels == obj] == owner) > 0.8


def test_where_no_span_quietens_the_slope_no_surface_is_told_facing_up():
    source = _pair(0.12, 0.18, True)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    body = (truth.labels > 0) & frame.valid
    assert facing_up(body, frame.xyz, np.full(frame.range.shape, 0.3), source.belt.geometry) is None


@dataclass(frozen=True)
class _Held:
    """Two boxes seen as tracks two ways: `boxes` one track each, `faces` the tall one's top
    (1) and what of its sides shows (2)."""

    xyz: np.ndarray
    noise: np.ndarray
    up: np.ndarray
    belt: BeltGeometry
    boxes: np.ndarray
    faces: np.ndarray


def _held(source: SceneSource) -> _Held:
    frame, truth = decode(source, scene_exposure(source, 0.0))
    belt = source.belt.geometry
    noise = range_noise(frame, 0.004)
    body = (truth.labels > 0) & frame.valid
    up = facing_up(body, frame.xyz, noise, belt)
    assert up is not None
    tall = body & (truth.labels == 2)
    faces = np.zeros(body.shape, np.uint16)
    faces[tall & up] = 1
    faces[tall & ~up] = 2
    boxes = np.where(body, truth.labels, 0).astype(np.uint16)
    return _Held(frame.xyz, noise, up, belt, boxes, faces)


def test_two_faces_of_one_box_are_one_object_and_two_boxes_are_not():
    h = _held(_pair(0.12, 0.18, True))
    # the two boxes, each a track: tops at different heights, never one object
    assert one_object(h.boxes, h.xyz, h.up, h.belt, 0.02) == []
    # one box held as two tracks, its top and its sides: one object
    assert one_object(h.faces, h.xyz, h.up, h.belt, 0.02) == [(1, 2)]


def test_two_objects_pressed_together_meet_at_a_crease_even_without_tops():
    # no tops to tell them apart (as where the noise hides the slope): the crease does
    source = _pair(0.12, 0.18, True)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    body = (truth.labels > 0) & frame.valid
    boxes = np.where(body, truth.labels, 0).astype(np.uint16)
    assert one_object(boxes, frame.xyz, None, source.belt.geometry, 0.02) == []


def test_a_side_face_lies_over_its_boxs_footprint_and_a_box_beside_does_not():
    h = _held(_pair(0.06, 0.16, False))
    # the tall box held as two tracks, its top and the smaller part, what of its sides shows
    assert sides_of(h.faces, h.xyz, h.noise, h.belt) == [(1, 2)]
    # a low box pressed against it stands on its own footprint, below the tall one's top
    assert sides_of(h.boxes, h.xyz, h.noise, h.belt) == []
