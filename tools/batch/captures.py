"""Many captures as one batch: `tofcut track A.tofcap B.tofcap ... --out DIR` (one task a
capture: `tofcut track CAPTURE` as a user runs it, in a process of its own) and `tofcut
evaluate A.tofcap B.tofcap ... --runs DIR` (one task a capture: its run scored both ways).

A capture's run is `DIR/NAME.tracks.jsonl` and `DIR/NAME.masks.npz` (NAME: the capture's
file name without `.tofcap`), the log of its tracking `DIR/NAME.log`.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tofcut.driver.errors import TofcutError
from tofcut.tools.batch.steps import cli, run_step


class NamesClash(TofcutError):
    """Two captures of one batch have the same name: their runs would overwrite each other."""

    exit_code = 2


def run_names(captures: Sequence[Path]) -> list[str]:
    """Each capture's run name (its file name without `.tofcap`); the same name twice is an
    error."""
    names = [c.name.removesuffix(".tofcap") for c in captures]
    seen: dict[str, Path] = {}
    for name, capture in zip(names, captures, strict=True):
        if name in seen:
            raise NamesClash(f"{seen[name]} and {capture} would both write {name}.*: rename one")
        seen[name] = capture
    return names


def run_files(folder: Path, name: str) -> tuple[Path, Path]:
    """A run's tracks and masks in `folder`."""
    return folder / f"{name}.tracks.jsonl", folder / f"{name}.masks.npz"


@dataclass(frozen=True)
class Tracked:
    """One capture tracked: frames, tracks and wall time, read from what it wrote."""

    capture: str
    frames: int
    tracks: int
    seconds: float

    def to_json(self) -> dict[str, Any]:
        return {"capture": self.capture, "frames": self.frames, "tracks": self.tracks,
                "seconds": round(self.seconds, 2)}  # fmt: skip


def track_capture(out: Path, extra: Sequence[str], job: tuple[Path, str]) -> Tracked:
    """A task: `tofcut track CAPTURE` (with `extra` arguments) writing into `out`."""
    capture, name = job
    tracks, masks = run_files(out, name)
    start = time.perf_counter()
    argv = cli("track", str(capture), "--tracks-out", str(tracks), "--masks-out", str(masks),
               "--save", os.devnull, *extra)  # fmt: skip
    run_step(argv, out / f"{name}.log", "track")
    ids: set[int] = set()
    frames = 0
    with tracks.open(encoding="utf-8") as f:
        for line in f:
            frames += 1
            ids.update(int(t["id"]) for t in json.loads(line)["tracks"])
    return Tracked(str(capture), frames, len(ids), time.perf_counter() - start)
