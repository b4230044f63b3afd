"""`tofcut bench`: that it runs and reports every stage (never how fast anything is), and the
pieces it is made of: fitted exponents, crowd scenes, the report's verdicts."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from tofcut.driver.calibration import pixel_rays
from tofcut.sim.catalog import scene_path
from tofcut.sim.crowd import MAX_BOXES, crowd_scene, crowd_source, resized
from tofcut.sim.preview import scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import SceneError, load_scene
from tofcut.tools.bench.report import best_energies, markdown, targets
from tofcut.tools.bench.runner import STAGES, run_stage
from tofcut.tools.bench.timing import fit_exponent, median_seconds, percentiles_ms
from tofcut.tools.cli import main
from tofcut.tools.experiments.grabcut import INSTALL_HINT


def test_quick_bench_writes_json_markdown_and_plot_for_every_stage(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "--quick", "--out", str(out)]) == 0
    doc = json.loads((out / "bench.json").read_text())
    assert set(doc["stages"]) == set(STAGES)
    assert doc["meta"]["errors"] == {}
    assert doc["meta"]["quick"] is True
    verdicts = {t["what"]: t["verdict"] for t in doc["targets"]}
    assert len(verdicts) == 10
    eight = {what for what in verdicts if what.startswith("8 cameras")}
    assert len(eight) == 2
    assert {verdicts[what] for what in eight} == {"not measured"}  # quick: 2 cameras only
    # every other target is measured, even quick
    assert {v for what, v in verdicts.items() if what not in eight} <= {"PASS", "MISS"}
    stages = doc["stages"]
    (two,) = stages["cameras"]["rows"]
    assert two["cameras"] == 2
    assert two["frames"] > 0
    assert two["cpu_ms_per_camera_frame"] > 0
    assert [r["objects"] for r in stages["tracker"]["objects"]] == [1, 10]
    assert stages["tracker"]["objects"][1]["tracks_in_view"] == 10
    assert all(r["identical"] for r in stages["segment"]["rows"])
    assert stages["live"]["frames"] > 0
    assert stages["live"]["rerun_written"] == stages["live"]["frames"]
    assert {f["against"] for f in doc["fits"]} >= {"pixels", "objects"}
    text = (out / "README.md").read_text()
    for heading in ("Targets", "Demodulation", "Segmentation", "Tracker", "Live pipeline",
                    "Rerun logging", "rendering rate", "Cameras per box",
                    "How cost grows"):  # fmt: skip
        assert f"## {heading}" in text or heading in text, heading
    with Image.open(out / "scaling.png") as image:
        assert image.size[0] > image.size[1] > 100
    printed = capsys.readouterr().out
    assert "demodulation, 176×144" in printed
    assert str(out / "README.md") in printed
    # a quick run says that its MISS lines are no measurement (and do not fail it)
    assert "bench --quick is a smoke run" in printed
    assert "do not fail it" in printed


def test_a_stage_that_does_not_exist_is_refused(tmp_path):
    with pytest.raises(ValueError, match="no bench stage 'nope'"):
        run_stage("nope", True, tmp_path / "x.json", None)


def test_targets_not_run_are_reported_as_not_measured_not_as_a_verdict():
    assert {t.verdict for t in targets({})} == {"not measured"}
    meta = {"quick": True, "date": "d", "cpu_model": "c", "cpus": 2, "pinned_cpu": 1,
            "python": "3", "numpy": "2"}  # fmt: skip
    text = markdown({}, meta, {"live": "boom"})
    assert "not measured" in text
    assert "Stage `live` failed: `boom`" in text


def test_without_opencv_the_report_says_how_to_get_grabcut():
    meta = {"quick": True, "date": "d", "cpu_model": "c", "cpus": 2, "pinned_cpu": 1,
            "python": "3", "numpy": "2"}  # fmt: skip
    row = {"scene": "s", "object": "o", "energy": "range-data", "kind": "data-term",
           "reference_cut_s": 0.004, "fast_cut_s": 0.001, "cut_ratio": 4.0,
           "segment_reference_s": 0.005, "segment_fast_s": 0.002, "identical": True,
           "iou_fast": 0.5, "iou_reference": 0.5}  # fmt: skip
    segment = {"rows": [row], "grabcut": False, "note": INSTALL_HINT}
    text = markdown({"segment": segment}, meta, {})
    assert "GrabCut not measured" in text
    assert "opencv-python-headless" in text
    assert "| 4.0× |" in text


def test_verdicts_follow_the_numbers():
    live = {"core_needed": 0.49, "dropped": 0}
    got = {t.what: t.verdict for t in targets({"live": live})}
    assert got["live pipeline at 50 fps with rerun file output"] == "PASS"
    assert got["live pipeline: frames dropped"] == "PASS"
    got = {t.what: t.verdict for t in targets({"live": {"core_needed": 0.5, "dropped": 1}})}
    assert got["live pipeline at 50 fps with rerun file output"] == "MISS"
    assert got["live pipeline: frames dropped"] == "MISS"
    for lost, cpu_ms, verdict in ((0, 5.0, "PASS"), (1, 5.1, "MISS")):
        eight = {"cameras": 8, "lost": lost, "cpu_ms_per_camera_frame": cpu_ms}
        got = {t.what: t.verdict for t in targets({"cameras": {"rows": [eight]}})}
        assert {v for what, v in got.items() if what.startswith("8 cameras")} == {verdict}


def test_grabcut_is_judged_against_the_best_energy_of_each_object():
    def row(name, energy, ours, peer):
        return {"scene": "s", "object": name, "energy": energy, "kind": "support",
                "iou_fast": ours, "iou_grabcut": peer, "cut_ratio": 1.0}  # fmt: skip

    rows = [row("a", "range-smooth", 0.5, 0.9), row("a", "support", 0.88, 0.9),
            row("b", "support", 0.7, 0.6)]  # fmt: skip
    best = best_energies(rows)
    assert [(b[0], b[1], b[2]) for b in best] == [("s", "a", "support"), ("s", "b", "support")]
    assert best[0][4] == pytest.approx(0.02)
    assert best[1][4] == pytest.approx(-0.1)
    what = "grabCut's lead over tofcut's best energy (every object)"
    got = {t.what: t.verdict for t in targets({"segment": {"rows": rows}})}
    assert got[what] == "PASS"
    rows.append(row("c", "support", 0.8, 0.86))
    got = {t.what: t.verdict for t in targets({"segment": {"rows": rows}})}
    assert got[what] == "MISS"


def test_fit_exponent_recovers_a_power_law():
    xs = [1.0, 5.0, 10.0, 20.0]
    assert fit_exponent(xs, [3.0 * x**1.5 for x in xs]) == pytest.approx(1.5)
    assert fit_exponent(xs, [0.2] * 4) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="two or more distinct"):
        fit_exponent([1.0, 1.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="positive"):
        fit_exponent([0.0, 1.0], [1.0, 2.0])


def test_median_and_percentiles():
    calls = []
    median_seconds(lambda: calls.append(1), warmup=2, repeats=3, number=4)
    assert len(calls) == 2 + 3 * 4
    assert percentiles_ms([0.001, 0.002, 0.003]) == pytest.approx(
        {"p50": 2.0, "p90": 2.8, "p99": 2.98}
    )
    with pytest.raises(ValueError, match="at least 1"):
        median_seconds(lambda: None, warmup=0, repeats=0)


@pytest.mark.parametrize("boxes", [1, 5, 10, 20])
def test_a_crowd_has_every_box_in_view(boxes):
    source = crowd_source(boxes)
    truth = source.render(scene_exposure(source, 0.0)).truth
    ids = set(np.unique(truth.labels)) - {0}
    assert ids == set(range(1, boxes + 1))


def test_a_crowd_outside_1_to_20_boxes_is_refused():
    for bad in (0, MAX_BOXES + 1):
        with pytest.raises(SceneError, match="1 to 20 boxes"):
            crowd_scene(bad)


def test_a_resized_scene_keeps_the_horizontal_field_of_view():
    scene = load_scene(scene_path("conveyor"))
    small = SceneSource(scene, 0).calibration
    big = SceneSource(resized(scene, 352, 288), 0).calibration
    assert (big.width, big.height) == (352, 288)
    a, b = pixel_rays(small), pixel_rays(big)
    np.testing.assert_allclose(a[72, 0], b[144:146, 0:2].mean(axis=(0, 1)), atol=2e-3)
    with pytest.raises(SceneError):
        resized(scene, 4, 4)


def test_the_profile_ranks_the_tracker_s_own_steps():
    from tofcut.tools.bench.profile import profile

    report = profile(objects=2, frames=3, top=40)
    assert "Ordered by: internal time" in report
    assert "Ordered by: cumulative time" in report
    assert "tracker.py:" in report  # the per-frame step was timed
    assert "(update)" in report
