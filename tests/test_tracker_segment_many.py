"""segment_many(): one target is segment(); several get disjoint masks on emulated frames."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import decode, scene_exposure
from tofcut.tools.experiments.reproduce import deepest_pixel, iou
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.paper.segment import Energy, Target, segment
from tofcut.tracker.paper.segment_many import segment_many


@pytest.fixture(scope="module")
def fig1():
    source = open_scene("paper-fig1", 0)
    frame, truth = decode(source, scene_exposure(source, 0.0))
    return frame, truth


def target_of(truth, name: str, seeded: bool) -> tuple[Target, np.ndarray]:
    obj = next(o for o in truth.objects if o.name == name)
    mask = truth.labels == obj.id
    if seeded:
        return Target(pixel=deepest_pixel(mask)), mask
    return Target(point=tuple(float(c) for c in obj.centroid)), mask


@pytest.mark.parametrize("energy", [Energy.RANGE_DATA, Energy.RANGE_INTENSITY_SMOOTH])
def test_one_target_is_segment(fig1, energy):
    frame, truth = fig1
    target, _ = target_of(truth, "target-box", energy.seeded)
    many = segment_many(frame, [target], energy=energy)
    one = segment(frame, target, energy)
    assert np.array_equal(many.mask(0), one.mask)
    assert many.energy == pytest.approx(one.energy, rel=1e-9)
    assert set(np.unique(many.labels)) <= {0, 1}


@pytest.mark.parametrize("energy", [Energy.RANGE_DATA, Energy.RANGE_INTENSITY_SMOOTH])
def test_two_targets_get_their_own_disjoint_masks(fig1, energy):
    frame, truth = fig1
    (box, box_mask), (ball, ball_mask) = (
        target_of(truth, name, energy.seeded) for name in ("target-box", "ball")
    )
    many = segment_many(frame, [box, ball], energy=energy)
    assert not (many.mask(0) & many.mask(1)).any()
    assert many.labels.max() == 2
    truths = (box_mask, ball_mask)
    for k in range(2):
        # each label lies on its own object rather than on the other one
        assert (many.mask(k) & truths[k]).sum() > 10 * (many.mask(k) & truths[1 - k]).sum()
    assert iou(many.mask(0), box_mask) > 0.5
    if energy.seeded:
        # no data term to share: far apart, each target gets what its own cut gives it
        for k, t in enumerate((box, ball)):
            assert np.array_equal(many.mask(k), segment(frame, t, energy).mask)
    assert len(many.models) == 2


def test_bad_targets_are_reported(fig1):
    frame, truth = fig1
    target, _ = target_of(truth, "ball", True)
    with pytest.raises(SegmentError, match="at least one target"):
        segment_many(frame, [])
    with pytest.raises(SegmentError, match="share a seed"):
        segment_many(frame, [target, target], energy=Energy.RANGE_SMOOTH)
    with pytest.raises(SegmentError, match="not the support energy"):
        segment_many(frame, [target], energy=Energy.SUPPORT)
    with pytest.raises(SegmentError, match="must be an Energy"):
        segment_many(frame, [target], energy="range-data")  # type: ignore[arg-type]
