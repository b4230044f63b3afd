"""COCO run-length masks against strings worked out by hand, and HOTA (TrackEval's) against
cases worked out by hand from its definition."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.tools.evaluation.hota import FrameMatch, centroid_similarity, hota
from tofcut.tools.pipeline.mot import parse_row
from tofcut.tools.pipeline.mots import decode, encode, parse_line

# --- COCO RLE ----------------------------------------------------------------------------------


def reference_counts(mask: np.ndarray) -> str:
    """COCO's compressed RLE, written out from its definition (maskApi.c's rleToString):
    runs down the columns from a run of 0s; from the third run on, each less the run two
    before; each number in 5-bit groups, low first, 0x20 where more follow, plus 48."""
    runs, current, n = [], False, 0
    for value in mask.ravel(order="F"):
        if value == current:
            n += 1
        else:
            runs.append(n)
            current, n = bool(value), 1
    runs.append(n)
    out = []
    for i, run in enumerate(runs):
        x = run - runs[i - 2] if i > 2 else run
        more = True
        while more:
            c = x & 0x1F
            x >>= 5
            more = x != -1 if c & 0x10 else x != 0
            out.append(chr((c | 0x20 if more else c) + 48))
    return "".join(out)


def test_rle_of_masks_worked_out_by_hand():
    mask = np.zeros((3, 4), bool)
    mask[0, 1] = mask[2, 3] = True  # down the columns: 3 off, 1 on, 7 off, 1 on
    assert encode(mask) == "3170"  # the fourth run is written as 1 − 1 = 0
    assert encode(np.zeros((3, 4), bool)) == "<"  # one run of 12: chr(12 + 48)
    # all on: runs 0, 25344 = 0b11000_11000_00000, in 5-bit groups 0 (+0x20), 24 (+0x20), 24
    # (+0x20: 24 has 0x10 set, so a 0 group follows to say the number is not negative)
    assert encode(np.ones((144, 176), bool)) == "0Phh0"


def test_rle_matches_its_definition_and_decodes_back():
    rng = np.random.default_rng(7)
    for _ in range(50):
        h, w = rng.integers(1, 40, size=2)
        mask = rng.random((h, w)) < rng.random()
        counts = encode(mask)
        assert counts == reference_counts(mask)
        assert (decode(counts, h, w) == mask).all()


def test_a_mots_line_reads_back_and_bad_ones_say_why():
    obj = parse_line("3 7 1 3 4 3170")
    assert obj is not None
    assert (obj.frame, obj.id, obj.class_id, obj.height, obj.width) == (3, 7, 1, 3, 4)
    assert obj.line() == "3 7 1 3 4 3170"
    assert parse_line("   ") is None
    for bad, words in (
        ("3 7 1 3 3170", "5 fields, not 6"),
        ("3 7 car 3 4 3170", "whole numbers"),
        ("-1 7 1 3 4 3170", "0 or more"),
        ("3 7 1 3 4 ~~~~~", "covers more than"),
    ):
        with pytest.raises(ValueError, match=words):
            parse_line(bad)


def test_mot_rows_read_with_or_without_a_3d_position():
    row = parse_row("5,2,11,21,30,40,1,0.1,-0.2,1.3")
    assert row is not None
    assert (row.frame, row.id, row.box, row.conf, row.xyz) == (
        5, 2, (11, 21, 30, 40), 1, (0.1, -0.2, 1.3)
    )  # fmt: skip
    no_xyz = parse_row("5 2 11 21 30 40 1 -1 -1 -1")
    assert no_xyz is not None
    assert no_xyz.xyz is None
    short = parse_row("5,2,11,21,30,40,1")
    assert short is not None
    assert short.xyz is None
    with pytest.raises(ValueError, match="frame from 1"):
        parse_row("0,2,11,21,30,40,1,0,0,1")


# --- HOTA --------------------------------------------------------------------------------------

ONE = np.ones((1, 1))


def test_a_perfect_run_is_one():
    h = hota([FrameMatch([1], [10], ONE) for _ in range(5)])
    assert (h.hota, h.deta, h.assa, h.loca) == pytest.approx((1, 1, 1, 1))


def test_an_object_whose_track_changes_id_halfway():
    # every detection is right (DetA 1); each of its 4 matches is with a track that holds
    # it for 2 of the object's 4 frames and nothing else: TPA 2 / (TPA 2 + FNA 2 + FPA 0)
    frames = [FrameMatch([1], [10 if t < 2 else 11], ONE) for t in range(4)]
    h = hota(frames)
    assert (h.deta, h.assa) == pytest.approx((1.0, 0.5))
    assert h.hota == pytest.approx(np.sqrt(0.5))


def test_a_false_positive_in_every_frame():
    # TP 2, FP 2, FN 0: DetA 2 / 4; association perfect
    h = hota([FrameMatch([1], [10, 99], np.array([[1.0, 0.0]])) for _ in range(2)])
    assert (h.deta, h.assa) == pytest.approx((0.5, 1.0))
    assert h.hota == pytest.approx(np.sqrt(0.5))


def test_a_loose_match_counts_only_up_to_its_similarity():
    # similarity 0.52 matches at α = 0.05 ... 0.50 (10 of the 19 thresholds), where HOTA_α is
    # 1, and at none above, where it is 0
    h = hota([FrameMatch([1], [10], np.full((1, 1), 0.52)) for _ in range(3)])
    assert (h.hota, h.deta, h.assa) == pytest.approx((10 / 19, 10 / 19, 10 / 19))


def test_nothing_to_match_is_zero():
    assert hota([FrameMatch([1], [], np.zeros((1, 0)))]).hota == 0
    assert hota([FrameMatch([], [10], np.zeros((0, 1)))]).hota == 0
    with pytest.raises(ValueError, match="similarity of shape"):
        hota([FrameMatch([1], [10], np.zeros((2, 2)))])


def test_centroid_similarity_is_one_half_at_the_gate():
    truth = np.zeros((1, 3))
    tracks = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.2, 0], [0, 0, 0.5]])
    sim = centroid_similarity(truth, tracks, gate=0.1)
    assert sim[0].tolist() == pytest.approx([1.0, 0.5, 0.0, 0.0])
    assert centroid_similarity(truth, np.zeros((0, 3)), 0.1).shape == (1, 0)
