"""An emulated conveyor controller for a test: Modbus RTU on a pseudo-terminal, as a plant's
controller answers on a serial port, with the line's faults as context managers.

    with emulated_conveyor(0.25) as conveyor:              # or camera=rig: the scene's belt
        client = conveyor.connect(poll_hz=200.0)           # tofcut's own client, or yours
        with conveyor.silent(seconds=0.5):
            ...                                            # the controller stops answering
        conveyor.controller.set_speed(0.4)                 # the plant side

Any Modbus client opens `conveyor.port` (parity N: a pseudo-terminal has none); the
controller's registers follow `RegisterMap` (`docs/conveyor.md`).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from tofcut._closing import Closing
from tofcut.driver.conveyor.config import LinkSettings, RegisterMap
from tofcut.driver.conveyor.link import ConveyorClient
from tofcut.sim.conveyor import EmulatedConveyor, for_scene
from tofcut.sim.modbus_server import Fault, PtyModbusServer
from tofcut.testing.camera import CameraRig
from tofcut.testing.common import Later, RigError, check_seconds, end_all

DEFAULT_SPEED_MPS = 0.25


class ConveyorRig(Closing):
    """The emulated controller (`controller`) served on a pseudo-terminal (`server`)."""

    def __init__(self, controller: EmulatedConveyor, server: PtyModbusServer) -> None:
        self.controller = controller
        """The plant side: `set_speed`, `stop`, `start`, `set_fault`, `count`,
        `diverter_commands`, `wait_diverter`, `heartbeats`."""
        self.server = server
        """The Modbus side: `stats` (requests, replies, bad frames), `inject`, `noise`."""
        self._clients: list[ConveyorClient] = []
        self._pending: list[Later] = []
        self._closed = False

    @property
    def port(self) -> str:
        """What a client opens: the link's path when one was asked for, else the tty."""
        return self.server.port

    def link(self, **settings: Any) -> LinkSettings:
        """`LinkSettings` that reach this controller (parity N), `settings` on top."""
        return LinkSettings(**{"port": self.port, "parity": "N", "unit": self.server.unit,
                               **settings})  # fmt: skip

    def connect(self, registers: RegisterMap | None = None, **settings: Any) -> ConveyorClient:
        """tofcut's own client, polling this controller (closed with the rig); `settings`
        are `LinkSettings`' (`poll_hz`, `timeout_s`, `heartbeat_s`, ...)."""
        client = ConveyorClient(self.link(**settings), registers or self.controller.map)
        client.open()
        self._clients.append(client)
        return client

    # --- faults ---------------------------------------------------------------------------

    @contextlib.contextmanager
    def silent(self, seconds: float | None = None) -> Iterator[None]:
        """The controller stops answering at the block's start, for `seconds` or the block
        (the block ends no sooner than it answers again)."""
        check_seconds("silent", seconds)

        def answer(_: threading.Event) -> None:
            self.server.silent = False

        self.server.silent = True
        with self._until(seconds, answer):
            yield

    @contextlib.contextmanager
    def unplugged(self, seconds: float | None = None) -> Iterator[None]:
        """The port goes away (the pty closed, its link removed, as a USB adapter pulled
        out) and comes back at the same path after `seconds`, or at the block's end."""
        check_seconds("unplugged", seconds)
        self.server.vanish()
        with self._until(seconds, lambda _: self.server.reappear()):
            yield

    @contextlib.contextmanager
    def spoiled(self, kind: str = "crc", count: int = 1) -> Iterator[None]:
        """The next `count` requests are spoiled: `kind` is garbage (random bytes for the
        reply), crc (a bad CRC), exception (a "busy" reply, not executed) or lost (no
        reply, not executed). What the block's requests did not use up is dropped at its
        end."""
        kinds = [f.value for f in Fault]
        if kind not in kinds:
            raise RigError(f"spoiled: kind must be one of {', '.join(kinds)}, not {kind!r:.40}")
        self.server.inject(Fault(kind), count)
        try:
            yield
        finally:
            self.server.clear_faults()

    def noise(self, nbytes: int) -> None:
        """Put `nbytes` random bytes on the line now (between requests)."""
        self.server.noise(nbytes)

    @contextlib.contextmanager
    def _until(
        self, seconds: float | None, end: Callable[[threading.Event], None]
    ) -> Iterator[None]:
        """`end` at the block's end, or after `seconds` on a thread (sooner if the block
        fails); the block ends no sooner."""
        if seconds is None:
            try:
                yield
            finally:
                end(threading.Event())
            return
        later = Later(seconds, end)
        self._pending.append(later)
        try:
            yield
        except BaseException:
            later.cancel.set()
            raise
        finally:
            later.join()

    # --- life -----------------------------------------------------------------------------

    def close(self) -> None:
        """Close the clients it made, then the controller's port; twice is fine."""
        if self._closed:
            return
        self._closed = True
        try:
            end_all(self._pending)
            for client in self._clients:
                client.close()
        finally:
            self.server.close()


def emulated_conveyor(
    speed_mps: float | None = None,
    *,
    camera: CameraRig | None = None,
    registers: RegisterMap | None = None,
    clock: Callable[[], float] | None = None,
    start_count: int = 0,
    link: str | Path | None = None,
    unit: int = 1,
    seed: int = 0,
) -> ConveyorRig:
    """Start the emulated controller on a pseudo-terminal. Its belt runs at `speed_mps`
    (0.25 m/s by default) on `clock` (seconds; the host's monotonic clock by default: a
    test may move its own instead), or, with `camera`, is that emulated scene's belt on
    the camera's device clock, as `--conveyor-emulator` runs it (the encoder counts the
    travel the camera sees). `link` is a path for a stable symlink to the tty (as udev's
    /dev/serial/by-id); `seed` seeds the line noise it makes."""
    if camera is not None:
        if speed_mps is not None or clock is not None:
            raise RigError("a conveyor that follows a camera takes its speed and clock from it")
        scene = camera.scene_model
        if scene is None or scene.belt is None:
            raise RigError(f"the camera's scene {camera.scene!r} has no belt to follow")
        controller = for_scene(scene, lambda: camera.now_us() * 1e-6, registers)
    else:
        controller = EmulatedConveyor(
            DEFAULT_SPEED_MPS if speed_mps is None else speed_mps, registers,
            clock=clock or time.monotonic, start_count=start_count,
        )  # fmt: skip
    server = PtyModbusServer(controller, unit=unit, link=link, seed=seed).start()
    return ConveyorRig(controller, server)
