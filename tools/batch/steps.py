"""A batch's step in a process of its own (`tofcut record`, `tofcut track`, ...), and an
error said in one line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tofcut.driver.errors import TofcutError


class StepFailed(Exception):
    """A step went wrong: the message says which step and why, in one line."""


def cli(*args: str) -> list[str]:
    """The argv of `tofcut ARGS...` with this Python (as a user would run it)."""
    return [sys.executable, "-m", "tofcut.tools.cli", *args]


def run_step(argv: list[str], log: Path, what: str) -> None:
    """Run a step in its own process, its output to `log`; a failure says why in one line."""
    with log.open("w", encoding="utf-8") as out:
        code = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                              check=False).returncode  # fmt: skip
    if code != 0:
        lines = [x.strip() for x in log.read_text(encoding="utf-8", errors="replace").splitlines()]
        last = next((x for x in reversed(lines) if x), "no output")
        raise StepFailed(f"{what} exited with {code}: {last} (log: {log})")


def describe(exc: BaseException) -> str:
    """An error as one line: our own errors by their message, others with their type."""
    if isinstance(exc, StepFailed | TofcutError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}".splitlines()[0]
