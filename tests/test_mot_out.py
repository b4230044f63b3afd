"""`track --mot-out`: MOTChallenge rows that py-motmetrics reads, matching the JSONL tracks
of the same run, with frame numbers that go on when the camera's sequence restarts."""

from __future__ import annotations

import json
from pathlib import Path

import motmetrics
import numpy as np

from tofcut.driver.capture import CaptureReader, CaptureWriter
from tofcut.tools.cli import main


def restarted_capture(tmp_path: Path) -> Path:
    """A capture whose camera restarts its sequence halfway: one recording's records twice."""
    once = tmp_path / "once.tofcap"
    assert main(["record", "emulator", "--frames", "12", "--fast", "-o", str(once)]) == 0
    reader = CaptureReader(once)
    raws = list(reader.raw_frames())
    twice = tmp_path / "twice.tofcap"
    with CaptureWriter(twice, reader.capture.metadata, reader.capture.calibration_block) as out:
        for raw in raws + raws:
            out.write(raw)
    return twice


def test_mot_rows_match_the_jsonl_and_frames_never_go_back(tmp_path, capsys):
    capture = restarted_capture(tmp_path)
    tracks, mot = tmp_path / "t.jsonl", tmp_path / "t.txt"
    argv = ["track", str(capture), "--tracks-out", str(tracks), "--mot-out", str(mot)]
    assert main([*argv, "--headless"]) == 0
    assert f"wrote {mot}" in capsys.readouterr().out
    lines = [json.loads(line) for line in tracks.read_text().splitlines()]
    seqs = [line["seq"] for line in lines]
    assert len(lines) == 24
    assert seqs[12] < seqs[11]  # the camera's sequence restarted ...
    expected = [
        (frame, t["id"], *t["bbox"], *t["centroid"])
        for frame, line in enumerate(lines, start=1)  # ... the MOT frame goes on
        for t in line["tracks"]
    ]
    assert expected, "the run tracked nothing: the test proves nothing"

    rows = np.loadtxt(mot, delimiter=",", ndmin=2)
    assert rows.shape == (len(expected), 10)
    assert (np.diff(rows[:, 0]) >= 0).all()
    assert (rows[:, 6] == 1).all()  # conf
    for row, (frame, ident, u0, v0, u1, v1, x, y, z) in zip(rows, expected, strict=True):
        assert tuple(row[:6]) == (frame, ident, u0 + 1, v0 + 1, u1 - u0, v1 - v0)
        assert tuple(row[7:]) == (x, y, z)

    df = motmetrics.io.loadtxt(str(mot), fmt="mot15-2D")  # MOTChallenge's own reader
    assert len(df) == len(expected)
    for frame, ident, u0, v0, u1, v1, x, y, _ in expected:
        got = df.loc[(frame, ident)]
        assert (got["X"], got["Y"], got["Width"], got["Height"]) == (u0, v0, u1 - u0, v1 - v0)
        assert got["Confidence"] == 1
        assert (got["ClassId"], got["Visibility"]) == (x, y)  # mot15's x, y under mot16 names


def test_live_writes_mot_rows_too(tmp_path):
    tracks, mot = tmp_path / "t.jsonl", tmp_path / "t.txt"
    argv = ["live", "emulator:conveyor", "--fast", "--frames", "30", "--headless"]
    assert main([*argv, "--tracks-out", str(tracks), "--mot-out", str(mot)]) == 0
    lines = [json.loads(line) for line in tracks.read_text().splitlines()]
    expected = [
        (frame, t["id"]) for frame, line in enumerate(lines, start=1) for t in line["tracks"]
    ]
    assert expected
    rows = np.loadtxt(mot, delimiter=",", ndmin=2)
    assert [(int(f), int(i)) for f, i in rows[:, :2]] == expected
