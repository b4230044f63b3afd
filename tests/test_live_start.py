"""`tofcut live` as a user starts it: progress from the first second, a line when the machine
cannot keep up (judged from what was lost), a viewer asked for that is not there refused in
one line, and the emulator's process gone when the run ends, however it ends."""

from __future__ import annotations

import io
import logging
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from tofcut.driver.stream import StreamStats
from tofcut.tools.cli import main
from tofcut.tools.commands import startup
from tofcut.tools.pipeline.keeping_up import PaceWatch, Tally, verdict
from tofcut.tools.pipeline.rerun_target import ViewerUnreachable, viewer_reachable

WAIT_S = 120.0


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


def emulator_children(pid: int) -> list[int]:
    """The emulator processes among `pid`'s children."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            try:
                cmdline = Path(f"/proc/{child}/cmdline").read_bytes()
            except FileNotFoundError:
                continue
            if b"tofcut.sim.process" in cmdline:
                found.append(int(child))
    return found


def wait_for_exit(pid: int) -> None:
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return
    try:
        assert select.select([fd], [], [], WAIT_S)[0], f"process {pid} still runs"
    finally:
        os.close(fd)


# --- keeping up -----------------------------------------------------------------------------


def stats(frames: int, lost: int = 0, *, flagged: int = 0, estimated: int = 0) -> StreamStats:
    return StreamStats(
        frames=frames, lost=lost, lost_estimated=estimated, device_dropped_flags=flagged
    )


def test_a_run_that_lost_nothing_or_a_hiccup_keeps_up():
    start = Tally.of(0.0, stats(0), 0)
    assert verdict(start, Tally.of(5.0, stats(250), 0), 50, emulated=True) is None
    hiccup = Tally.of(5.0, stats(246, 4, flagged=2), 0)
    assert verdict(start, hiccup, 50, emulated=True) is None  # fewer than LEAST
    small = Tally.of(50.0, stats(2490, 10, flagged=5), 0)
    assert verdict(start, small, 50, emulated=True) is None  # under SHARE


def test_frames_lost_to_the_fifo_or_the_queue_say_what_to_lower():
    start = Tally.of(0.0, stats(0), 0)
    behind = Tally.of(5.0, stats(218, 32, flagged=20), 0)
    line = verdict(start, behind, 50, emulated=True)
    assert line is not None
    assert line.startswith("this machine does not keep up with 50 fps: ")
    assert "the camera's FIFO overflowed" in line
    assert "tracker" not in line
    assert "losing 32 of 250 frames (13%) in 5 s" in line
    assert "lower --fps (40 should fit)" in line  # 218 frames in 5 s: 43.6 fps delivered
    assert "a smaller scene" in line
    queue = verdict(start, Tally.of(5.0, stats(250), 20), 50, emulated=False)
    assert queue is not None
    assert "the tracker fell behind" in queue
    assert "scene" not in queue


def test_frames_lost_to_an_outage_are_not_slowness():
    """Gaps with no overflow flag (an unplug, a stall) or estimated ones are faults."""
    start = Tally.of(0.0, stats(0), 0)
    unplugged = Tally.of(5.0, stats(200, 50, estimated=20), 0)
    assert unplugged.overflowed == 0
    assert verdict(start, unplugged, 50, emulated=True) is None


def test_the_watch_says_it_once_judging_the_last_seconds():
    now = [0.0]
    st = StreamStats()
    said: list[str] = []
    watch = PaceWatch(lambda: st, lambda: 0, lambda: now[0], 50, say=said.append)
    for i in range(1, 600):  # 12 s at 50 fps; from 6 s on, 1 frame in 5 lost to the FIFO
        now[0] = i * 0.02
        st.frames += 1
        if now[0] > 6 and i % 4 == 0:
            st.lost += 1
            st.device_dropped_flags += 1
        watch.write(None, None)  # type: ignore[arg-type]
    watch.close()
    assert len(said) == 1
    assert watch.said == said[0]
    assert "FIFO overflowed" in said[0]


def test_a_run_shorter_than_the_window_is_judged_at_its_end():
    now = [0.0]
    st = StreamStats()
    said: list[str] = []
    watch = PaceWatch(lambda: st, lambda: 0, lambda: now[0], 50, say=said.append)
    watch.write(None, None)  # type: ignore[arg-type]
    now[0], st.frames, st.lost, st.device_dropped_flags = 2.0, 80, 20, 10
    watch.close()
    assert len(said) == 1
    assert "losing 20 of 100 frames" in said[0]


# --- progress from the first second ----------------------------------------------------------


class Terminal(io.StringIO):
    """A stream that says it is a terminal, and tells when it was written to."""

    def __init__(self) -> None:
        super().__init__()
        self.written = threading.Event()

    def isatty(self) -> bool:
        return True

    def write(self, text: str) -> int:
        n = super().write(text)
        self.written.set()
        return n


def test_on_a_terminal_each_step_shows_on_one_line_and_is_cleared():
    term = Terminal()
    shown = startup.Startup(term)
    shown.step("compiling the tracker")
    assert term.written.wait(WAIT_S)
    shown.done()
    text = term.getvalue()
    assert text.startswith("\rtofcut: compiling the tracker ... 0 s")
    assert text.endswith("\r" + " " * startup.WIDTH + "\r")  # the command's lines follow
    assert "\n" not in text


def test_off_a_terminal_a_long_step_is_a_progress_note(monkeypatch, caplog):
    monkeypatch.setattr(startup, "SAY_AFTER_S", 0.0)
    logged = threading.Event()

    class Tell(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            logged.set()

    tell = Tell()
    logging.getLogger("tofcut.startup").addHandler(tell)
    stream = io.StringIO()
    try:
        with caplog.at_level(logging.INFO, logger="tofcut.startup"):
            shown = startup.Startup(stream)
            shown.step("loading the tracker")
            assert logged.wait(WAIT_S)
            shown.done()
    finally:
        logging.getLogger("tofcut.startup").removeHandler(tell)
    assert [r.getMessage() for r in caplog.records] == ["loading the tracker ..."]
    assert stream.getvalue() == ""  # stderr stays as scripts read it


def test_quiet_and_quick_commands_show_nothing():
    term = Terminal()
    quiet = startup.begin("live", quiet=True, stream=term)
    for shown in (quiet, startup.begin("ports", stream=term)):
        shown.step("anything")
        shown.done()
    assert term.getvalue() == ""


def test_a_real_time_run_shows_its_steps_then_the_status_line_and_cleans_up(tmp_path):
    """The command as a user runs it at a terminal (stderr a pseudo-terminal): progress
    steps from the start, the live status, then Ctrl-C: the closing lines, exit 130, and
    the emulator's process gone."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "tofcut.tools.cli", "live", "emulator:test-pattern",
         "--seconds", "0", "--headless"],
        stdout=subprocess.PIPE, stderr=slave, text=True, cwd=tmp_path,
    )  # fmt: skip
    os.close(slave)
    seen = b""
    try:
        while b" fps " not in seen:
            ready, _, _ = select.select([master], [], [], WAIT_S)
            assert ready, f"no status line: {seen!r}"
            seen += os.read(master, 4096)
        (emulator,) = emulator_children(proc.pid)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    wait_for_exit(emulator)
    assert proc.returncode == 130
    assert b"tofcut: loading tofcut live ... " in seen
    assert b"tofcut: starting the emulated camera ... " in seen
    assert b"tofcut: loading the tracker ... " in seen
    assert "stopped by Ctrl-C after" in out


def test_a_real_time_run_to_its_end_leaves_no_emulator_behind(capsys):
    assert main(["live", "emulator:test-pattern", "--seconds", "1", "--headless"]) == 0
    assert emulator_children(os.getpid()) == []
    out = capsys.readouterr().out
    assert "tracked " in out
    assert "received " in out


# --- a viewer that is not there -------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_connect_with_no_viewer_is_one_error_before_the_run(capsys):
    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"
    assert main(["live", "emulator:test-pattern", "--fast", "--frames", "5", "--url", url]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert lines == [
        f"tofcut: error: no rerun viewer at {url} (Connection refused): start one with "
        "'rerun', or leave out --connect"
    ]
    assert "frames sent" not in captured.out
    assert "tracked" not in captured.out


def test_a_viewer_that_listens_is_reachable():
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        viewer_reachable(f"rerun+http://127.0.0.1:{listener.getsockname()[1]}/proxy")
    with pytest.raises(ViewerUnreachable, match="names no host"):
        viewer_reachable("rerun+http:///proxy")
