"""Evaluation that cannot cheat: bare captures, both matchings on hand-made label images,
the baseline tracker, and the family runner through the real command line."""

from __future__ import annotations

import numpy as np

from tofcut.driver.capture import CAMERA_KEYS, CaptureReader, bare_copy
from tofcut.sim.truth import load_truth, truth_path
from tofcut.tools.cli import main

# --- bare captures ---------------------------------------------------------------------------


def test_a_bare_capture_holds_only_the_cameras_metadata_and_replays_the_same_frames(tmp_path):
    full, bare = tmp_path / "full.tofcap", tmp_path / "bare.tofcap"
    assert main(["record", "emulator:conveyor", "-o", str(full), "--frames", "6", "--fast"]) == 0
    assert {"scene", "belt", "source"} <= set(CaptureReader(full).capture.metadata)
    assert bare_copy(full, bare) == 6
    assert set(CaptureReader(bare).capture.metadata) == set(CAMERA_KEYS)
    a, b = list(CaptureReader(full).frames()), list(CaptureReader(bare).frames())
    assert [f.sequence for f in a] == [f.sequence for f in b] == list(range(6))
    for x, y in zip(a, b, strict=True):
        assert x.header == y.header
        np.testing.assert_array_equal(x.range, y.range)
    # recorded bare directly: the camera's keys only, and the truth still beside it
    direct = tmp_path / "direct.tofcap"
    cmd = ["record", "emulator:conveyor", "-o", str(direct), "--frames", "6", "--fast", "--bare"]
    assert main(cmd) == 0
    reader = CaptureReader(direct)
    assert set(reader.capture.metadata) == set(CAMERA_KEYS)
    assert len(list(reader.frames())) == 6
    assert len(load_truth(truth_path(direct))) == 6
