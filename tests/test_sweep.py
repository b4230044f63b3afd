"""`tofcut sweep`: tracker settings from the command line, checked; a grid of them scored
on a family, each line recorded once."""

from __future__ import annotations

import argparse
import json

import pytest

from tofcut.tools.cli import main
from tofcut.tools.pipeline.settings import SettingError, applied, grid, setting
from tofcut.tracker.errors import SegmentError
from tofcut.tracker.params import TrackerParams


def test_settings_are_read_as_the_parameters_types():
    s = setting("tracker.beta=2,2.5,3")
    assert (s.name, s.values) == ("beta", (2.0, 2.5, 3.0))
    assert setting("tracker.background.learn_frames=3").values == (3,)
    points = grid([setting("tracker.beta=2,3"), setting("tracker.motion.accel_sigma=0.5")])
    assert points == [{"beta": 2.0, "motion.accel_sigma": 0.5},
                      {"beta": 3.0, "motion.accel_sigma": 0.5}]  # fmt: skip
    p = applied(TrackerParams(), points[1])
    assert (p.beta, p.motion.accel_sigma, p.object_cost) == (3.0, 0.5, TrackerParams().object_cost)


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("tracker.bta=3", "tracker.bta is not a tracker parameter (did you mean tracker.beta?)"),
        ("tracker.min_pixels=2.5", "tracker.min_pixels: '2.5' is not a whole number"),
        ("tracker.beta=nan", "tracker.beta: 'nan' is not a finite number"),
        ("tracker.rigid=false", "tracker.rigid is set by --deformable, not --set"),
        ("beta=3", "'beta=3': give tracker.PARAM=VALUE"),
    ],
)
def test_a_bad_setting_is_a_one_line_error(text, error):
    with pytest.raises(argparse.ArgumentTypeError) as e:
        setting(text)
    assert str(e.value).startswith(error)
    assert "\n" not in str(e.value)


def test_settings_the_tracker_refuses_are_refused_before_anything_runs(tmp_path, capsys):
    with pytest.raises(SettingError, match=r"tracker\.beta is set more than once"):
        grid([setting("tracker.beta=2"), setting("tracker.beta=3")])
    with pytest.raises(SegmentError, match="beta must be positive"):
        applied(TrackerParams(), {"beta": -1.0})
    code = main(["sweep", "--scene", "conveyor", "--seeds", "0", "--set", "tracker.beta=1,-1",
                 "--work", str(tmp_path / "work")])  # fmt: skip
    assert code == 1
    assert (
        capsys.readouterr().err == "tofcut: error: TrackerParams.beta must be positive, got -1.0\n"
    )
    assert not (tmp_path / "work").exists()


def test_a_sweep_records_each_line_once_and_scores_every_setting(tmp_path, capsys):
    work, out = tmp_path / "work", tmp_path / "out"
    code = main(["sweep", "--scene", "conveyor", "--seeds", "0", "--frames", "8",
                 "--set", "tracker.beta=2.5,4", "--workers", "1", "--work", str(work),
                 "--out", str(out)])  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    doc = json.loads((out / "sweep.json").read_text())
    assert [s["values"] for s in doc["settings"]] == [{"tracker.beta": 2.5}, {"tracker.beta": 4.0}]
    assert [s["defaults"] for s in doc["settings"]] == [True, False]
    assert all(s["aggregate"]["lines"] == 1 for s in doc["settings"])
    md = (out / "sweep.md").read_text()
    assert "| beta=2.5 (defaults) | 1 of 1 |" in md
    assert "| beta=4.0 | 1 of 1 |" in md
    line = work / "conveyor" / "seed-0"
    assert printed.count("seed 0 recorded") == 1
    assert (line / "sweep" / "beta=4.0" / "tofcut.tracks.jsonl").is_file()
    # the default setting scores as the family evaluation's tofcut run of the same capture
    assert main(["evaluate", "--scene", "conveyor", "--seeds", "0", "--frames", "8",
                 "--trackers", "tofcut", "--workers", "1", "--work", str(work),
                 "--json", str(tmp_path / "family.json")]) == 0  # fmt: skip
    family = json.loads((tmp_path / "family.json").read_text())
    assert (doc["settings"][0]["lines"][0]["runs"]["tofcut"]["scores"]
            == family["lines"][0]["runs"]["tofcut"]["scores"])  # fmt: skip
