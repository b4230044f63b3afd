"""What stands out, cut into pieces (`tofcut.tracker.pieces`): one piece per object, even in
loud range noise."""

from __future__ import annotations

import numpy as np

from tofcut.sim.preview import decode, scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import parse_scene
from tofcut.tracker.noise import range_noise
from tofcut.tracker.params import TrackerParams
from tofcut.tracker.pieces import Pieces


def test_dark_touching_boxes_in_loud_noise_are_two_whole_pieces():
    # dark boxes seen from 2 m: ~3 cm of range noise, where a 3×3 median left each box's top
    # in specks (its largest piece 55% and 65% of the box, of 18 pieces)
    doc = {
        "name": "dark-pair",
        "duration_s": 10.0,
        "camera": {"position": [-0.5, -0.4, 2.0], "look_at": [0.0, 0.0, 0.0], "fps": 50},
        "belt": {"width": 0.6, "speed": 0.0, "albedo": 0.08},
        "object": [
            {"name": "a", "shape": "box", "size": [0.2, 0.2, 0.12], "albedo": 0.08,
             "position": [-0.1, 0.0, 0.06], "motion": "static"},
            {"name": "b", "shape": "box", "size": [0.2, 0.2, 0.17], "albedo": 0.08,
             "position": [0.1, 0.0, 0.085], "motion": "static"},
        ],
    }  # fmt: skip
    source = SceneSource(parse_scene(doc), seed=3)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    body = (truth.labels > 0) & frame.valid
    noise = range_noise(frame, 0.004)
    assert np.median(noise[body]) > 0.025
    belt = source.belt
    assert belt is not None
    pieces = Pieces(TrackerParams()).split(frame, body, noise, belt.geometry, step_noise=False)
    owners = []
    for obj in (1, 2):
        held = pieces[truth.labels == obj]
        owner = np.bincount(held[held > 0]).argmax()
        assert np.mean(held == owner) > 0.85
        owners.append(owner)
    assert owners[0] != owners[1]
