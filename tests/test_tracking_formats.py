"""`track`/`live` outputs in the standard tracking formats, and `evaluate --truth`: every row
on the run-wide frame index and the host's clock, `--mots-out` masks that TrackEval reads,
and HOTA that agrees with TrackEval's own evaluation of the same files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trackeval

from tofcut.driver.calibration import pixel_rays
from tofcut.driver.capture import CaptureReader, CaptureWriter
from tofcut.sim.truth import load_truth, truth_path
from tofcut.tools.cli import main
from tofcut.tools.pipeline import run as pipeline
from tofcut.tools.pipeline.mots import decode, encode, read_mots

FRAMES = 40


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


@pytest.fixture(scope="module")
def restarted(tmp_path_factory) -> Path:
    """A capture whose camera restarts its sequence halfway (one recording's records twice)."""
    folder = tmp_path_factory.mktemp("restart")
    once = folder / "once.tofcap"
    assert main(["record", "emulator", "--frames", "20", "--fast", "-o", str(once)]) == 0
    reader = CaptureReader(once)
    raws = list(reader.raw_frames())
    twice = folder / "twice.tofcap"
    with CaptureWriter(twice, reader.capture.metadata, reader.capture.calibration_block) as out:
        for raw in raws + raws:
            out.write(raw)
    return twice


def outputs(folder: Path) -> dict[str, Path]:
    return {
        "tracks": folder / "t.jsonl",
        "mot": folder / "t.txt",
        "mots": folder / "m.txt",
        "masks": folder / "m.npz",
    }


def track_argv(out: dict[str, Path]) -> list[str]:
    return [
        "--tracks-out", str(out["tracks"]), "--mot-out", str(out["mot"]),
        "--mots-out", str(out["mots"]), "--masks-out", str(out["masks"]), "--headless",
    ]  # fmt: skip


@pytest.fixture(scope="module")
def restarted_run(restarted, tmp_path_factory) -> dict[str, Path]:
    out = outputs(tmp_path_factory.mktemp("run"))
    assert main(["track", str(restarted), *track_argv(out)]) == 0
    return out


@pytest.fixture(scope="module")
def emulated(tmp_path_factory) -> tuple[Path, dict[str, Path]]:
    """The conveyor recorded with its truth and tracked, with every output."""
    folder = tmp_path_factory.mktemp("conveyor")
    capture = folder / "run.tofcap"
    argv = ["record", "emulator:conveyor", "--frames", str(FRAMES), "--fast", "-o", str(capture)]
    assert main(argv) == 0
    out = outputs(folder)
    assert main(["track", str(capture), *track_argv(out)]) == 0
    return capture, out


def jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# --- every row on the run-wide index, the camera's clock and the host's ----------------------


def test_every_jsonl_row_carries_the_run_s_index_the_camera_s_clock_and_the_host_s(
    restarted, restarted_run
):
    rows = jsonl(restarted_run["tracks"])
    raws = list(CaptureReader(restarted).raw_frames())
    assert [r["frame"] for r in rows] == list(range(40))  # never back ...
    assert rows[20]["seq"] < rows[19]["seq"]  # ... though the camera's sequence restarted
    assert [r["seq"] for r in rows] == [raw.sequence for raw in raws]
    assert [r["device_time_us"] for r in rows] == [raw.device_time_us for raw in raws]
    assert [r["host_time_ns"] for r in rows] == [raw.host_time_ns for raw in raws]
    assert list(rows[0]) == ["frame", "seq", "device_time_us", "host_time_ns", "tracks"]
    with np.load(restarted_run["masks"]) as z:
        assert z["frame"].tolist() == list(range(40))
        assert z["seq"].tolist() == [r["seq"] for r in rows]


def test_mot_and_mots_frames_are_the_run_s_index(restarted_run):
    rows = jsonl(restarted_run["tracks"])
    listed = [(r["frame"], t["id"]) for r in rows for t in r["tracks"]]
    assert listed, "the run tracked nothing: the test proves nothing"
    mot = np.loadtxt(restarted_run["mot"], delimiter=",", ndmin=2)
    assert [(int(f) - 1, int(i)) for f, i in mot[:, :2]] == listed  # MOT counts from 1
    mots = read_mots(restarted_run["mots"])
    assert [(o.frame, o.id) for o in mots] == listed  # MOTS from 0, as KITTI MOTS
    assert {o.class_id for o in mots} == {1}


def test_mots_masks_are_the_label_images(restarted_run):
    with np.load(restarted_run["masks"]) as z:
        labels = z["labels"]
    objects = read_mots(restarted_run["mots"])
    assert {(o.height, o.width) for o in objects} == {labels.shape[1:]}
    for o in objects:
        assert (decode(o.counts, o.height, o.width) == (labels[o.frame] == o.id)).all()
    for frame, image in enumerate(labels):  # and nothing in the images is left out
        ids = {o.id for o in objects if o.frame == frame}
        assert set(np.unique(image)) - {0} == ids


def test_mots_lines_are_written_as_the_run_goes(restarted, restarted_run, tmp_path, monkeypatch):
    def full_disk(self):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pipeline.MasksWriter, "close", full_disk)
    out = outputs(tmp_path)
    assert main(["track", str(restarted), *track_argv(out)]) == 1  # the end failed ...
    assert out["mots"].read_text() == restarted_run["mots"].read_text()  # ... nothing lost
    assert out["tracks"].read_text().count("\n") == 40


def test_live_writes_mots_lines_too(tmp_path):
    out = outputs(tmp_path)
    argv = ["live", "emulator:conveyor", "--fast", "--frames", "30", *track_argv(out)]
    assert main([*argv, "--deformable"]) == 0
    rows = jsonl(out["tracks"])
    mots = read_mots(out["mots"])
    assert [(o.frame, o.id) for o in mots] == [
        (r["frame"], t["id"]) for r in rows for t in r["tracks"]
    ]
    assert mots, "the run tracked nothing"
    assert {o.class_id for o in mots} == {2}  # deformable targets: KITTI MOTS's pedestrian


# --- evaluate --truth ---------------------------------------------------------------------------


def evaluate_json(capsys, *argv: str) -> tuple[list[str], dict]:
    assert main(["evaluate", *argv, "--json", "e.json"]) == 0
    return capsys.readouterr().out.splitlines(), json.loads(Path("e.json").read_text())


def mots_truth(capture: Path, path: Path) -> None:
    """The emulator's truth as MOTS lines: every visible object, class 1, frames from 0."""
    lines = []
    for frame, truth in enumerate(load_truth(truth_path(capture))):
        for oid in np.unique(truth.labels):
            if oid:
                mask = truth.labels == oid
                lines.append(f"{frame} {oid} 1 {mask.shape[0]} {mask.shape[1]} {encode(mask)}")
    path.write_text("\n".join(lines) + "\n")


def mot_truth(capture: Path, path: Path) -> None:
    """The emulator's truth as MOTChallenge rows: each visible object's surface centroid."""
    rays = pixel_rays(CaptureReader(capture).calibration)
    rows = []
    for frame, truth in enumerate(load_truth(truth_path(capture)), start=1):
        for oid in np.unique(truth.labels):
            if oid:
                mask = truth.labels == oid
                x, y, z = (rays[mask] * truth.range[mask][:, None]).mean(axis=0)
                rows.append(f"{frame},{oid},-1,-1,-1,-1,1,{x:.6f},{y:.6f},{z:.6f}")
    path.write_text("\n".join(rows) + "\n")


def trackeval_kitti_mots(truth: Path, tracks: Path, frames: int, folder: Path) -> dict:
    """TrackEval's own evaluation of MOTS files (its KITTI MOTS dataset, class car)."""
    (folder / "gt/label_02").mkdir(parents=True)
    (folder / "trackers/tofcut/data").mkdir(parents=True)
    (folder / "gt/label_02/run.txt").write_text(truth.read_text())
    (folder / "trackers/tofcut/data/run.txt").write_text(tracks.read_text())
    quiet = {"PRINT_CONFIG": False}
    evaluator = trackeval.Evaluator(
        {**quiet, "USE_PARALLEL": False, "PRINT_RESULTS": False, "TIME_PROGRESS": False,
         "OUTPUT_SUMMARY": False, "OUTPUT_DETAILED": False, "PLOT_CURVES": False}
    )  # fmt: skip
    dataset = trackeval.datasets.KittiMOTS(
        {**quiet, "GT_FOLDER": str(folder / "gt"), "TRACKERS_FOLDER": str(folder / "trackers"),
         "SEQ_INFO": {"run": frames}, "CLASSES_TO_EVAL": ["car"]}
    )  # fmt: skip
    metrics = [trackeval.metrics.HOTA(), trackeval.metrics.CLEAR(), trackeval.metrics.Identity()]
    results, _ = evaluator.evaluate([dataset], metrics)
    res = results["KittiMOTS"]["tofcut"]["run"]["car"]
    return {
        "hota": float(np.mean(res["HOTA"]["HOTA"])),
        "deta": float(np.mean(res["HOTA"]["DetA"])),
        "assa": float(np.mean(res["HOTA"]["AssA"])),
        "mota": float(res["CLEAR"]["MOTA"]),
        "idf1": float(res["Identity"]["IDF1"]),
        "id_switches": int(res["CLEAR"]["IDSW"]),
    }


def test_mots_out_scored_by_trackeval_itself_agrees_with_evaluate(emulated, tmp_path, capsys):
    capture, out = emulated
    truth = tmp_path / "gt.txt"
    mots_truth(capture, truth)
    expected = trackeval_kitti_mots(truth, out["mots"], FRAMES, tmp_path / "te")
    capsys.readouterr()
    assert expected["deta"] > 0.5, "the run tracked too little for the check to mean much"
    lines, doc = evaluate_json(capsys, "--truth", str(truth), "--masks", str(out["mots"]))
    assert doc["format"] == "MOTS"
    for key, value in expected.items():
        assert doc[key] == pytest.approx(value, abs=1e-9), key
    assert lines[0].startswith(f"{truth} (MOTS): {FRAMES} frames, ")
    assert lines[0].endswith("matched by mask IoU >= 0.5")
    assert f"HOTA {expected['hota']:.3f} (DetA {expected['deta']:.3f}, " in lines[1]
    # the run's label images score exactly as its MOTS lines
    _, from_npz = evaluate_json(capsys, "--truth", str(truth), "--masks", str(out["masks"]))
    assert from_npz == doc


def test_mot_truth_is_matched_by_3d_centroid(emulated, tmp_path, capsys):
    capture, out = emulated
    truth = tmp_path / "gt.txt"
    mot_truth(capture, truth)
    lines, doc = evaluate_json(capsys, "--truth", str(truth), "--tracks", str(out["tracks"]))
    assert doc["format"] == "MOTChallenge"
    assert doc["frames"] == FRAMES
    assert 0.5 < doc["hota"] <= 1
    assert 0.5 < doc["mota"] <= 1
    assert doc["hota"] == pytest.approx(np.sqrt(doc["deta"] * doc["assa"]), abs=0.05)
    assert lines[0].endswith("matched by 3D centroid within 0.1 m")
    assert lines[1].startswith(f"MOTA {doc['mota']:.3f}  IDF1 {doc['idf1']:.3f}  HOTA ")
    # the run's MOT rows score exactly as its JSONL
    _, from_mot = evaluate_json(capsys, "--truth", str(truth), "--tracks", str(out["mot"]))
    assert from_mot == doc
    # a tighter gate matches less
    _, tight = evaluate_json(
        capsys, "--truth", str(truth), "--tracks", str(out["tracks"]), "--gate", "0.005"
    )
    assert tight["deta"] < doc["deta"]


def test_a_run_scored_against_its_own_files_is_perfect(emulated, capsys):
    _, out = emulated
    _, doc = evaluate_json(capsys, "--truth", str(out["mot"]), "--tracks", str(out["tracks"]))
    _, docs = evaluate_json(capsys, "--truth", str(out["mots"]), "--masks", str(out["masks"]))
    for d in (doc, docs):
        assert d["objects"] > 0
        assert (d["mota"], d["idf1"], d["hota"], d["deta"], d["assa"]) == (1, 1, 1, 1, 1)


def test_truth_rows_not_to_score_make_nearby_tracks_neither_hits_nor_false_positives(
    emulated, tmp_path, capsys
):
    _, out = emulated
    rows = out["mot"].read_text().splitlines()
    truth = tmp_path / "gt.txt"
    fields = [r.split(",") for r in rows]
    truth.write_text("".join(",".join([*f[:6], "0", *f[7:]]) + "\n" for f in fields))  # conf 0
    _, doc = evaluate_json(capsys, "--truth", str(truth), "--tracks", str(out["tracks"]))
    assert (doc["objects"], doc["false_positives"]) == (0, 0)


def test_emulator_truth_reports_hota_beside_the_lines_it_always_printed(emulated, capsys):
    capture, out = emulated
    argv = [str(capture), "--tracks", str(out["tracks"]), "--masks", str(out["masks"])]
    lines, doc = evaluate_json(capsys, *argv)
    assert len(lines) == 3
    assert lines[0].startswith(f"{FRAMES} frames, ")
    assert ": MOTA " in lines[0]
    assert lines[1].startswith("by mask IoU >= 0.5: MOTA ")
    c, i = doc["by_centroid"], doc["by_iou"]
    assert lines[2] == (
        f"HOTA by centroid {c['hota']:.3f} (DetA {c['deta']:.3f}, AssA {c['assa']:.3f}); "
        f"by mask IoU {i['hota']:.3f} (DetA {i['deta']:.3f}, AssA {i['assa']:.3f})"
    )
    assert 0.5 < c["hota"] <= 1
    assert 0.5 < i["hota"] <= 1
    assert doc["mota"] == c["mota"]  # the legacy keys stay where they were


# --- mistakes ------------------------------------------------------------------------------------


def error_line(capsys, argv: list[str]) -> tuple[int, str]:
    """The exit status and the one line of a command that fails."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own checks
        code = int(exc.code or 0)
    err = capsys.readouterr().err.strip()
    assert err.startswith("tofcut: error: "), err
    assert "\n" not in err, err
    return code, err


def test_evaluate_truth_mistakes_are_one_line(emulated, tmp_path, capsys):
    capture, out = emulated
    t, m, mot, mots = (str(out[k]) for k in ("tracks", "masks", "mot", "mots"))
    odd = tmp_path / "odd.txt"
    odd.write_text("hello world\n")
    first, *rest = Path(mots).read_text().splitlines(keepends=True)
    broken = tmp_path / "broken.txt"
    broken.write_text(first + rest[0].replace(" 144 176 ", " 144 x ", 1))
    no_xyz = tmp_path / "noxyz.txt"
    no_xyz.write_text("1,1,10,10,5,5,1,-1,-1,-1\n")
    cases = [  # usage mistakes: 2; files that are not what they should be: 1
        (["--truth", mot, "--masks", m], 2, "give the run's tracks, --tracks"),
        (["--truth", mots, "--tracks", t], 2, "give the run's masks, --masks"),
        ([str(capture), "--truth", mot, "--tracks", t], 2, "give no CAPTURE"),
        (["--truth", "gone.txt", "--tracks", t], 2, "gone.txt does not exist"),
        (["--truth", str(odd), "--tracks", t], 1, "is neither MOTChallenge rows"),
        (["--truth", mot, "--tracks", m], 1, "is an .npz file"),
        (["--truth", str(broken), "--masks", m], 1, "broken.txt, line 2: not a MOTS line"),
        (["--truth", str(no_xyz), "--tracks", t], 1, "has no x,y,z"),
    ]
    for argv, code, words in cases:
        got, line = error_line(capsys, ["evaluate", *argv])
        assert (got, words in line) == (code, True), (argv, line)


def test_the_mots_folder_is_checked_before_the_run(capsys, restarted, tmp_path):
    argv = ["track", str(restarted), "--mots-out", "/nonexistent/out/m.txt"]
    code, line = error_line(capsys, argv)
    assert code == 2
    assert "folder /nonexistent/out does not exist" in line
    assert list(tmp_path.iterdir()) == []  # nothing ran
