"""The emulated conveyor controller: a belt with an encoder, a status word, a diverter that
records every command, and the registers a Modbus client reads them through.

Serve it on a pseudo-terminal with `tofcut.sim.modbus_server.PtyModbusServer`. Its belt
follows a clock (by default the host's monotonic one); give it the emulated camera's
device clock and the scene's belt speed (`for_scene`) and its encoder counts exactly the
belt travel the camera sees.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tofcut.driver.belt import BeltGeometry
from tofcut.driver.conveyor.config import RegisterMap
from tofcut.sim.modbus_rtu import ExceptionCode, ModbusFault
from tofcut.sim.scene import Scene

REGISTER_SPACE = 64
"""Addresses 0..63 exist (unmapped ones read 0); beyond them: illegal address."""


@dataclass(frozen=True)
class DiverterCommand:
    """One write to the diverter register, and where the belt was when it came."""

    value: int
    count: int
    """The encoder count at that moment."""
    distance_m: float
    time_s: float
    """The controller's clock."""


class EmulatedBelt:
    """Belt travel over a clock: speed changes, stops and starts integrate exactly."""

    def __init__(
        self,
        speed_mps: float,
        clock: Callable[[], float] = time.monotonic,
        epoch: float | None = None,
    ) -> None:
        """`epoch`: the clock time at which the belt's travel was 0 (default: now)."""
        self._clock = clock
        self._t0 = clock() if epoch is None else epoch
        self._d0 = 0.0
        self._speed = speed_mps
        self._running = True

    def distance_m(self, t: float | None = None) -> float:
        """Travel since start (m) at clock time t (default: now)."""
        t = self._clock() if t is None else t
        return self._d0 + self.speed_mps * (t - self._t0)

    @property
    def speed_mps(self) -> float:
        """Actual speed: the set speed while running, else 0."""
        return self._speed if self._running else 0.0

    @property
    def running(self) -> bool:
        return self._running

    def _rebase(self) -> None:
        now = self._clock()
        self._d0 = self.distance_m(now)
        self._t0 = now

    def set_speed(self, speed_mps: float) -> None:
        self._rebase()
        self._speed = speed_mps

    def set_running(self, running: bool) -> None:
        self._rebase()
        self._running = running


class EmulatedConveyor:
    """The controller's registers over an `EmulatedBelt`; thread-safe (`RegisterDevice`)."""

    def __init__(
        self,
        speed_mps: float = 0.25,
        registers: RegisterMap | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        epoch: float | None = None,
        start_count: int = 0,
    ) -> None:
        self.map = registers or RegisterMap()
        self._clock = clock
        self._belt = EmulatedBelt(speed_mps, clock, epoch)
        self._start_count = start_count
        self._fault = False
        self._lock = threading.Condition()
        self._diverter: list[DiverterCommand] = []
        self._heartbeats: list[int] = []

    # --- the plant side: what a test or the emulated line does -----------------------------

    def set_speed(self, speed_mps: float) -> None:
        with self._lock:
            self._belt.set_speed(speed_mps)

    def stop(self) -> None:
        with self._lock:
            self._belt.set_running(False)

    def start(self) -> None:
        with self._lock:
            self._belt.set_running(True)

    def set_fault(self, fault: bool) -> None:
        with self._lock:
            self._fault = fault

    def distance_m(self) -> float:
        with self._lock:
            return self._belt.distance_m()

    def count(self) -> int:
        """The encoder count now (unsigned 32-bit)."""
        with self._lock:
            return self._count(self._belt.distance_m())

    def count_at_distance(self, distance_m: float) -> int:
        """The encoder count the belt shows after `distance_m` of travel (unwrapped)."""
        return self._start_count + round(distance_m * self.map.counts_per_m)

    def _count(self, distance_m: float) -> int:
        return self.count_at_distance(distance_m) & 0xFFFFFFFF

    @property
    def diverter_commands(self) -> list[DiverterCommand]:
        with self._lock:
            return list(self._diverter)

    @property
    def heartbeats(self) -> list[int]:
        """Every heartbeat value written, in order."""
        with self._lock:
            return list(self._heartbeats)

    def wait_diverter(self, n: int, timeout_s: float) -> list[DiverterCommand]:
        """Block until `n` diverter commands came (or the timeout); all of them."""
        with self._lock:
            self._lock.wait_for(lambda: len(self._diverter) >= n, timeout_s)
            return list(self._diverter)

    def wait_heartbeats(self, n: int, timeout_s: float) -> list[int]:
        """Block until `n` heartbeats came (or the timeout); all of them."""
        with self._lock:
            self._lock.wait_for(lambda: len(self._heartbeats) >= n, timeout_s)
            return list(self._heartbeats)

    # --- the Modbus side ------------------------------------------------------------------

    def read(self, address: int, count: int) -> list[int]:
        if address + count > REGISTER_SPACE:
            raise ModbusFault(ExceptionCode.ILLEGAL_ADDRESS)
        m = self.map
        with self._lock:  # one snapshot per request: the encoder's two words agree
            d = self._belt.distance_m()
            first, second = m.encoder_registers(self._count(d))
            live = {m.encoder: first, m.encoder + 1: second}
            live[m.speed] = m.speed_register(self._belt.speed_mps)
            live[m.status] = m.status_word(self._belt.running, self._fault)
            live[m.diverter] = self._diverter[-1].value if self._diverter else 0
            live[m.heartbeat] = self._heartbeats[-1] if self._heartbeats else 0
        return [live.get(a, 0) for a in range(address, address + count)]

    def write(self, address: int, values: list[int]) -> None:
        m = self.map
        if len(values) != 1 or address not in (m.diverter, m.heartbeat):
            raise ModbusFault(ExceptionCode.ILLEGAL_ADDRESS, "only diverter and heartbeat")
        with self._lock:
            if address == m.diverter:
                now = self._clock()
                d = self._belt.distance_m(now)
                self._diverter.append(DiverterCommand(values[0], self._count(d), d, now))
            else:
                self._heartbeats.append(values[0])
            self._lock.notify_all()


def for_scene(
    scene: Scene, device_clock_s: Callable[[], float], registers: RegisterMap | None = None
) -> EmulatedConveyor:
    """The controller of a scene's belt on the emulated camera's device clock (seconds): its
    travel is the belt's since the camera's power-on, as the renderer moves the objects."""
    if scene.belt is None:
        raise ValueError(f"scene {scene.name!r} has no belt")
    return EmulatedConveyor(scene.belt.speed_mps, registers, clock=device_clock_s, epoch=0.0)


def belt_geometry(scene: Scene) -> BeltGeometry:
    """The scene's belt in camera coordinates (world +x travel, top at z = `top_z`, centred on
    y = 0)."""
    if scene.belt is None:
        raise ValueError(f"scene {scene.name!r} has no belt")
    pose = scene.camera_from_world
    return BeltGeometry.from_plane(
        pose.rotation @ np.array([1.0, 0.0, 0.0]),
        pose.rotation @ np.array([0.0, 0.0, 1.0]),
        pose.apply(np.array([0.0, 0.0, scene.belt.top_z])),
        scene.belt.width_m,
    )
