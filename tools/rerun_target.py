"""Where rerun output goes: rerun's customary script options, with a file as the default.

`add_rerun_options` adds rerun's own `--headless --connect --serve --url --save --stdout`
(`rr.script_add_args`) plus `--spawn`. Rerun's example scripts spawn a viewer when no option is
given; tofcut saves a `.rrd` file in the working directory instead, so the main command works on
a machine with no screen. `--headless` alone records nothing (as in rerun's own scripts, where
it means no viewer and no sink); `--headless --save FILE` writes FILE. `--url` alone implies
`--connect`.
"""

from __future__ import annotations

import argparse
import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, cast

import rerun as rr
import rerun.blueprint as rrb

TargetKind = Literal["save", "spawn", "connect", "serve", "stdout", "none"]


@dataclass(frozen=True)
class RerunTarget:
    """One destination for a recording: a file, or a viewer (spawned, running, served, piped)."""

    kind: TargetKind
    path: Path | None = None
    """The .rrd file, for `save`."""
    url: str | None = None
    """The viewer's gRPC URL, for `connect` (None: rerun's default)."""

    def __post_init__(self) -> None:
        if (self.kind == "save") != (self.path is not None):
            raise ValueError("a rerun target saves exactly when it has a path")

    @classmethod
    def save(cls, path: str | Path) -> RerunTarget:
        return cls("save", path=Path(path))

    @property
    def lossless(self) -> bool:
        """A file must hold every frame; a live viewer had better drop frames than lag."""
        return self.kind == "save"

    def describe(self) -> str:
        if self.kind == "none":
            return "no recording (--headless; add --save FILE.rrd to keep one)"
        if self.kind == "save":
            return f"saving the recording to {self.path} (view it with: rerun {self.path})"
        if self.kind == "connect":
            return f"streaming to the rerun viewer at {self.url or 'the default address'}"
        if self.kind == "serve":
            return "serving the recording over gRPC, with a web viewer"
        if self.kind == "stdout":
            return "writing the recording to standard output (pipe it into: rerun -)"
        return "streaming to a newly spawned rerun viewer"

    def attach(self, rec: rr.RecordingStream, blueprint: rrb.Blueprint) -> None:
        """Point `rec` at this target, with `blueprint` as the default layout (as rerun does).

        Files and stdout get no footer: rerun keeps the footer's manifest (metadata on every
        chunk written) in memory until the end, 12 KiB a frame in `tools.rerun_memory`'s run,
        so a run of weeks would grow without bound. The stream is complete without it;
        `rerun rrd optimize RUN.rrd -o OUT.rrd` writes a copy with one.
        """
        if self.kind == "none":
            return  # rerun's `--headless`: no sink (a sink that records nothing is `NullSink`)
        if self.kind == "save":
            assert self.path is not None
            rec.save(self.path, default_blueprint=blueprint, write_footer=False)
        elif self.kind == "spawn":
            rec.spawn(default_blueprint=blueprint)
        elif self.kind == "connect":
            rec.connect_grpc(self.url, default_blueprint=blueprint)
        elif self.kind == "serve":
            server = rec.serve_grpc(default_blueprint=blueprint)
            rr.serve_web_viewer(open_browser=True, connect_to=server)
        else:
            rec.stdout(default_blueprint=blueprint, write_footer=False)


def add_rerun_options(parser: argparse.ArgumentParser) -> None:
    """Rerun's customary options (`rr.script_add_args`) and `--spawn`, in their own group."""
    group = parser.add_argument_group(
        "rerun output (default: save tofcut-DATE-TIME.rrd in the working directory; "
        "--headless: no recording unless --save)"
    )
    # script_add_args only calls add_argument, which an argument group has too.
    rr.script_add_args(cast(argparse.ArgumentParser, group))
    group.add_argument("--spawn", action="store_true", help="Spawn a Rerun Viewer and stream to it")


def default_recording_path(now: dt.datetime | None = None, directory: Path | None = None) -> Path:
    """`tofcut-YYYYmmdd-HHMMSS.rrd` in `directory` (the working one), never an existing file."""
    stamp = (now or dt.datetime.now()).strftime("%Y%m%d-%H%M%S")
    folder = directory or Path.cwd()
    path = folder / f"tofcut-{stamp}.rrd"
    n = 2
    while path.exists():
        path = folder / f"tofcut-{stamp}-{n}.rrd"
        n += 1
    return path


def target_from_args(args: argparse.Namespace, now: dt.datetime | None = None) -> RerunTarget:
    """The target the options ask for, in rerun's order of precedence; a new file if none."""
    if args.stdout:
        return RerunTarget("stdout")
    if args.serve:
        return RerunTarget("serve")
    if args.connect or args.url is not None:
        return RerunTarget("connect", url=args.url)
    if args.save is not None:
        return RerunTarget.save(args.save)
    if args.spawn:
        return RerunTarget("spawn")
    if args.headless:
        return RerunTarget("none")
    return RerunTarget.save(default_recording_path(now))


def wait_while_serving(args: argparse.Namespace) -> None:
    """After the run, keep a served recording up until Ctrl-C (rerun's `script_teardown`).

    Call it after `RerunSink.close()`, while the sink is still referenced: it holds the server.
    """
    rr.script_teardown(args)
