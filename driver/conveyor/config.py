"""The conveyor controller as configuration: its register map, how to reach it, where its
belt and diverter are. Defaults, and the TOML file that overrides them::

    [link]                       # how to reach the controller
    port = "/dev/ttyUSB0"        # a serial port, or "tcp://HOST:PORT" for a Modbus TCP gateway
    baudrate = 19200
    parity = "E"                 # N, E or O (Modbus RTU's default is 8E1)
    bytesize = 8
    stopbits = 1
    unit = 1                     # the controller's Modbus unit (slave) id, 1..247
    timeout_s = 0.1              # per request, 0.001..10 s
    retries = 2                  # extra attempts after a timeout, bad frame or exception reply
    poll_hz = 50                 # encoder polls per second, 0.1..1000
    heartbeat_s = 1.0            # heartbeat write interval, 0.01..3600 s (0: none)
    reopen_s = 0.5               # wait between attempts to reopen a lost port, 0.01..60 s

    [registers]                  # holding registers, 0-based protocol addresses
    encoder = 0                  # 32-bit unsigned count in two registers: encoder, encoder + 1
    encoder_words = "high-first" # or "low-first"
    speed = 2                    # signed 16-bit, in speed_unit_mps (mm/s by default)
    status = 3                   # bit running_bit: belt running; bit fault_bit: fault
    diverter = 10                # the client writes diverter_value here to push an object off
    heartbeat = 11               # the client writes a counter here every heartbeat_s
    counts_per_m = 10000.0
    speed_unit_mps = 0.001
    running_bit = 0
    fault_bit = 1
    diverter_value = 1

    [belt]                       # where the belt is, in camera coordinates (x right, y down,
    direction = [1.0, 0.0, 0.0]  #   z forward), metres; the emulator knows its own
    normal = [0.0, -0.8, -0.6]   # up, away from the belt
    point = [0.0, 0.4, 1.2]      # a point of the belt's top surface (on its centre line if
    width_m = 0.6                #   the width is given; the width is optional)
    diverter_m = 1.5             # the diverter, downstream of the camera's optical axis
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from tofcut.driver.belt import BeltGeometry
from tofcut.driver.config_file import as_float, load_toml, unknown_keys
from tofcut.driver.config_file import show as _show
from tofcut.driver.errors import ConfigError

MAX_READ_REGISTERS = 125
"""The most registers one Modbus read (function 3) may ask for."""
READ_GAP = 8
"""Registers this close together are read in one request (the gap is read and ignored)."""
TCP_PREFIX = "tcp://"
MAX_FILE_BYTES = 1 << 20
"""A conveyor file larger than this is refused unread (real ones are a few hundred bytes)."""
LINK_RANGES: dict[str, tuple[float, float]] = {
    "timeout_s": (0.001, 10.0),
    "poll_hz": (0.1, 1000.0),
    "heartbeat_s": (0.01, 3600.0),
    "reopen_s": (0.01, 60.0),
}
"""The ranges of the link's timings (`heartbeat_s` may also be 0: no heartbeat). A request
shorter than a millisecond cannot reach a controller; one longer than 10 s would hold up the
end of a run (`ConveyorClient.close` abandons a request after its deadline); past 1000 polls a
second a serial line cannot keep up, and the history of readings grows with the rate; a
heartbeat faster than 100 a second would crowd out the polls."""


@dataclass(frozen=True)
class RegisterMap:
    """Where the controller keeps what the client reads and writes, and their units."""

    encoder: int = 0
    encoder_words: str = "high-first"
    speed: int = 2
    status: int = 3
    diverter: int = 10
    heartbeat: int = 11
    counts_per_m: float = 10000.0
    speed_unit_mps: float = 0.001
    running_bit: int = 0
    fault_bit: int = 1
    diverter_value: int = 1

    def __post_init__(self) -> None:
        for name in ("encoder", "speed", "status", "diverter", "heartbeat"):
            _check_int(name, getattr(self, name), 0, 0xFFFF)
        if self.encoder == 0xFFFF:
            raise ConfigError("registers.encoder needs two registers: it must be below 65535")
        used = [self.encoder, self.encoder + 1, self.speed, self.status]
        used += [self.diverter, self.heartbeat]
        if len(set(used)) != len(used):
            raise ConfigError(f"registers overlap: {self.addresses()}")
        if self.encoder_words not in ("high-first", "low-first"):
            raise ConfigError("registers.encoder_words must be 'high-first' or 'low-first'")
        if not (math.isfinite(self.counts_per_m) and self.counts_per_m > 0):
            raise ConfigError("registers.counts_per_m must be a positive number")
        if not (math.isfinite(self.speed_unit_mps) and self.speed_unit_mps > 0):
            raise ConfigError("registers.speed_unit_mps must be a positive number")
        _check_int("running_bit", self.running_bit, 0, 15)
        _check_int("fault_bit", self.fault_bit, 0, 15)
        if self.running_bit == self.fault_bit:
            raise ConfigError("registers.running_bit and fault_bit must differ")
        _check_int("diverter_value", self.diverter_value, 0, 0xFFFF)

    def addresses(self) -> dict[str, int]:
        """Name → address of every register, for messages and documentation."""
        return {
            "encoder": self.encoder,
            "speed": self.speed,
            "status": self.status,
            "diverter": self.diverter,
            "heartbeat": self.heartbeat,
        }

    def read_plan(self) -> list[tuple[int, int]]:
        """(start, count) of the reads that fetch encoder, speed and status in one poll.

        The encoder's two registers are always in the same request, so its 32 bits are one
        snapshot; registers at most `READ_GAP` apart share a request.
        """
        spans = sorted([(self.encoder, 2), (self.speed, 1), (self.status, 1)])
        plan: list[tuple[int, int]] = []
        for start, count in spans:
            if plan:
                s0, c0 = plan[-1]
                end = max(s0 + c0, start + count)
                if start - (s0 + c0) <= READ_GAP and end - s0 <= MAX_READ_REGISTERS:
                    plan[-1] = (s0, end - s0)
                    continue
            plan.append((start, count))
        return plan

    def encoder_registers(self, count: int) -> tuple[int, int]:
        """The two register values that hold an encoder count, in address order."""
        hi, lo = (count >> 16) & 0xFFFF, count & 0xFFFF
        return (hi, lo) if self.encoder_words == "high-first" else (lo, hi)

    def encoder_count(self, first: int, second: int) -> int:
        """The encoder count from its two registers, in address order."""
        hi, lo = (first, second) if self.encoder_words == "high-first" else (second, first)
        return (hi << 16) | lo

    def speed_register(self, speed_mps: float) -> int:
        """The speed register's 16-bit value for a speed (saturating, two's complement)."""
        units = max(-0x8000, min(0x7FFF, round(speed_mps / self.speed_unit_mps)))
        return units & 0xFFFF

    def speed_mps(self, register: int) -> float:
        """The speed a 16-bit speed register value means."""
        signed = register - 0x10000 if register & 0x8000 else register
        return signed * self.speed_unit_mps

    def status_word(self, running: bool, fault: bool) -> int:
        return (int(running) << self.running_bit) | (int(fault) << self.fault_bit)


@dataclass(frozen=True)
class LinkSettings:
    """How to reach the controller: a serial port (Modbus RTU) or a TCP gateway."""

    port: str = ""
    baudrate: int = 19200
    parity: str = "E"
    bytesize: int = 8
    stopbits: int = 1
    unit: int = 1
    timeout_s: float = 0.1
    retries: int = 2
    poll_hz: float = 50.0
    heartbeat_s: float = 1.0
    reopen_s: float = 0.5

    def __post_init__(self) -> None:
        if self.baudrate <= 0:
            raise ConfigError(f"link.baudrate must be positive, not {self.baudrate}")
        if self.parity not in ("N", "E", "O"):
            raise ConfigError(f"link.parity must be N, E or O, not {_show(self.parity)}")
        if self.bytesize not in (7, 8):
            raise ConfigError(f"link.bytesize must be 7 or 8, not {self.bytesize}")
        if self.stopbits not in (1, 2):
            raise ConfigError(f"link.stopbits must be 1 or 2, not {self.stopbits}")
        _check_int("unit", self.unit, 1, 247)
        _check_int("retries", self.retries, 0, 10)
        for name, (lo, hi) in LINK_RANGES.items():
            value = getattr(self, name)
            if name == "heartbeat_s" and value == 0:
                continue
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not lo <= value <= hi
            ):
                none = " (or 0: none)" if name == "heartbeat_s" else ""
                raise ConfigError(
                    f"link.{name} must be in {lo:g}..{hi:g}{none}, not {_show(value)}"
                )
        if self.is_tcp:
            self.tcp_address()  # checks the form

    @property
    def is_tcp(self) -> bool:
        return self.port.startswith(TCP_PREFIX)

    def tcp_address(self) -> tuple[str, int]:
        """(host, port) of a `tcp://HOST:PORT` link; the port defaults to Modbus's 502."""
        rest = self.port[len(TCP_PREFIX) :]
        host, _, port = rest.rpartition(":") if ":" in rest else (rest, "", "502")
        if not port.isdigit() or not 0 < int(port) < 65536 or not host:
            raise ConfigError(f"{_show(self.port)} is not tcp://HOST:PORT")
        return host, int(port)


@dataclass(frozen=True, eq=False)
class ConveyorConfig:
    """Everything a conveyor file says; `belt` and `diverter_m` are None when not given."""

    link: LinkSettings = field(default_factory=LinkSettings)
    registers: RegisterMap = field(default_factory=RegisterMap)
    belt: BeltGeometry | None = None
    diverter_m: float | None = None


def load_conveyor_config(path: str | Path) -> ConveyorConfig:
    """Read a conveyor TOML file (format in this module's docstring)."""
    return load_toml(path, MAX_FILE_BYTES, parse_conveyor_config, ConfigError)


def parse_conveyor_config(doc: dict[str, Any]) -> ConveyorConfig:
    """A conveyor configuration from a parsed TOML document."""
    tables = {"link", "registers", "belt"}
    _check_keys(doc, tables, "the file", {t: f"[{t}]" for t in tables})
    link = _dataclass_from(LinkSettings, doc.get("link", {}), "link")
    registers = _dataclass_from(RegisterMap, doc.get("registers", {}), "registers")
    belt_table = doc.get("belt", {})
    if not isinstance(belt_table, dict):
        raise ConfigError("[belt] must be a table")
    _check_keys(belt_table, {"direction", "normal", "point", "width_m", "diverter_m"}, "belt")
    geometry = None
    given = [k for k in ("direction", "normal", "point") if k in belt_table]
    if given:
        if len(given) != 3:
            raise ConfigError("belt: give direction, normal and point together")
        width = belt_table.get("width_m")
        direction, normal, point = (
            _vector(belt_table[k], f"belt.{k}") for k in ("direction", "normal", "point")
        )
        geometry = BeltGeometry.from_plane(
            direction, normal, point, None if width is None else _number(width, "belt.width_m")
        )
    diverter_m = belt_table.get("diverter_m")
    if diverter_m is not None:
        diverter_m = _number(diverter_m, "belt.diverter_m")
    return ConveyorConfig(link, registers, geometry, diverter_m)


def with_port(config: ConveyorConfig, port: str) -> ConveyorConfig:
    """The same configuration, reaching the controller at another port."""
    return replace(config, link=replace(config.link, port=port))


def _dataclass_from(cls: Any, table: object, where: str) -> Any:
    if not isinstance(table, dict):
        raise ConfigError(f"[{where}] must be a table")
    types = {f.name: f.type for f in fields(cls)}
    _check_keys(table, set(types), where)
    values: dict[str, object] = {}
    for key, value in table.items():
        kind = types[key]
        if kind == "float":
            values[key] = _number(value, f"{where}.{key}")
        elif kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{where}.{key} must be an integer, not {_show(value)}")
            values[key] = value
        elif not isinstance(value, str):
            raise ConfigError(f"{where}.{key} must be a string, not {_show(value)}")
        else:
            values[key] = value
    return cls(**values)


def _check_keys(
    table: dict[str, Any], allowed: set[str], where: str, forms: dict[str, str] | None = None
) -> None:
    if message := unknown_keys(table, allowed, forms):
        raise ConfigError(f"{where}: {message}")


def _check_int(name: str, value: int, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError(f"{name} must be an integer in {lo}..{hi}, not {_show(value)}")


def _number(value: object, where: str) -> float:
    number = as_float(value)
    if number is None:
        raise ConfigError(f"{where} must be a number, not {_show(value)}")
    if not math.isfinite(number):
        raise ConfigError(f"{where} must be a finite number, not {_show(value)}")
    return number


MAX_BELT_COORD_M = 1e4
"""The belt's point, and the components of its direction and normal, are at most this large."""


def _vector(value: object, where: str) -> np.ndarray[Any, np.dtype[np.float64]]:
    if not isinstance(value, list) or len(value) != 3:
        raise ConfigError(f"{where} must be a list of 3 numbers")
    out = np.array([_number(v, where) for v in value])
    if np.abs(out).max() > MAX_BELT_COORD_M:
        raise ConfigError(f"{where}: each number must be within ±{MAX_BELT_COORD_M:g}")
    return out
