"""The conveyor options of `tofcut live`, `track`, `record` and `soak`, and the link they
open: the controller (real, or emulated on a pseudo-terminal), the belt readings, and the
reject rule. The belt's geometry is the run's, resolved once (`tools.pipeline.belt_source`).

    add_conveyor_options(parser)
    ...
    line = open_conveyor(args, opened)      # None without --conveyor / --conveyor-emulator
    with line or contextlib.nullcontext():
        for frame in camera.frames():
            prior = line.velocity_prior(frame)  # for the tracker (or pipeline.run_belt.RunBelt)
            tracked = ...
            line.observe(tracked)               # rejects
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import rerun as rr

from tofcut._closing import Closing
from tofcut.driver.belt import BeltGeometry, BeltReading
from tofcut.driver.conveyor.config import ConveyorConfig, load_conveyor_config
from tofcut.driver.conveyor.exposure_clock import ExposureClock
from tofcut.driver.conveyor.link import ConveyorClient, Listener
from tofcut.driver.conveyor.reject_rule import RejectRule
from tofcut.driver.conveyor.rejects import RejectEvent, RejectScheduler
from tofcut.driver.errors import ConfigError
from tofcut.driver.frames import Frame
from tofcut.sim.conveyor import EmulatedConveyor, for_scene
from tofcut.sim.device import EmulatedDevice
from tofcut.sim.modbus_server import PtyModbusServer
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene import Scene
from tofcut.tools.pipeline.belt_source import (
    BeltResolution,
    NoBelt,
    map_candidate,
    resolve_belt,
    resolve_run_belt,
)
from tofcut.tools.pipeline.sources import Opened
from tofcut.tracker.belt_prior import VelocityPrior, belt_velocity_prior
from tofcut.tracker.tracks import TrackedFrame

EMULATOR_SPEED_MPS = 0.25
"""The emulated belt's speed when the camera is not an emulated scene with a belt."""


def add_conveyor_options(parser: argparse.ArgumentParser, *, rejects: bool = True) -> None:
    """The conveyor's options; without `rejects`, no `--reject` nor `--diverter-distance`
    (`tofcut record` links the conveyor only to log its encoder)."""
    g = parser.add_argument_group("conveyor (Modbus RTU, or Modbus TCP via tcp://HOST:PORT)")
    g.add_argument("--conveyor", metavar="PORT", help="the controller's serial port (see 'ports')")
    g.add_argument("--conveyor-map", metavar="FILE", type=Path, help="register map and link, TOML")
    g.add_argument(
        "--conveyor-emulator",
        action="store_true",
        help="start the emulated controller on a pseudo-terminal and connect to it",
    )
    g.add_argument("--baud", type=int, metavar="N", help="baud rate (default 19200)")
    g.add_argument("--parity", choices=["N", "E", "O"], help="parity (default E; emulator N)")
    g.add_argument("--unit", type=int, metavar="ID", help="Modbus unit id (default 1)")
    g.add_argument("--poll-hz", type=float, metavar="HZ", help="encoder polls per second")
    if not rejects:
        parser.set_defaults(reject=None, diverter_distance=None)
        return
    g.add_argument(
        "--reject",
        metavar="RULE",
        help="push objects matching RULE off the belt, e.g. 'height > 0.08'",
    )
    g.add_argument(
        "--diverter-distance",
        type=float,
        metavar="M",
        help="the diverter's distance downstream of the camera's axis, along the belt (m)",
    )


def conveyor_config(args: argparse.Namespace, port: str | None) -> ConveyorConfig:
    """The map file (or the defaults) with the command line's settings on top."""
    config = load_conveyor_config(args.conveyor_map) if args.conveyor_map else ConveyorConfig()
    given = {
        "port": port,
        "baudrate": args.baud,
        "parity": args.parity,
        "unit": args.unit,
        "poll_hz": args.poll_hz,
    }
    link = replace(config.link, **{k: v for k, v in given.items() if v is not None})
    diverter_m = config.diverter_m if args.diverter_distance is None else args.diverter_distance
    return replace(config, link=link, diverter_m=diverter_m)


FIRST_READING_S = 2.0
"""How long a run waits for the conveyor link's first reading before its first frame."""


@dataclass(eq=False)
class ConveyorLine(Closing):
    """An opened conveyor: the client, the emulated controller behind it if any, rejects."""

    client: ConveyorClient
    direction: np.ndarray | None
    """The belt's travel direction in camera coordinates, when known."""
    rejects: RejectScheduler | None = None
    server: PtyModbusServer | None = None
    emulated: EmulatedConveyor | None = None
    exposures: ExposureClock = field(default_factory=ExposureClock)
    closed: bool = False

    def frame_time_ns(self, frame: Frame) -> int:
        """The host time of the frame's exposure: when to ask the belt where it was."""
        return self.exposures.host_time_ns(frame)

    def reading_at(self, time_ns: int) -> BeltReading | None:
        """The belt at a host time, as the link knows it now (`ConveyorClient.reading_at`)."""
        return self.client.reading_at(time_ns)

    def velocity_prior(self, frame: Frame) -> VelocityPrior | None:
        """The belt's velocity prior for a frame (None: the belt's direction is unknown)."""
        if self.direction is None:
            return None
        time_ns = self.frame_time_ns(frame)
        return belt_velocity_prior(self.client.reading_at(time_ns), self.direction, time_ns=time_ns)

    def observe(self, tracked: TrackedFrame) -> None:
        """Hand one tracked frame to the reject rule."""
        if self.rejects is not None:
            frame = tracked.frame
            self.rejects.observe(tracked.tracks, self.frame_time_ns(frame), frame.shape)

    def summary(self) -> str:
        s = self.client.stats
        text = (
            f"conveyor {self.client.link.port}: {s.readings}/{s.polls} polls, "
            f"{s.retries} retries ({s.timeouts} timeouts, {s.bad_frames} bad frames, "
            f"{s.exception_replies} exception replies), {s.reopens} reopens"
        )
        if self.rejects is not None:
            r = self.rejects.stats
            text += f"; rejects: {r.fired} fired, {r.passed} passed ({self.rejects.rule.text})"
        return text

    def close(self) -> None:
        """Stop the link (and the emulated controller); a second call does nothing."""
        if self.closed:
            return
        self.closed = True
        self.client.close()
        if self.server is not None:
            self.server.close()


def open_conveyor(
    args: argparse.Namespace,
    opened: Opened | None = None,
    on_reject: Callable[[RejectEvent], None] | None = None,
    *,
    resolution: BeltResolution | None = None,
    on_reading: Listener | None = None,
) -> ConveyorLine | None:
    """Open what the options ask for; None when they ask for no conveyor.

    The belt's geometry (the prior's direction, the rejects' measures) is `resolution`'s:
    by default what the map and the source's metadata say (`belt_source.resolve_run_belt`).
    `--reject` without a belt from anywhere is `NoBelt` (exit status 2), said before anything
    is opened. `on_reject` is told of every reject as the diverter is fired (on the link's
    thread; it must be quick); by default rejects go to rerun's global recording
    (`log_reject`). `on_reading` hears every reading, the first one included (the
    recorder's conveyor log).

    With `--conveyor-emulator` and an emulated scene, the controller's belt runs on the
    emulated camera's clock at the scene's speed, so its encoder counts the travel the
    camera sees.
    """
    if not args.conveyor and not args.conveyor_emulator:
        if args.reject:
            raise ConfigError("--reject needs a conveyor: --conveyor PORT or --conveyor-emulator")
        return None
    if args.conveyor and args.conveyor_emulator:
        raise ConfigError("give --conveyor PORT or --conveyor-emulator, not both")
    config = conveyor_config(args, args.conveyor)
    if resolution is None:
        resolution = (
            resolve_run_belt(args, opened)
            if opened is not None
            else resolve_belt([map_candidate(args.conveyor_map)])
        )
    geometry = None if resolution.belt is None else resolution.belt.geometry
    rule = None
    if args.reject:
        rule = RejectRule.parse(args.reject)
        if geometry is None:
            raise NoBelt(
                "--reject needs the belt's geometry, and nothing gave it: give a [belt] table "
                "in --conveyor-map (the source's metadata has none)"
            )
        if config.diverter_m is None:
            raise ConfigError("rejects need --diverter-distance M (or belt.diverter_m in the map)")
    server = emulated = None
    if args.conveyor_emulator:
        scene = _scene(opened)
        camera = opened.emulator if opened is not None else None
        if scene is not None and scene.belt is not None and camera is not None:
            emulated = for_scene(scene, lambda: camera.now_us() * 1e-6, config.registers)
        else:
            emulated = EmulatedConveyor(EMULATOR_SPEED_MPS, config.registers)
        server = PtyModbusServer(emulated, unit=config.link.unit).start()
        parity = args.parity or "N"  # a pseudo-terminal refuses parity settings
        config = replace(config, link=replace(config.link, port=server.port, parity=parity))
    client = ConveyorClient(config.link, config.registers)
    if on_reading is not None:
        client.add_listener(on_reading)
    line = ConveyorLine(
        client, None if geometry is None else geometry.direction, None, server, emulated
    )
    if opened is not None and opened.emulator is not None:  # its clock is the host's
        line.exposures = ExposureClock(offset_ns=_device_clock_offset_ns(opened.emulator))
    if rule is not None:
        assert config.diverter_m is not None
        line.rejects = _rejects(rule, geometry, config.diverter_m, client, on_reject or log_reject)
    try:
        client.open()
        # the frames get the belt's prior from the start of the stream: the run starts once
        # the link has its first reading (or after FIRST_READING_S: a link that answers
        # nothing says so in its own statistics and errors)
        client.wait_for(lambda _: True, FIRST_READING_S)
    except BaseException:
        client.close()
        if server is not None:
            server.close()
        raise
    return line


def _device_clock_offset_ns(camera: EmulatedDevice) -> int:
    """Host time minus an emulated camera's device time (both run on the host's clocks)."""
    before = time.time_ns()
    device_ns = camera.now_us() * 1000
    return (before + time.time_ns()) // 2 - device_ns


def _scene(opened: Opened | None) -> Scene | None:
    if opened is None or opened.emulator is None:
        return None
    source = opened.emulator.source
    return source.scene if isinstance(source, SceneSource) else None


def _rejects(
    rule: RejectRule,
    geometry: BeltGeometry | None,
    diverter_m: float,
    client: ConveyorClient,
    on_reject: Callable[[RejectEvent], None],
) -> RejectScheduler:
    def fire(event: RejectEvent) -> None:
        client.divert(event.track_id)
        on_reject(event)

    scheduler = RejectScheduler(rule, geometry, diverter_m, client.reading_at, fire)
    client.add_listener(scheduler.on_reading)
    return scheduler


def log_reject(event: RejectEvent, recording: rr.RecordingStream | None = None) -> None:
    """Show a reject in rerun (a text log line at the reading's host time)."""
    rr.set_time("host_time", timestamp=event.time_ns * 1e-9, recording=recording)
    rr.log("conveyor/rejects", rr.TextLog(event.describe(), level="INFO"), recording=recording)


def log_reading(reading: BeltReading, recording: rr.RecordingStream | None = None) -> None:
    """Plot the belt's speed and travel in rerun."""
    rr.set_time("host_time", timestamp=reading.time_ns * 1e-9, recording=recording)
    rr.log("conveyor/speed_mps", rr.Scalars([reading.speed_mps]), recording=recording)
    rr.log("conveyor/distance_m", rr.Scalars([reading.distance_m]), recording=recording)
