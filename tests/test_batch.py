"""Batch runs on Ray: a batch on two Ray workers gives the table the same runs give one by
one; a failing task is run once more and reported, never dropped; Ray leaves no process."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest

from tofcut.tools.batch.pool import Pool
from tofcut.tools.batch.tasks import run_tasks
from tofcut.tools.cli import main


def _processes_under(folder: Path) -> list[str]:
    """The command lines of the processes that name `folder` (Ray's own name its files)."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if str(folder) in cmdline:
            found.append(f"{proc.name}: {cmdline[:120]}")
    return found


@pytest.fixture
def ray_temp(monkeypatch):
    """A short temporary folder for Ray's files (its sockets' paths are limited to 107
    bytes), checked at the end for processes Ray left behind."""
    folder = Path(tempfile.mkdtemp(prefix="tofcut-test-", dir="/tmp"))
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    yield folder
    assert list(folder.glob("tofcut-ray-*")) == []  # its files are removed at the end
    assert _processes_under(folder) == []
    folder.rmdir()


def _without_times(doc):
    """A family's JSON without the trackers' wall times (the one thing that may differ)."""
    for line in doc["lines"]:
        for run in line["runs"].values():
            run.pop("seconds")
    return doc


def test_a_batch_on_two_ray_workers_gives_the_table_of_the_runs_one_by_one(
    tmp_path, capsys, ray_temp
):
    # the lines are recorded by the first run, on Ray, and reused by the second (rendering
    # is the slow part)
    work, tables, recorded = tmp_path / "work", {}, {}
    for workers in ("2", "1"):
        out = tmp_path / f"out{workers}"
        code = main(["evaluate", "--scene", "conveyor", "--seeds", "0-1", "--frames", "8",
                     "--trackers", "tofcut", "--workers", workers, "--work", str(work),
                     "--out", str(out)])  # fmt: skip
        printed, err = capsys.readouterr()
        assert code == 0, printed + err
        assert ("2 at a time on a local Ray" if workers == "2" else "one at a time") in printed
        tables[workers] = (
            (out / "evaluation.md").read_text(),
            _without_times(json.loads((out / "evaluation.json").read_text())),
        )
        recorded[workers] = [p.stat().st_mtime_ns for p in sorted(work.rglob("capture.tofcap"))]
    assert tables["1"] == tables["2"]
    assert len(recorded["2"]) == 2
    assert recorded["1"] == recorded["2"]
    md = tables["2"][0]
    assert "| 0 | conveyor" in md
    assert "| 1 | conveyor" in md
    assert "Failed" not in md


def _flaky_task():
    """A task that fails its first attempt as its job says (raises, or its worker dies), or
    every attempt ("always"), else returns its name. Made here so that Ray's workers get it
    by value (they cannot import the tests)."""

    def flaky(job):
        name, marker = job
        if name == "always":
            raise ValueError("broken for good")
        if name in ("raises", "dies") and not marker.exists():
            marker.touch()
            if name == "dies":
                os._exit(3)
            raise RuntimeError("only the first time")
        return name

    return flaky


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_task_is_run_once_more_and_reported(tmp_path, ray_temp, workers):
    kinds = ["fine", "raises", "always"] + (["dies"] if workers > 1 else [])
    jobs = [(k, tmp_path / f"{k}.{workers}") for k in kinds]
    retries = []
    with Pool(workers) as pool:
        assert (pool.ray is not None) == (workers > 1)
        outcomes = run_tasks(
            _flaky_task(), jobs, pool, on_retry=lambda job, why: retries.append((job[0], why))
        )
    assert [o.item for o in outcomes] == jobs  # in the items' order, none dropped
    by = {o.item[0]: o for o in outcomes}
    assert (by["fine"].result, by["fine"].error, by["fine"].retried) == ("fine", None, None)
    assert by["raises"].result == "raises"
    assert by["raises"].error is None
    assert by["raises"].retried == "RuntimeError: only the first time"
    assert by["always"].result is None
    assert by["always"].error == by["always"].retried == "ValueError: broken for good"
    if workers > 1:
        assert by["dies"].result == "dies"
        assert by["dies"].error is None
        assert "worker was lost" in by["dies"].retried
    assert sorted(k for k, _ in retries) == sorted(k for k in kinds if k != "fine")


def test_a_failing_line_is_run_twice_and_reported_with_its_error(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["evaluate", "--scene", "no-such-scene-{seed}", "--seeds", "3", "--frames",
                 "5", "--workers", "1", "--work", str(tmp_path / "work"), "--out",
                 str(out)])  # fmt: skip
    printed = capsys.readouterr()
    assert code == 1
    assert "seed 3 failed (no scene 'no-such-scene-3'" in printed.out
    assert "running it once more" in printed.out
    assert "1 of 1 lines failed" in printed.err
    doc = json.loads((out / "evaluation.json").read_text())
    assert doc["failed"][0]["seed"] == 3
    assert doc["retried"][0]["first_error"].startswith("no scene 'no-such-scene-3'")
    md = (out / "evaluation.md").read_text()
    assert "## Failed" in md
    assert "## Run twice" in md


def test_many_captures_are_tracked_and_scored_as_a_batch(tmp_path, capsys):
    caps = tmp_path / "caps"
    caps.mkdir()
    for name, seed in (("a", "0"), ("b", "1")):
        assert main(["record", "emulator:conveyor", "-o", str(caps / f"{name}.tofcap"),
                     "--frames", "8", "--fast", "--seed", seed]) == 0  # fmt: skip
    captures = [str(caps / "a.tofcap"), str(caps / "b.tofcap")]
    runs = tmp_path / "runs"
    assert main(["track", *captures, "--out", str(runs), "--workers", "1"]) == 0
    tracked = json.loads((runs / "track.json").read_text())["captures"]
    assert [(c["name"], c["frames"], c["error"]) for c in tracked] == [
        ("a", 8, None), ("b", 8, None)]  # fmt: skip
    assert main(["evaluate", *captures, "--runs", str(runs), "--workers", "1", "--out",
                 str(tmp_path / "scores")]) == 0  # fmt: skip
    doc = json.loads((tmp_path / "scores" / "evaluation.json").read_text())
    assert doc["aggregate"]["lines"] == 2
    # each run scores as `tofcut evaluate` scores it alone
    one = tmp_path / "one.json"
    assert main(["evaluate", captures[1], "--tracks", str(runs / "b.tracks.jsonl"), "--masks",
                 str(runs / "b.masks.npz"), "--json", str(one)]) == 0  # fmt: skip
    alone = json.loads(one.read_text())
    assert doc["runs"][1]["scores"]["by_iou"] == alone["by_iou"]
    capsys.readouterr()
    # a capture whose run is missing is reported by name, and fails the batch
    (runs / "a.masks.npz").unlink()
    assert main(["evaluate", *captures, "--runs", str(runs), "--workers", "1"]) == 1
    printed = capsys.readouterr()
    assert "a: failed: masks file" in printed.out
    assert "1 of 2 runs failed" in printed.err
    # two captures of one name would overwrite each other's runs
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "a.tofcap").write_bytes((caps / "a.tofcap").read_bytes())
    assert main(["track", captures[0], str(tmp_path / "other" / "a.tofcap"), "--out",
                 str(runs), "--workers", "1"]) == 2  # fmt: skip
    assert "would both write a.*" in capsys.readouterr().err
