"""Where rerun output goes: rerun's customary script options, with a file as the default.

`add_rerun_options` adds rerun's own `--headless --connect --serve --url --save --stdout`
(`rr.script_add_args`) plus `--spawn` and `--bind`. Rerun's example scripts spawn a viewer when
no option is given; tofcut saves a `.rrd` file in the working directory instead, so the main
command works on a machine with no screen. `--headless` alone records nothing (as in rerun's
own scripts, where it means no viewer and no sink); `--headless --save FILE` writes FILE.
`--url` alone implies `--connect`.

A saved recording is written in segments: when the file reaches `--segment-mb` (default 256 MB,
about half a minute of the conveyor at 50 fps) or `--segment-minutes` (default 10), it is closed
with rerun's footer and the recording goes on in a new file of the same recording. A run that
stays within both bounds writes the one file it was given (RUN.rrd); a longer one writes
RUN-0001.rrd, RUN-0002.rrd, ... instead (the first file is renamed when the second starts).
`rerun RUN-*.rrd` shows them as one recording. Each closed file passes `rerun rrd verify`, and
the memory rerun keeps for a footer (metadata on every chunk in the file) is bounded by the
segment's size, however long the run.

`--serve` serves the whole recording (depth, images, point clouds, tracks; the newest 1 GiB)
over gRPC, without authentication, from the start of the run until Ctrl-C after it. It listens
on the loopback address only (rerun's default is every interface); `--bind ADDRESS` opens it to
that address's network, with a warning, and only then starts rerun's web viewer too (rerun
0.41 can bind that server to every interface only).
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import socket
import sys
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, cast

import rerun as rr
import rerun.blueprint as rrb
import rerun_bindings as bindings

from tofcut.driver.errors import TofcutError

TargetKind = Literal["save", "spawn", "connect", "serve", "stdout", "none"]
LOOPBACK = "127.0.0.1"
"""Where `--serve` listens unless `--bind` says otherwise: this machine only."""
GRPC_PORT = 9876
"""Rerun's gRPC port (`rerun+http://HOST:9876/proxy`)."""
WEB_VIEWER_PORT = 9090
DEFAULT_VIEWER_URL = f"rerun+http://{LOOPBACK}:{GRPC_PORT}/proxy"
"""Where `--connect` streams without `--url` (rerun's default)."""
CONNECT_TIMEOUT_S = 2.0
MB = 1_000_000
SEGMENT_MB = 256.0
"""Default size at which a saved recording goes on in a new file (0: no bound)."""
SEGMENT_MINUTES = 10.0
"""Default duration after which a saved recording goes on in a new file (0: no bound)."""


class BlueprintSource:
    """A default blueprint for each file of a recording, from one blueprint stream.

    Rerun's `save(default_blueprint=...)` makes a new blueprint stream for each call, which
    rerun-sdk 0.41 never frees (about 1 MB each for tofcut's layout): a recording in many
    segments would grow by that much a file. This logs the blueprint again into a fresh
    in-memory sink of the same stream for each file instead.
    """

    def __init__(self, rec: rr.RecordingStream, blueprint: rrb.BlueprintLike) -> None:
        self.blueprint = blueprint.to_blueprint()
        app_id = rr.get_application_id(recording=rec)
        if app_id is None:
            raise ValueError("a recording without an application id")
        native = bindings.new_blueprint(
            application_id=app_id,
            make_default=False,
            make_thread_default=False,
            default_enabled=True,
        )
        self._stream = rr.RecordingStream._from_native(native)

    def storage(self) -> bindings.PyMemorySinkStorage:
        """The blueprint's messages, for one file's sink (which takes them)."""
        memory = self._stream.memory_recording()
        self._stream.set_time("blueprint", sequence=0)
        self.blueprint._log_to_stream(self._stream)
        return memory.storage


@dataclass(frozen=True)
class RerunTarget:
    """One destination for a recording: a file, or a viewer (spawned, running, served, piped)."""

    kind: TargetKind
    path: Path | None = None
    """The .rrd file, for `save`."""
    url: str | None = None
    """The viewer's gRPC URL, for `connect` (None: rerun's default)."""
    bind: str = LOOPBACK
    """The address `serve` listens on."""
    port: int = GRPC_PORT
    """The port `serve` listens on (0: any free one)."""
    segment_bytes: int = round(SEGMENT_MB * MB)
    """For `save`: the size at which the recording goes on in a new file (0: never)."""
    segment_s: float = SEGMENT_MINUTES * 60.0
    """For `save`: the time after which the recording goes on in a new file (0: never)."""

    def __post_init__(self) -> None:
        if (self.kind == "save") != (self.path is not None):
            raise ValueError("a rerun target saves exactly when it has a path")
        if self.segment_bytes < 0 or self.segment_s < 0:
            raise ValueError("a segment bound cannot be negative")

    @classmethod
    def save(
        cls,
        path: str | Path,
        segment_bytes: int = round(SEGMENT_MB * MB),
        segment_s: float = SEGMENT_MINUTES * 60.0,
    ) -> RerunTarget:
        return cls("save", path=Path(path), segment_bytes=segment_bytes, segment_s=segment_s)

    def segment_path(self, number: int) -> Path:
        """Segment `number` (from 1) of a saved recording: RUN.rrd's 3rd is RUN-0003.rrd."""
        assert self.path is not None
        return self.path.with_name(f"{self.path.stem}-{number:04d}{self.path.suffix}")

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
            url = self.serve_url
            text = (
                f"serving the recording over gRPC at {url} until Ctrl-C after the run, "
                "without authentication, "
            )
            if self.loopback:
                web = "https://app.rerun.io/version/{}/?url={}".format(
                    rr.__version__, urllib.parse.quote(url, safe="")
                )
                return text + f"to this machine only; view it with: rerun {url} (or {web})"
            return text + f"with rerun's web viewer on port {WEB_VIEWER_PORT}"
        if self.kind == "stdout":
            return "writing the recording to standard output (pipe it into: rerun -)"
        return "streaming to a newly spawned rerun viewer"

    @property
    def loopback(self) -> bool:
        return ipaddress.ip_address(self.bind).is_loopback

    @property
    def serve_url(self) -> str:
        host = f"[{self.bind}]" if ":" in self.bind else self.bind
        return f"rerun+http://{host}:{self.port}/proxy"

    def attach(self, rec: rr.RecordingStream, blueprint: rrb.Blueprint | BlueprintSource) -> None:
        """Point `rec` at this target, with `blueprint` as the default layout (as rerun does).

        Files and stdout get rerun's footer, written when the file sink is closed (when
        `start_segment` replaces it, or at `rec.disconnect()`). Rerun keeps the footer's
        manifest (metadata on every chunk written) in memory until then: a file is bounded by
        its segment (`RerunSink` starts the next one); a stream on stdout is not (it is meant
        for a viewer, which keeps far more).
        """
        if self.kind == "none":
            return  # rerun's `--headless`: no sink (a sink that records nothing is `NullSink`)
        if self.kind == "save":
            assert self.path is not None
            if not isinstance(blueprint, BlueprintSource):
                blueprint = BlueprintSource(rec, blueprint)
            self.start_segment(rec, self.path, blueprint)
            return
        if isinstance(blueprint, BlueprintSource):
            blueprint = blueprint.blueprint
        if self.kind == "spawn":
            rec.spawn(default_blueprint=blueprint)
        elif self.kind == "connect":
            viewer_reachable(self.url or DEFAULT_VIEWER_URL)
            rec.connect_grpc(self.url, default_blueprint=blueprint)
        elif self.kind == "serve":
            sink = rr.GrpcServerSink(bind_ip=self.bind, port=self.port)
            rec.set_sinks(sink, default_blueprint=blueprint)
            if not self.loopback:
                print(
                    f"warning: --bind {self.bind}: the recording is served to that network at "
                    f"{self.serve_url} without authentication, and rerun's web viewer listens "
                    f"on every interface (port {WEB_VIEWER_PORT}), until Ctrl-C after the run",
                    file=sys.stderr,
                    flush=True,
                )
                rr.serve_web_viewer(
                    web_port=WEB_VIEWER_PORT, open_browser=True, connect_to=sink.uri
                )
        else:
            rec.stdout(default_blueprint=blueprint, write_footer=True)

    def start_segment(
        self, rec: rr.RecordingStream, path: Path, blueprint: BlueprintSource
    ) -> None:
        """Send what `rec` logs from now on to the file `path`, with `blueprint` as its default
        layout. The file sink it replaces, if any, is flushed and closed first, footer and all
        (rerun swaps sinks synchronously); the new file starts with the recording's store info
        and blueprint, nothing else: what was logged as static must be logged again.
        (`rr.save` less its new blueprint stream per call, see `BlueprintSource`.)"""
        bindings.save(
            path=str(path),
            default_blueprint=blueprint.storage(),
            recording=rec.to_native(),
            write_footer=True,
        )


def add_rerun_options(parser: argparse.ArgumentParser) -> None:
    """Rerun's customary options (`rr.script_add_args`) and `--spawn`, in their own group."""
    group = parser.add_argument_group(
        "rerun output (default: save tofcut-DATE-TIME.rrd in the working directory; "
        "--headless: no recording unless --save). A saved recording longer than "
        "--segment-mb or --segment-minutes is written as RUN-0001.rrd, RUN-0002.rrd, ... "
        "(each file complete, with rerun's footer; view them together with: rerun RUN-*.rrd)"
    )
    # script_add_args only calls add_argument, which an argument group has too.
    rr.script_add_args(cast(argparse.ArgumentParser, group))
    for action in group._group_actions:
        if action.dest == "serve":
            action.help = (
                f"Serve the whole recording (images, point clouds, tracks; the newest 1 GiB) "
                f"over gRPC on port {GRPC_PORT}, without authentication, from the start of the "
                f"run until Ctrl-C after it; to this machine only ({LOOPBACK}) unless --bind"
            )
    group.add_argument("--spawn", action="store_true", help="Spawn a Rerun Viewer and stream to it")
    group.add_argument(
        "--bind",
        metavar="ADDRESS",
        type=_ip_address,
        default=None,
        help=(
            f"with --serve: listen on this IP address instead of {LOOPBACK}, e.g. 0.0.0.0 for "
            "every interface: anyone on that network can then read the recording; also starts "
            f"rerun's web viewer (port {WEB_VIEWER_PORT}, every interface). Prints a warning"
        ),
    )

    group.add_argument(
        "--segment-mb",
        metavar="MB",
        type=_bound,
        default=SEGMENT_MB,
        help=(
            f"close a saved recording's file at this size and go on in a new one (default "
            f"{SEGMENT_MB:g} MB, about 30 s at 50 fps; 0: no bound). Bounds the memory rerun "
            "keeps for the file's footer"
        ),
    )
    group.add_argument(
        "--segment-minutes",
        metavar="MIN",
        type=_bound,
        default=SEGMENT_MINUTES,
        help=(
            "close a saved recording's file after this many minutes and go on in a new one "
            f"(default {SEGMENT_MINUTES:g}; 0: no bound)"
        ),
    )


def _bound(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text[:40]!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be 0 (no bound) or more: {text[:40]!r}")
    return value


def _ip_address(text: str) -> str:
    try:
        return str(ipaddress.ip_address(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an IP address: {text!r}") from None


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
        bind = getattr(args, "bind", None)
        return RerunTarget("serve", bind=bind or LOOPBACK)
    if args.connect or args.url is not None:
        return RerunTarget("connect", url=args.url)
    segment_bytes = round(getattr(args, "segment_mb", SEGMENT_MB) * MB)
    segment_s = getattr(args, "segment_minutes", SEGMENT_MINUTES) * 60.0
    if args.save is not None:
        return RerunTarget.save(args.save, segment_bytes, segment_s)
    if args.spawn:
        return RerunTarget("spawn")
    if args.headless:
        return RerunTarget("none")
    return RerunTarget.save(default_recording_path(now), segment_bytes, segment_s)


class ViewerUnreachable(TofcutError):
    """`--connect`: no rerun viewer listens where the recording was to go."""


def viewer_reachable(url: str) -> None:
    """Raise `ViewerUnreachable` unless something accepts a connection at `url`'s address
    (rerun itself would log an error and drop every frame, and the run would seem fine)."""
    parts = urllib.parse.urlsplit(url)
    try:
        host, port = parts.hostname, parts.port or GRPC_PORT
    except ValueError:
        raise ViewerUnreachable(f"--url {url!r} is not a rerun viewer's address") from None
    if host is None:
        raise ViewerUnreachable(f"--url {url!r} names no host")
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise ViewerUnreachable(
            f"no rerun viewer at {url} ({exc.strerror or exc}): start one with 'rerun', "
            "or leave out --connect"
        ) from None


def check_viewer(args: argparse.Namespace) -> None:
    """With `--connect` or `--url` (and no output that takes precedence), fail now, in one
    line, unless a viewer is there: before a run that would stream to nothing."""
    if getattr(args, "stdout", False) or getattr(args, "serve", False):
        return
    if getattr(args, "connect", False) or getattr(args, "url", None) is not None:
        viewer_reachable(args.url or DEFAULT_VIEWER_URL)


def wait_while_serving(args: argparse.Namespace) -> None:
    """After the run, keep a served recording up until Ctrl-C (rerun's `script_teardown`).

    Call it after `RerunSink.close()`, while the sink is still referenced: it holds the server.
    """
    rr.script_teardown(args)
