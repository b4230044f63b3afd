"""The facade a Python user meets first: `tofcut.open`, `tofcut.Tracker`, the shared types."""

from __future__ import annotations

import subprocess
import sys

import pytest

import tofcut
from tofcut.tools.cli import main


def _tracks(source: str, **options) -> list[list[int]]:
    ids = []
    with tofcut.open(source, **options) as camera:
        tracker = tofcut.Tracker()
        for frame in camera.frames(count=15):
            assert isinstance(frame, tofcut.Frame)
            tracked = tracker.update(frame)
            assert isinstance(tracked, tofcut.TrackedFrame)
            ids.append([t.id for t in tracked.tracks])
    return ids


def test_an_emulated_camera_and_its_capture_open_by_name_and_track_alike(tmp_path):
    path = tmp_path / "run.tofcap"
    assert main(["record", "emulator:conveyor", "--fast", "--frames", "15", "-o", str(path)]) == 0
    live = _tracks("emulator:conveyor", realtime=False)
    assert live[-1], "the conveyor's boxes are tracked"
    assert _tracks(str(path)) == live


def test_a_name_that_is_no_source_is_a_tofcut_error():
    with pytest.raises(tofcut.TofcutError, match="is not a source"):
        tofcut.open("nonsense")


def test_importing_tofcut_imports_no_tracker_and_no_driver():
    code = "import sys, tofcut; print(sorted(m for m in sys.modules if m.startswith('tofcut.')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
