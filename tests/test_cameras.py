"""Many cameras on one box (`tofcut live CAMERA CAMERA ...`, `--cameras FILE`): a worker
process per camera with its own outputs and entity tree, a worker that dies restarted and
said so, every process gone after Ctrl-C or SIGTERM, and a camera list whose mistakes are
said in one line."""

from __future__ import annotations

import functools
import importlib
import json
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import rerun_cli
from rerun.chunk import RrdReader

from tofcut.tools.cli import build_parser, main
from tofcut.tools.commands import cameras
from tofcut.tools.commands.arguments import UsageError
from tofcut.tools.commands.camera_list import CameraEntry, CameraListError, load_camera_list
from tofcut.tools.commands.cameras import plan_jobs
from tofcut.tools.pipeline.sources import SourceSpec

WAIT_S = 120.0
LOOPBACK = "127.0.0.1"
RERUN_CLI = Path(rerun_cli.__file__).with_name("rerun")
FIRST, SECOND = "4000002F", "40000030"
"""The serial numbers of the first two emulated cameras of a box."""


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


def lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def live_args(*argv: str):
    return build_parser(["live"]).parse_args(["live", *argv])


# --- two cameras under one `tofcut live` ----------------------------------------------------


def test_two_cameras_get_their_own_files_and_trees_and_a_dead_worker_is_restarted(
    tmp_path, capsys, monkeypatch
):
    """Two emulated cameras under one `tofcut live`, a scene and a capture replayed, the
    first one's worker killed at its first frame: each camera's own serial number, tracks,
    files and entity tree; the restart said."""

    def kill_once(camera: cameras.CameraRun, supervisor: cameras.Supervisor) -> None:
        if camera.serial == FIRST and camera.restarts == 0:
            supervisor.kill(camera)

    monkeypatch.setattr(
        cameras, "Supervisor", functools.partial(cameras.Supervisor, on_health=kill_once)
    )
    record = ["record", "emulator:conveyor", "--seed", "2", "--fast", "--frames", "12"]
    assert main([*record, "-o", "cap.tofcap"]) == 0
    listing = tmp_path / "box.toml"
    listing.write_text(
        '[[camera]]\nsource = "emulator:conveyor"\nseed = 1\n\n'
        '[[camera]]\nsource = "emulator:cap.tofcap"\ntracks_out = "second.jsonl"\n'
    )
    argv = ["live", "--cameras", str(listing), "--fast", "--frames", "12", "--tracks-out",
            "tracks.jsonl", "--save", "run.rrd", "--summary-json", "box.json"]  # fmt: skip
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert f"camera {FIRST}: its worker killed by SIGKILL; restarting it (1 of at most 3)" in (
        captured.err
    )
    second = lines(tmp_path / "second.jsonl")
    assert [r["frame"] for r in second] == list(range(12))
    restarted = lines(tmp_path / f"tracks-{FIRST}-restart1.jsonl")
    assert 0 < len(restarted) <= 12
    assert restarted != second[: len(restarted)]  # two cameras (two noise seeds), two runs
    summary = {c["serial"]: c for c in json.loads((tmp_path / "box.json").read_text())["cameras"]}
    assert (summary[FIRST]["restarts"], summary[SECOND]["restarts"]) == (1, 0)
    assert summary[FIRST]["frames"] >= 12
    assert summary[SECOND]["frames"] == 12
    assert summary[FIRST]["exit_status"] == summary[SECOND]["exit_status"] == 0
    assert f"{SECOND}: 12 frames tracked" in captured.out
    assert "1 restarts" in captured.out
    assert f"camera {SECOND} (emulator:cap.tofcap):" in captured.out
    assert f"{SECOND}: camera {SECOND} (emulator:cap.tofcap): 30 MHz" in captured.out
    # one recording, a tree per camera, in one file per camera
    ids = set()
    for name, serial in ((f"run-{FIRST}-restart1.rrd", FIRST), (f"run-{SECOND}.rrd", SECOND)):
        reader = RrdReader(tmp_path / name)
        (recording,) = reader.recordings()
        ids.add(recording.recording_id)
        entities = {ch.entity_path for ch in reader.stream()} - {"/__properties"}
        assert f"/cameras/{serial}/world/camera/depth" in entities
        assert all(e.startswith(f"/cameras/{serial}/") for e in entities)
    assert len(ids) == 1


def descendants(pid: int) -> list[int]:
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            found += [int(child), *descendants(int(child))]
    return found


def gone(pid: int) -> bool:
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        return bool(select.select([fd], [], [], WAIT_S)[0])
    finally:
        os.close(fd)


def free_port() -> int:
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_or_sigterm_stops_every_worker_and_leaves_no_process(tmp_path, sig):
    """Two real-time cameras streaming to one viewer (rerun's own server, saving what it is
    sent), stopped by Ctrl-C or SIGTERM: every worker closes its outputs, no process is left,
    and the viewer got one recording with a tree per camera."""
    port = free_port()
    viewer = subprocess.Popen(
        [str(RERUN_CLI), "--bind", LOOPBACK, "--port", str(port), "--save", "got.rrd"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path,
        env=dict(os.environ, RERUN_ANALYTICS="0"),
    )  # fmt: skip
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "tofcut.tools.cli", "live", "emulator:test-pattern",
         "emulator:test-pattern", "--seconds", "0", "--tracks-out", "t.jsonl",
         "--url", f"rerun+http://{LOOPBACK}:{port}/proxy"],
        stdout=subprocess.PIPE, stderr=slave, text=True, cwd=tmp_path,
    )  # fmt: skip
    os.close(slave)
    seen = b""
    try:
        while b" fps " not in seen:  # the status line: the cameras' runs have begun
            ready, _, _ = select.select([master], [], [], WAIT_S)
            assert ready, f"no status line: {seen!r}"
            seen += os.read(master, 4096)
        processes = descendants(proc.pid)
        assert len(processes) == 4  # two workers, each with its emulator
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
        viewer.send_signal(signal.SIGINT)  # it writes what it got, and ends
        viewer.wait(WAIT_S)
    assert proc.returncode == 130
    assert all(gone(pid) for pid in processes)
    for serial in (FIRST, SECOND):
        assert lines(tmp_path / f"t-{serial}.jsonl")  # written, and whole
        assert f"{serial}: " in out
    assert out.count("stopped by Ctrl-C after") == 2
    assert "error" not in out
    with warnings.catch_warnings():  # a stream saved by the viewer has no footer
        warnings.simplefilter("ignore")
        reader = RrdReader(tmp_path / "got.rrd")
        assert len(reader.recordings()) == 1
        entities = {ch.entity_path for ch in reader.stream()}
    for serial in (FIRST, SECOND):
        assert f"/cameras/{serial}/world/camera/depth" in entities


# --- planning: names, files, recordings -----------------------------------------------------


def entries(*names: str) -> list[CameraEntry]:
    return [CameraEntry(SourceSpec.parse(n)) for n in names]


def test_emulated_cameras_are_numbered_and_their_files_named_after_them(tmp_path):
    args = live_args("--tracks-out", "t.jsonl", "--save", "run.rrd")
    jobs = plan_jobs(args, entries("emulator", "usb:ABC", "emulator:conveyor"))
    assert [jobs[0].serial, jobs[2].serial] == [0x4000002F, 0x40000030]
    assert [j.args.tracks_out.name for j in jobs] == [
        f"t-{FIRST}.jsonl",
        "t-ABC.jsonl",
        f"t-{SECOND}.jsonl",
    ]
    assert [Path(j.args.save).name for j in jobs] == [
        f"run-{FIRST}.rrd",
        "run-ABC.rrd",
        f"run-{SECOND}.rrd",
    ]
    trees = [j.tree for j in jobs]
    assert [t.root for t in trees] == [f"cameras/{FIRST}", "cameras/ABC", f"cameras/{SECOND}"]
    assert len({t.recording_id for t in trees}) == 1
    assert trees[0].recording_id is not None
    assert all(t.roots == tuple(x.root for x in trees) for t in trees)
    own = plan_jobs(live_args("--rerun-per-camera", "file"), entries("emulator", "emulator"))
    assert [(j.tree.root, j.tree.recording_id) for j in own] == [("", None), ("", None)]


@pytest.mark.parametrize(
    ("argv", "names", "message"),
    [
        ([], ["usb", "usb:A"], "name each USB camera as usb:SERIAL"),
        ([], ["usb:A", "usb:A"], "camera A is named twice"),
        (["--serve"], ["emulator", "emulator"], "cannot share --serve"),
        (["--stdout"], ["emulator", "emulator"], "cannot share --stdout"),
        (["--conveyor-emulator"], ["emulator", "emulator"], "the conveyor options take one"),
    ],
)
def test_cameras_that_cannot_run_together_are_refused(argv, names, message):
    with pytest.raises(UsageError, match=message):
        plan_jobs(live_args(*argv), entries(*names))


def test_two_cameras_writing_one_file_are_refused(tmp_path):
    listing = tmp_path / "box.toml"
    listing.write_text(
        '[[camera]]\nsource = "emulator"\ntracks_out = "same.jsonl"\n\n'
        '[[camera]]\nsource = "emulator"\ntracks_out = "same.jsonl"\n'
    )
    with pytest.raises(UsageError, match=r"same\.jsonl is the output of two cameras"):
        plan_jobs(live_args(), load_camera_list(listing))


# --- the camera list ------------------------------------------------------------------------


def test_a_camera_list_reads_every_camera_s_settings(tmp_path):
    listing = tmp_path / "box.toml"
    listing.write_text(
        '[[camera]]\nsource = "usb:4000A1B2"\nfps = 25\n\n'
        '[[camera]]\nsource = "emulator:tools"\nseed = 7\nmasks_out = "m.npz"\n'
    )
    first, second = load_camera_list(listing)
    assert first.source == SourceSpec("usb", "4000A1B2")
    assert (first.fps, first.seed, first.outputs) == (25.0, None, {})
    assert second.source == SourceSpec("emulator", "tools")
    assert (second.seed, second.outputs) == (7, {"masks_out": Path("m.npz")})


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "no [[camera]] tables"),
        ("[[cameras]]\nsource = 'usb:A'\n", "unknown table [[cameras]]; did you mean [[camera]]?"),
        ("[[camera]]\nseed = 1\n", "camera 1: no source"),
        ("[[camera]]\nsource = 'usb:A'\n[[camera]]\nsource = 'gopro'\n",
         "camera 2: source: 'gopro' is not a source"),
        ("[[camera]]\nsource = 'usb:A'\nsed = 1\n",
         "camera 1: unknown key 'sed'; did you mean seed?"),
        ("[[camera]]\nsource = 'usb:A'\nseed = 1.5\n", "camera 1: seed must be a whole number"),
        ("[[camera]]\nsource = 'usb:A'\nfps = -1\n",
         "camera 1: fps must be a number, 0 or more, not -1"),
        ("[[camera]]\nsource = 'usb:A'\nfps = 'fast'\n", "camera 1: fps must be a number, 0 or "
         "more, not 'fast'"),
        ("[[camera]]\nsource = 'usb:A'\ntracks_out = 3\n", "camera 1: tracks_out must be a string"),
        ("[[camera]]\nsource = 'usb:A'\ntracks_out = 'no/such/t.jsonl'\n",
         "camera 1: tracks_out: cannot write no/such/t.jsonl: folder no/such does not exist"),
        ("[[camera]\n", "Expected ']]' at the end of an array declaration"),
        ("[[camera]]\nsource = 'capture.tofcap'\n", "camera 1: source: capture.tofcap: this "
         "command reads from a camera"),
    ],
)  # fmt: skip
def test_a_bad_camera_list_is_said_in_one_line(tmp_path, text, message):
    listing = tmp_path / "box.toml"
    listing.write_text(text)
    with pytest.raises(CameraListError) as caught:
        load_camera_list(listing)
    assert message in str(caught.value)
    assert str(caught.value).startswith(f"{listing}: ")
    assert "\n" not in str(caught.value)


def test_a_bad_camera_list_ends_the_command_with_one_line_and_status_2(tmp_path, capsys):
    listing = tmp_path / "box.toml"
    listing.write_text("[[camera]]\nsource = 'emulator'\ncolour = 'red'\n")
    assert main(["live", "--cameras", str(listing)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line == f"tofcut: error: {listing}: camera 1: unknown key 'colour'; known: " + (
        "fps, masks_out, mot_out, mots_out, seed, source, tracks_out"
    )


# --- the tracker's kernels ------------------------------------------------------------------


def test_every_tracker_kernel_runs_without_the_gil():
    """A camera's reader and rerun threads never wait on the tracker's compiled loops (or
    demodulation's)."""
    from tofcut.driver import demod_kernels
    from tofcut.tracker import compiled

    for name in compiled.kernel_modules():
        importlib.import_module(name)
    dispatchers = [d for d, _ in compiled.KERNELS.values()] + list(compiled.HELPERS.values())
    assert len(dispatchers) > 30
    dispatchers += [demod_kernels.taps_to_signal, demod_kernels.phase_to_points]
    assert all(d.targetoptions.get("nogil") for d in dispatchers)
