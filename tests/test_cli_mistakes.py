"""The command line as a new user meets it: ordinary mistakes end in one line and an exit
status (2: usage, 1: failure) with no traceback unless `--debug`; what is given is checked
before the run; start-up imports only what the command needs; `-v`/`-q` set the logs;
damaged input and Ctrl-C end with the closing lines; `--headless` writes nothing; a fast
emulated recording is the same bit for bit."""

from __future__ import annotations

import json
import logging
import os
import pty
import select
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tofcut.driver.capture import CaptureReader
from tofcut.tools import cli
from tofcut.tools.cli import main
from tofcut.tools.commands import ports, tracking
from tofcut.tools.pipeline.run import MasksWriter
from tofcut.tools.pipeline.status import PipelineStatus

REPO = Path(__file__).resolve().parent.parent
HEAVY = ("motmetrics", "pandas", "rerun", "numba", "scipy", "maxflow", "tofcut.tracker.tracker")


def cli_process(*argv: str, **kwargs) -> subprocess.CompletedProcess[str]:
    """`tofcut ARGV` as its own process (what a shell runs)."""
    return subprocess.run(
        [sys.executable, "-m", "tofcut.tools.cli", *argv],
        capture_output=True, text=True, timeout=240, **kwargs,
    )  # fmt: skip


def usage_error(capsys, argv: list[str]) -> str:
    """The one line a usage error prints (exit status 2)."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("tofcut: error: ")
    assert "usage:" not in err
    assert "Traceback" not in err
    return lines[0]


def one_line_failure(capsys, argv: list[str], code: int = 1) -> str:
    assert main(argv) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("tofcut: error: "), err
    assert not any("Traceback" in line for line in err)
    return err[-1]


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cap") / "run.tofcap"
    assert main(["record", "emulator:conveyor", "-o", str(path), "--frames", "4", "--fast"]) == 0
    return path


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a run that saves a default .rrd saves it here


# --- 1. ordinary mistakes ------------------------------------------------------------------


@pytest.mark.parametrize("command", ["track", "convert", "info"])
def test_a_capture_that_does_not_exist_is_said_so(capsys, command):
    argv = [command, "nope.tofcap"] + (["-o", "x.npz"] if command == "convert" else [])
    line = usage_error(capsys, argv)
    assert "nope.tofcap does not exist" in line


def test_a_folder_given_as_a_capture_is_said_so(capsys, tmp_path):
    (tmp_path / "adir").mkdir()
    line = usage_error(capsys, ["track", "adir"])
    assert "adir is a folder, not a capture" in line
    assert "invalid" not in line


def test_output_folders_are_checked_before_the_run(capsys, capture, tmp_path):
    gone = "/nonexistent/out"
    for argv in (
        ["record", "emulator", "--fast", "--frames", "2", "-o", f"{gone}/a.tofcap"],
        ["convert", str(capture), "-o", f"{gone}/x.npz"],
        ["track", str(capture), "--tracks-out", f"{gone}/t.jsonl"],
        ["track", str(capture), "--masks-out", f"{gone}/m.npz"],
        ["track", str(capture), "--mots-out", f"{gone}/m.txt"],
    ):
        line = usage_error(capsys, argv)
        assert "folder /nonexistent/out does not exist" in line, line
    assert list(tmp_path.iterdir()) == []  # nothing ran: not even a recording was started


def test_evaluate_says_which_file_is_missing_or_swapped(capsys, capture, tmp_path):
    tracks, masks = tmp_path / "t.jsonl", tmp_path / "m.npz"
    tracks.write_text(json.dumps({"seq": 0, "tracks": []}) + "\n")
    np.savez_compressed(masks, labels=np.zeros((1, 144, 176), np.uint16), seq=np.zeros(1))
    cap = str(capture)
    line = usage_error(capsys, ["evaluate", cap, "--tracks", "no.jsonl", "--masks", str(masks)])
    assert "no.jsonl does not exist" in line
    line = usage_error(
        capsys, ["evaluate", "nope.tofcap", "--tracks", str(tracks), "--masks", str(masks)]
    )
    assert "capture nope.tofcap does not exist" in line
    assert "truth" not in line
    t, m = str(tracks), str(masks)
    line = one_line_failure(capsys, ["evaluate", cap, "--tracks", m, "--masks", t])
    assert "is an .npz file, not a tracks file" in line
    line = one_line_failure(capsys, ["evaluate", cap, "--tracks", t, "--masks", t])
    assert "is not an .npz file" in line


def test_a_target_pixel_is_checked(capsys, capture):
    line = usage_error(capsys, ["track", str(capture), "--target-pixel", "abc"])
    assert "'abc' is not U,V" in line
    assert "_pixel" not in line
    line = one_line_failure(
        capsys, ["track", str(capture), "--target-pixel", "999,999", "--headless"], code=2
    )
    assert "--target-pixel 999,999 is outside the frame: the image is 176x144" in line


@pytest.mark.parametrize(
    ("option", "value"), [("--frames", "0"), ("--frames", "-5"), ("--seconds", "-1")]
)
def test_counts_and_durations_must_be_positive(capsys, capture, option, value):
    line = usage_error(capsys, ["track", str(capture), option, value])
    assert f"argument {option}: must be" in line
    if option == "--seconds":
        assert "must be 0 or more" in usage_error(capsys, ["live", option, value])
    else:
        usage_error(capsys, ["live", option, value])
        usage_error(capsys, ["record", "emulator", "-o", "x.tofcap", option, value])


@pytest.mark.parametrize("command", ["live", "record"])
def test_camera_commands_neither_offer_nor_take_a_capture(capsys, capture, command):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    help_text = capsys.readouterr().out
    source_help = next(
        x for x in help_text.splitlines() if x.strip().startswith(("SOURCE", "CAMERA"))
    )
    assert "FILE.tofcap" not in source_help
    argv = [command, str(capture)] + (["-o", "x.tofcap"] if command == "record" else [])
    assert "reads from a camera" in usage_error(capsys, argv)


def test_an_unexpected_error_is_one_line_unless_debug(capsys, monkeypatch):
    def broken(args):
        raise RuntimeError("something inside broke")

    monkeypatch.setattr(ports, "run", broken)
    line = one_line_failure(capsys, ["ports"])
    assert "RuntimeError: something inside broke" in line
    assert "--debug" in line
    with pytest.raises(RuntimeError, match="inside broke"):
        main(["--debug", "ports"])


def test_a_shell_sees_one_line_and_no_traceback():
    done = cli_process("track", "nope.tofcap")
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "tofcut: error: track: argument SOURCE: capture nope.tofcap does not exist "
        "(see 'tofcut track --help')"
    ]


def test_masks_are_written_whole_or_not_at_all(tmp_path):
    class Tracked:
        def __init__(self, seq: int) -> None:
            self.sequence, self.labels = seq, np.full((4, 6), seq, np.uint16)

    path = tmp_path / "m.npz"
    writer = MasksWriter(path)
    for seq in range(3):
        status = PipelineStatus(0.0, 0.0, seq + 1, 0, 0)
        writer.write(Tracked(seq), status)  # type: ignore[arg-type]
    writer.close()
    with np.load(path) as z:
        assert z["seq"].tolist() == [0, 1, 2]
        assert z["frame"].tolist() == [0, 1, 2]
        assert z["labels"].shape == (3, 4, 6)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]  # no partial file left


# --- 2. start-up --------------------------------------------------------------------------


def test_help_version_devices_and_ports_import_nothing_heavy():
    code = (
        "import sys, contextlib, io\n"
        "from tofcut.tools.cli import main\n"
        "for argv in (['--version'], ['--help'], ['track', '--help']):\n"
        "    if argv[0] == 'track': break\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "        main(argv)\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    assert main(['ports']) == 0\n"
        "    assert main(['devices']) == 0\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.strip() == "[]", done.stdout + done.stderr


def test_every_command_is_listed_with_its_own_help():
    full = cli.build_parser()
    lazy = cli.build_parser(["--help"])

    def helps(parser):
        action = next(a for a in parser._actions if a.dest == "command")
        return {c.dest: c.help for c in action._choices_actions}

    assert helps(lazy) == helps(full) == {k: v[1] for k, v in cli.COMMANDS.items()}


# --- 3. -v / -q ---------------------------------------------------------------------------


def test_verbose_and_quiet_set_the_logs_of_tofcut_and_its_libraries(capsys, monkeypatch):
    def chatty(args):
        logging.getLogger("tofcut.driver.conveyor.link").info("a note")
        logging.getLogger("tofcut.driver.conveyor.link").warning("a warning")
        from pymodbus.client import ModbusSerialClient  # its own chatter, through logging

        client = ModbusSerialClient("/dev/no-such-port-for-tofcut")
        assert not client.connect()
        client.close()
        return 0

    monkeypatch.setattr(ports, "run", chatty)
    assert main(["ports"]) == 0
    assert capsys.readouterr().err.splitlines() == ["tofcut: warning: a warning"]
    assert main(["-q", "ports"]) == 0
    assert capsys.readouterr().err == ""
    assert main(["-v", "ports"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[:2] == ["tofcut: info: a note", "tofcut: warning: a warning"]
    assert any(x.startswith("tofcut: pymodbus: error: ") for x in err[2:]), err
    main(["ports"])  # back to the default for the tests that follow


def test_quiet_silences_rerun_native_log_and_colour():
    env = {k: v for k, v in os.environ.items() if k not in ("RUST_LOG", "NO_COLOR")}
    code = (
        "import os, contextlib, io\n"
        "from tofcut.tools.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()): main(['-q', 'ports'])\n"
        "print(os.environ['RUST_LOG'], os.environ['NO_COLOR'])\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
    )
    assert done.stdout.split() == ["off", "1"]


# --- 4. damaged input, Ctrl-C; 5. --headless -----------------------------------------------


def _damaged(capture: Path, tmp_path: Path, how: str) -> Path:
    data = bytearray(capture.read_bytes())
    start = CaptureReader(capture)._records_start
    path = tmp_path / f"{how}.tofcap"
    if how == "truncated":
        frame = (len(data) - start) // 4
        path.write_bytes(bytes(data[: start + frame * 2 + frame // 2]))
    else:
        rng = np.random.default_rng(1)
        for i in rng.integers(start, len(data), 400):
            data[i] ^= 0xFF
        path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("how", ["truncated", "flipped"])
def test_damaged_captures_fail_unless_keep_going(capsys, capture, tmp_path, how):
    path = _damaged(capture, tmp_path, how)
    assert main(["track", str(path), "--headless"]) == 1
    printed = capsys.readouterr()
    skipped = next(x for x in printed.out.splitlines() if x.startswith(f"{path}: skipped"))
    assert ("bytes cut short" if how == "truncated" else "damaged frames") in skipped
    assert printed.err.strip().splitlines()[-1].startswith("tofcut: error: ")
    assert main(["track", str(path), "--headless", "--keep-going"]) == 0
    printed = capsys.readouterr()
    assert f"{path}: skipped" in printed.out
    assert "rerun: nothing recorded (--headless)" in printed.out
    assert not list(Path.cwd().glob("*.rrd"))  # --headless writes nothing


def test_headless_with_save_writes_the_file(capsys, capture, tmp_path):
    rrd = tmp_path / "kept.rrd"
    assert main(["track", str(capture), "--headless", "--save", str(rrd)]) == 0
    assert rrd.stat().st_size > 0
    assert [p.name for p in Path.cwd().glob("*.rrd")] == ["kept.rrd"]


def test_ctrl_c_on_track_prints_the_closing_lines(capsys, capture, tmp_path, monkeypatch):
    frames = []

    class InterruptedTracker(tracking.Tracker):
        def update(self, frame, belt=None):
            frames.append(frame)
            if len(frames) == 2:
                os.kill(os.getpid(), signal.SIGINT)  # the user presses Ctrl-C
            return super().update(frame, belt)

    monkeypatch.setattr(tracking, "Tracker", InterruptedTracker)
    tracks = tmp_path / "t.jsonl"
    code = main(["track", str(capture), "--headless", "--tracks-out", str(tracks)])
    assert code == 130
    out = capsys.readouterr().out
    assert "tracked 2 frames" in out
    assert "received 2 frames" in out
    assert "stopped by Ctrl-C after 2 frames" in out
    assert len(tracks.read_text().splitlines()) == 2


def test_ctrl_c_on_live_prints_the_closing_lines(tmp_path):
    """SIGINT once the status line shows (stderr on a terminal), as a user's Ctrl-C."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "tofcut.tools.cli", "live", "emulator:conveyor", "--fast",
         "--seconds", "0", "--headless"],
        stdout=subprocess.PIPE, stderr=slave, text=True,
    )  # fmt: skip
    os.close(slave)
    seen = b""
    try:
        while b" fps " not in seen:
            ready, _, _ = select.select([master], [], [], 240)
            assert ready, f"no status line: {seen!r}"
            seen += os.read(master, 4096)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    assert proc.returncode == 130
    assert "tracked " in out
    assert "received " in out
    assert "stopped by Ctrl-C after" in out


# --- 6. a fast recording is the same every time ----------------------------------------------


def test_a_fast_recording_with_a_seed_is_the_same_bit_for_bit(capsys, tmp_path):
    runs = []
    for name in ("a", "b"):
        path = tmp_path / f"{name}.tofcap"
        argv = ["record", "emulator:conveyor", "--fast", "--frames", "6", "--seed", "7"]
        assert main([*argv, "-o", str(path)]) == 0
        runs.append((path.read_bytes(), path.with_suffix(".truth.npz").read_bytes()))
    assert runs[0][0] == runs[1][0]
    assert runs[0][1] == runs[1][1]
    times = [f.host_time_ns for f in CaptureReader(tmp_path / "a.tofcap").raw_frames()]
    assert len(set(np.diff(times))) == 1  # the virtual clock: one frame period apart
