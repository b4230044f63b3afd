"""Object-frames counted by how the masks held them (`tofcut.tools.evaluation.holding`)."""

from __future__ import annotations

import numpy as np

from tests.test_evaluation_situations import A, B, _masks, _truths
from tofcut.tools.evaluation.holding import Holding, holding

BOTH = np.s_[2:12, 2:22]  # objects 1 and 2, as one mask


def test_each_object_frame_is_held_merged_partly_held_or_missed():
    truths = _truths(10, {1: A, 2: B})
    assert holding(truths, _masks(10, {7: (A, 0), 8: (B, 0)})) == Holding(held=20)
    # one track over both: an IoU of 0.5 with each, half of it on the other
    assert holding(truths, _masks(10, {7: (BOTH, 0)})) == Holding(held=20)
    # one track over both and a strip of scenery: neither held (IoU 100 / 240), both merged
    wide = _masks(10, {7: (np.s_[2:14, 2:22], 0)})
    assert holding(truths, wide) == Holding(merged=20)
    # over all the scenery too: each object a loose edge of that mask, not a merge
    assert holding(truths, _masks(10, {7: (np.s_[0:16, 0:24], 0)})) == Holding(partly=20)
    # a quarter of object 1 and nothing else; object 2 not touched
    quarter = _masks(10, {7: (np.s_[2:7, 2:7], 0)})
    assert holding(truths, quarter) == Holding(partly=10, missed=10)
    # no masks at all for the first 4 frames
    late = [None] * 4 + _masks(6, {7: (A, 0), 8: (B, 0)})
    counted = holding(truths, late)
    assert counted == Holding(held=12, missed=8)
    assert counted.total == 20


def test_objects_too_small_to_score_are_not_counted():
    tiny = np.s_[2:5, 2:5]  # 9 pixels, under MIN_PIXELS
    assert holding(_truths(5, {1: tiny}), _masks(5, {})) == Holding()


def test_holdings_add_up():
    assert Holding(1, 2, 3, 4) + Holding(4, 3, 2, 1) == Holding(5, 5, 5, 5)
