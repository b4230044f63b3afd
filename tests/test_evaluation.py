"""Evaluation that cannot cheat: bare captures, both matchings on hand-made label images,
the baseline tracker, and the family runner through the real command line."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from tofcut.driver.capture import CAMERA_KEYS, CaptureReader, bare_copy
from tofcut.sim.truth import FrameTruth, ObjectTruth, load_truth
from tofcut.tools.cli import main
from tofcut.tools.evaluation import family
from tofcut.tools.evaluation.baseline import MIN_PIXELS, STEP_M, components
from tofcut.tools.evaluation.family import parse_seeds
from tofcut.tools.evaluation.scoring import evaluate

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
    # `tofcut record --bare` itself: the family runner's captures, in its test below


# --- the two matchings on hand-made label images ---------------------------------------------

H = W = 20
_X, _Y = np.meshgrid((np.arange(W) - 9.5) * 0.05, (np.arange(H) - 9.5) * 0.05)
RAYS = np.dstack([_X, _Y, np.ones((H, W))])
RAYS /= np.linalg.norm(RAYS, axis=-1, keepdims=True)
FRAMES = 6


def _square(v: int, u: int, n: int = 4) -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[v : v + n, u : u + n] = True
    return m


def _centroid(mask: np.ndarray) -> list[float]:
    return RAYS[mask].mean(axis=0).tolist()  # range 1 m everywhere


def _scene():
    """Two 4×4 objects moving right a pixel a frame, and a static one (scenery)."""
    truths, tracks, masks = [], {}, {}
    for f in range(FRAMES):
        labels = np.zeros((H, W), np.int32)
        objs = []
        for oid, mask in ((1, _square(2, 1 + f)), (2, _square(10, 1 + f)), (3, _square(15, 15))):
            labels[mask] = oid
            c = np.array(_centroid(mask))
            objs.append(ObjectTruth(oid, f"o{oid}", np.eye(4), c, c, c, c, int(mask.sum())))
        truths.append(FrameTruth(f, f * 0.02, (0.0,) * 4, labels, np.ones((H, W), np.float32),
                                 tuple(objs)))  # fmt: skip
        tracks[f] = [{"id": 10 * o, "centroid": _centroid(labels == o)} for o in (1, 2, 3)]
        masks[f] = np.where(labels > 0, labels * 10, 0).astype(np.uint16)
    return truths, tracks, masks


def _score(truths, tracks, masks):
    return evaluate(truths, tracks, masks, RAYS, gate=0.1, min_pixels=5)


def test_a_perfect_run_scores_one_both_ways():
    s = _score(*_scene())
    for m in (s.by_centroid, s.by_iou):
        assert (m.mota, m.idf1, m.id_switches, m.objects) == (1.0, 1.0, 0, 2 * FRAMES)
    assert s.mask_iou == 1.0
    assert s.matched_iou == 1.0  # the static object's track is ignored, not a false positive


def test_a_swapped_id_is_a_switch_both_ways():
    truths, tracks, masks = _scene()
    for f in range(3, FRAMES):  # from frame 3 on, tracks 10 and 20 trade objects
        for t in tracks[f]:
            t["id"] = {10: 20, 20: 10}.get(t["id"], t["id"])
        m = masks[f].copy()
        m[masks[f] == 10], m[masks[f] == 20] = 20, 10
        masks[f] = m
    s = _score(truths, tracks, masks)
    for m in (s.by_centroid, s.by_iou):
        assert m.id_switches == 2
        assert m.mota == pytest.approx(1 - 2 / (2 * FRAMES))
        assert m.idf1 == pytest.approx(0.5)  # each track holds its object in half the frames
    assert s.mask_iou == 1.0  # masks are whole: the IoU does not see whose id it is


def test_a_missed_object_and_a_false_positive_lower_mota_by_their_count():
    truths, tracks, masks = _scene()
    for f in (1, 2):  # object 2 is missed in two frames
        tracks[f] = [t for t in tracks[f] if t["id"] != 20]
        masks[f] = np.where(masks[f] == 20, 0, masks[f]).astype(np.uint16)
    fp = _square(6, 14, 3)  # on the background in three frames
    for f in (3, 4, 5):
        tracks[f] = [*tracks[f], {"id": 99, "centroid": _centroid(fp)}]
        masks[f] = np.where(fp, 99, masks[f]).astype(np.uint16)
    s = _score(truths, tracks, masks)
    n = 2 * FRAMES
    for m in (s.by_centroid, s.by_iou):
        assert (m.misses, m.false_positives, m.id_switches) == (2, 3, 0)
        assert m.mota == pytest.approx(1 - 5 / n)
    assert s.mask_iou == pytest.approx((n - 2) / n)  # a missed object-frame counts 0


def test_a_mask_under_half_the_object_matches_by_centroid_but_not_by_iou():
    truths, tracks, masks = _scene()
    n, f = 2 * FRAMES, 2
    obj = truths[f].labels == 2  # columns 1 + f to 4 + f
    cols = np.arange(W)[None, :]
    masks[f] = np.where(masks[f] == 20, 0, masks[f]).astype(np.uint16)
    masks[f][obj & (cols < 1 + f + 3)] = 20  # 3 of its 4 columns: IoU 0.75, still a match
    s = _score(truths, tracks, masks)
    assert (s.by_iou.misses, s.by_iou.false_positives) == (0, 0)
    assert s.mask_iou == pytest.approx((n - 1 + 0.75) / n)
    masks[f] = np.where(masks[f] == 20, 0, masks[f]).astype(np.uint16)
    masks[f][obj & (cols < 1 + f + 1)] = 20  # 1 of its 4 columns: IoU 0.25
    s = _score(truths, tracks, masks)
    assert (s.by_iou.misses, s.by_iou.false_positives) == (1, 1)
    assert s.by_iou.mota == pytest.approx(1 - 2 / n)
    # the centroid the track reports is still the object's
    assert (s.by_centroid.misses, s.by_centroid.false_positives) == (0, 0)
    assert s.mask_iou == pytest.approx((n - 1 + 0.25) / n)


def test_a_track_mostly_on_scenery_or_a_small_object_is_ignored_by_iou():
    truths, tracks, masks = _scene()
    for f in range(FRAMES):  # the static object's track grows onto the background a little
        masks[f][14, 15:19] = 30
    s = _score(truths, tracks, masks)
    assert s.by_iou.false_positives == 0
    for f in range(FRAMES):  # now most of it is background: a false positive
        masks[f][0:5, 15:20] = 30
    assert _score(truths, tracks, masks).by_iou.false_positives == FRAMES


# --- the baseline ----------------------------------------------------------------------------


def test_the_baseline_cuts_components_at_3d_steps_and_drops_small_ones():
    stands_out = np.zeros((30, 30), bool)
    stands_out[2:12, 2:22] = True  # one region in the image...
    stands_out[20:23, 20:23] = True  # ...and a small one
    xyz = np.zeros((30, 30, 3))
    xyz[..., 0] = np.arange(30)[None, :] * 0.005
    xyz[..., 1] = np.arange(30)[:, None] * 0.005
    xyz[..., 2] = np.where(np.arange(30)[None, :] < 12, 1.0, 1.0 + 2 * STEP_M)  # a step at u=12
    index, count = components(stands_out, xyz)
    assert count == 2
    assert MIN_PIXELS > 9
    assert set(np.unique(index[2:12, 2:12])) == {0}
    assert set(np.unique(index[2:12, 12:22])) == {1}
    assert (index[20:23, 20:23] == -1).all()
    assert (index[~stands_out] == -1).all()


# --- the family runner, through the command line ---------------------------------------------


def test_seeds_parse_as_ranges_and_lists():
    assert parse_seeds("1000-1003") == (1000, 1001, 1002, 1003)
    assert parse_seeds("0,2,5-6,2") == (0, 2, 5, 6)
    with pytest.raises(Exception, match="is not seeds"):
        parse_seeds("5-3")


def cells(row: str) -> list[str]:
    """A Markdown table row's cells."""
    return [cell.strip() for cell in row.strip().strip("|").split("|")]


def test_a_family_runs_both_trackers_reuses_captures_and_reports_failures(
    tmp_path, capsys, monkeypatch
):
    work, out = tmp_path / "work", tmp_path / "out"
    code = main(["evaluate", "--scene", "conveyor", "--seeds", "0-1", "--frames", "20",
                 "--work", str(work), "--out", str(out), "--workers", "1"])  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    doc = json.loads((out / "evaluation.json").read_text())
    assert [line["seed"] for line in doc["lines"]] == [0, 1]
    for line in doc["lines"]:
        assert line["frames"] == 20
        assert line["error"] is None
        assert line["scene"].startswith("conveyor, belt 0.25 m/s")
        for tracker in ("tofcut", "baseline"):
            scores = line["runs"][tracker]["scores"]
            assert {"by_centroid", "by_iou", "mask_iou", "mota", "idf1"} <= set(scores)
            assert scores["frames"] == 20
    assert [a["tracker"] for a in doc["aggregate"]] == ["tofcut", "baseline"]
    assert all(a["lines"] == 2 and a["by_iou"]["median_mota"] <= 1 for a in doc["aggregate"])
    md = (out / "evaluation.md").read_text()
    assert "| tofcut − baseline |" in md
    # each line's belt noise (the conveyor's belt is near and bright: a few millimetres),
    # the family split by it, and the two situations summed per tracker
    assert all(0.001 < line["belt_noise_m"] < 0.02 for line in doc["lines"])
    assert "| under 2 cm | 2 |" in md
    for a, line in ((a, doc["lines"][0]) for a in doc["aggregate"]):
        run = line["runs"][a["tracker"]]["situations"]
        assert set(run) == {"from_start", "from_start_held", "touching", "touching_apart"}
        assert a["situations"]["from_start"] == sum(
            x["runs"][a["tracker"]]["situations"]["from_start"] for x in doc["lines"]
        )
    assert "## Two situations" in md
    # every object-frame counted once, by how it was held
    for a in doc["aggregate"]:
        counted = sum(a["holding"].values())
        assert counted > 0
        assert counted == sum(
            sum(x["runs"][a["tracker"]]["holding"].values()) for x in doc["lines"]
        )
    assert "## Where the objects are lost" in md
    assert md in printed
    # HOTA, DetA and AssA in both tables, the baseline's too, as the JSON has them
    lines = md.splitlines()
    head = cells(next(x for x in lines if x.startswith("| seed |")))
    for tracker in ("tofcut", "baseline"):
        for name in ("MOTA", "IDF1", "HOTA", "DetA", "AssA", "switches", "mask IoU"):
            assert f"{tracker} {name}" in head
        scores = doc["lines"][1]["runs"][tracker]["scores"]
        row = cells(next(x for x in lines if x.startswith("| 1 |")))
        for key, name in (("hota", "HOTA"), ("deta", "DetA"), ("assa", "AssA")):
            shown = f"{scores['by_centroid'][key]:.3f} / {scores['by_iou'][key]:.3f}"
            assert row[head.index(f"{tracker} {name}")] == shown
    family_head = cells(next(x for x in lines if x.startswith("| tracker |")))
    for aggregate in doc["aggregate"]:
        row = cells(next(x for x in lines if x.startswith(f"| {aggregate['tracker']} |")))
        for key, name in (("median_hota", "median HOTA"), ("median_assa", "median AssA")):
            shown = f"{aggregate['by_centroid'][key]:.3f} / {aggregate['by_iou'][key]:.3f}"
            assert row[family_head.index(name)] == shown
    # the captures are recorded --bare, their truth beside them, and the trackers' outputs
    # score the same through `evaluate`
    seed0 = work / "conveyor" / "seed-0"
    assert set(CaptureReader(seed0 / "capture.tofcap").capture.metadata) == set(CAMERA_KEYS)
    assert len(load_truth(seed0 / "capture.truth.npz")) == 20
    # the baseline stamps its rows and masks as tofcut does: run-wide index, the camera's
    # sequence and time, the host's
    stamps = ("frame", "seq", "device_time_us", "host_time_ns")
    rows = {
        tracker: [json.loads(x) for x in (seed0 / f"{tracker}.tracks.jsonl").open()]
        for tracker in ("tofcut", "baseline")
    }
    assert [list(r)[:4] for r in rows["baseline"]] == [list(stamps)] * 20
    assert [[r[k] for k in stamps] for r in rows["baseline"]] == [
        [r[k] for k in stamps] for r in rows["tofcut"]
    ]
    assert [r["frame"] for r in rows["baseline"]] == list(range(20))
    for key in ("frame", "seq"):
        masks = [np.load(seed0 / f"{tracker}.masks.npz")[key] for tracker in rows]
        assert masks[0].tolist() == masks[1].tolist()
    js = tmp_path / "one.json"
    assert main(["evaluate", str(seed0 / "capture.tofcap"), "--tracks",
                 str(seed0 / "baseline.tracks.jsonl"), "--masks",
                 str(seed0 / "baseline.masks.npz"), "--json", str(js)]) == 0  # fmt: skip
    assert "by mask IoU >= 0.5: MOTA" in capsys.readouterr().out
    assert json.loads(js.read_text())["by_iou"] == doc["lines"][0]["runs"]["baseline"][
        "scores"]["by_iou"]  # fmt: skip

    # again, with a tracker that hands back the baseline's outputs (a command like any
    # other): seed 0's capture is reused and scores the same, seed 1's (its truth lost) is
    # recorded anew
    copy = "import shutil, sys; shutil.copy(sys.argv[1], sys.argv[3]); shutil.copy(*sys.argv[2::2])"

    def replay(cap, tracks, masks):
        done = [cap.parent / "baseline.tracks.jsonl", cap.parent / "baseline.masks.npz"]
        return [sys.executable, "-c", copy, str(done[0]), str(done[1]), str(tracks), str(masks)]

    monkeypatch.setitem(family.COMMANDS, "replay", replay)
    kept = (seed0 / "capture.tofcap").stat().st_mtime_ns
    (work / "conveyor" / "seed-1" / "capture.truth.npz").unlink()
    code = main(["evaluate", "--scene", "conveyor", "--seeds", "0-1", "--frames", "20",
                 "--work", str(work), "--trackers", "replay", "--json", str(js),
                 "--workers", "1"])  # fmt: skip
    assert code == 0
    assert (seed0 / "capture.tofcap").stat().st_mtime_ns == kept
    assert (work / "conveyor" / "seed-1" / "capture.truth.npz").is_file()
    again = json.loads(js.read_text())["lines"][0]["runs"]["replay"]["scores"]
    assert again == doc["lines"][0]["runs"]["baseline"]["scores"]
    assert "replay MOTA" in capsys.readouterr().out

    # a line that cannot be made is reported with its seed and error, and fails the run
    code = main(["evaluate", "--scene", "no-such-scene-{seed}", "--seeds", "3", "--frames",
                 "5", "--work", str(work), "--json", str(tmp_path / "bad.json"),
                 "--workers", "1"])  # fmt: skip
    printed = capsys.readouterr()
    assert code == 1
    assert "seed 3 (emulator:no-such-scene-3): no scene 'no-such-scene-3'" in printed.out
    assert "1 of 1 lines failed" in printed.err
    bad = json.loads((tmp_path / "bad.json").read_text())
    assert bad["failed"][0]["seed"] == 3


def test_bad_evaluate_arguments_are_one_line_errors(capsys):
    assert main(["evaluate", "--scene", "conveyor"]) == 1
    assert "needs --seeds" in capsys.readouterr().err
    assert main(["evaluate"]) == 1
    assert "evaluate needs CAPTURE" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["evaluate", "--family", "conveyor", "--seeds", "9-1"])
    assert "is not seeds" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["evaluate", "--scene", "conveyor", "--seeds", "1", "--trackers", "magic"])
