"""The suite's process-wide settings.

A suite started in the background without job control (`pytest &` in a script) has SIGINT
ignored, and the children the Ctrl-C tests start would inherit that and never stop. SIGINT
is given Python's usual handler, which a child's exec resets to the default.

With numba's cache cold (a fresh clone, or CI's bounds-checked run in a cache of its own),
every worker and every `tofcut` process a test starts would compile the tracker's kernels
itself, at once, for about 80 s of CPU each: they are compiled once, before the workers
start, by tracking a few frames of the emulated conveyor.

Where PYTHONDONTWRITEBYTECODE is set (containers often set it), every process the suite
starts (a `tofcut` command, a Ray worker, a bench stage: hundreds) would compile numpy,
scipy, numba, rerun and Ray from source again, 3 s or more each: in a fresh clone with
numba's cache cold, the suite took 11:15 on 2 cores, and 7:40 writing bytecode. It writes
it where Python does by default, beside the sources (the venv, and the clone's gitignored
`__pycache__`)."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import tofcut

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

if os.environ.pop("PYTHONDONTWRITEBYTECODE", None) is not None:  # for the workers, and below
    sys.dont_write_bytecode = False

WARM_UP = ["track", "emulator:conveyor", "--fast", "--frames", "20", "--save", os.devnull]
"""What compiles the kernels: the emulator's, demodulation's and the tracker's."""


def _cache_is_cold() -> bool:
    """Whether numba has no cached tracker kernel where this run would look for one."""
    where = os.environ.get("NUMBA_CACHE_DIR") or str(Path(tofcut.__file__).parent / "tracker")
    return not any(Path(where).rglob("cut_kernels.*.nbi"))


def pytest_sessionstart(session: pytest.Session) -> None:
    config = session.config
    workers = getattr(config.option, "numprocesses", None) or 0
    if hasattr(config, "workerinput") or workers < 2 or not _cache_is_cold():
        return
    print("\nnumba's cache is cold: compiling the kernels once before the workers start")
    done = subprocess.run(
        [sys.executable, "-m", "tofcut.tools.cli", "-q", *WARM_UP],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if done.returncode != 0:  # the tests will say what is wrong; this only saves time
        print(f"the warm-up failed (exit {done.returncode}); the workers compile instead")
