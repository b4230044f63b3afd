"""The project's own hygiene: lint, types and packaging, checked with the test suite."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*cmd: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, check=False)


def test_ruff_finds_nothing():
    result = _run(sys.executable, "-m", "ruff", "check", ".")
    assert result.returncode == 0, result.stdout + result.stderr
    result = _run(sys.executable, "-m", "ruff", "format", "--check", ".")
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_finds_nothing(tmp_path):
    # The repository root is the package `tofcut`; mypy needs a folder of that name.
    (tmp_path / "tofcut").symlink_to(ROOT, target_is_directory=True)
    result = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
         "--cache-dir", str(tmp_path / "cache"), "-p", "tofcut"],
        cwd=tmp_path, env={"MYPYPATH": str(tmp_path), "PATH": ""},
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_wheel_installs_only_the_tofcut_package(tmp_path):
    uv = os.environ.get("UV") or shutil.which("uv")  # `uv run` says where it is in $UV
    assert uv, "run the tests through uv (scripts/uv run pytest)"
    # The build runs in this environment (its setuptools), whichever interpreter uv itself
    # was installed under (pip puts it under the system Python, whose setuptools is older).
    result = _run(
        uv, "build", "--wheel", "--no-build-isolation", "--python", sys.executable,
        "-o", str(tmp_path),
    )  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    (wheel,) = tmp_path.glob("tofcut-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.startswith("tofcut-")}
    assert top == {"tofcut"}
    for sub in ("driver", "sim", "tracker", "tools"):
        assert f"tofcut/{sub}/__init__.py" in names
    assert "tofcut/py.typed" in names
    assert "tofcut/testing/plugin.py" in names  # and pytest finds it by its entry point:
    (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    text = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert "[pytest11]\ntofcut = tofcut.testing.plugin" in text
    assert "tofcut/sim/scenes/conveyor.toml" in names
    assert not any(n.startswith("tofcut/tests/") for n in names)
