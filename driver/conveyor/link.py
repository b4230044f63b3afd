"""The conveyor link: a Modbus client (pymodbus, RTU on a serial port or a TCP gateway) that
polls the belt's encoder on its own thread, writes a heartbeat, and fires the diverter.

    with ConveyorClient(LinkSettings(port="/dev/ttyUSB0")) as belt:
        reading = belt.reading_at(frame.host_time_ns)   # distance and speed at that frame
        belt.divert(track_id)                           # returns at once; written next

One thread owns the port (Modbus is one transaction at a time): it polls at `poll_hz`,
writes queued diverter commands before the next poll, and the heartbeat every
`heartbeat_s`. Timeouts, bad frames (CRC errors, garbage) and exception replies are retried
up to `retries` times and counted; a port that goes away is reopened every `reopen_s` until
it comes back. Callers only ever take a short lock: nothing here waits on the link.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from functools import partial

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException
from pymodbus.framer import FramerType
from pymodbus.pdu import ModbusPDU

from tofcut._closing import Closing
from tofcut.driver.belt import BeltHistory, BeltReading, unwrap_count
from tofcut.driver.conveyor.config import LinkSettings, RegisterMap
from tofcut.driver.errors import ConfigError, LinkError

log = logging.getLogger(__name__)

Listener = Callable[[BeltReading], object]
CLOSE_DEADLINE_S = 1.0
"""`close()` waits this long at most for a request under way to end."""
COMMANDS_KEPT = 64
"""Diverter commands waiting for the link: past this many (a link stuck in a long request),
the oldest is dropped and counted as late (it would be dropped as late when sent anyway)."""


@dataclass(frozen=True)
class LinkStats:
    """What the link has done so far (a snapshot)."""

    readings: int = 0
    """Polls that returned a belt reading."""
    failed_polls: int = 0
    """Polls that failed after every retry, or on a lost port."""
    retries: int = 0
    """Requests sent again after a failed attempt."""
    timeouts: int = 0
    """Attempts that got no reply at all."""
    bad_frames: int = 0
    """Attempts whose reply was unusable: CRC error, garbage, wrong length."""
    exception_replies: int = 0
    """Attempts the controller answered with a Modbus exception."""
    disconnects: int = 0
    """Times the port went away (or the gateway hung up)."""
    reopens: int = 0
    """Times it was opened again after that."""
    heartbeats: int = 0
    diverter_writes: int = 0
    diverter_failures: int = 0
    """Diverter commands that failed after every retry."""
    diverter_late: int = 0
    """Diverter commands dropped because the link could not send them in time."""
    link_up: bool = False
    """The last request got a good reply."""
    last_error: str = ""

    @property
    def polls(self) -> int:
        """Polls done (the one under way is not counted yet)."""
        return self.readings + self.failed_polls


class _Failed(Exception):
    """A request failed after every retry (or the port went away); already counted."""


class ConveyorClient(Closing):
    """A conveyor controller over Modbus; `open()` (or `with`) starts its polling thread."""

    def __init__(
        self,
        link: LinkSettings,
        registers: RegisterMap | None = None,
        *,
        history_s: float = 10.0,
        max_extrapolation_s: float = 0.5,
        max_command_delay_s: float = 0.25,
        clock_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        if not link.port:
            raise ConfigError("no conveyor port given (a serial port or tcp://HOST:PORT)")
        self.link = link
        self.registers = registers or RegisterMap()
        self._plan = self.registers.read_plan()
        self.max_extrapolation_s = max_extrapolation_s
        """How long past its last reading the link still answers `reading_at` (see BeltHistory)."""
        self._max_command_delay_s = max_command_delay_s
        self._clock_ns = clock_ns
        self._modbus = self._make_modbus()
        self._lock = threading.Condition()
        self._history = BeltHistory(max(2, round(history_s * link.poll_hz)), max_extrapolation_s)
        self._counts = {f.name: 0 for f in fields(LinkStats) if f.type == "int"}
        self._link_up = False
        self._last_error = ""
        self._commands: deque[tuple[int, float]] = deque()
        self._listeners: list[Listener] = []
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._abandoned: threading.Thread | None = None
        self._connected = False
        self._ever_connected = False
        self._rx_seen = False
        self._unwrapped: int | None = None
        self._raw: int | None = None
        self._first: int | None = None
        self._delivered: BeltReading | None = None
        self._beat = 0

    def _make_modbus(self) -> ModbusSerialClient | ModbusTcpClient:
        # retries=0: this class retries itself, so that it can count what went wrong.
        link = self.link
        if link.is_tcp:
            host, port = link.tcp_address()
            return ModbusTcpClient(
                host, port=port, timeout=link.timeout_s, retries=0, trace_packet=self._trace
            )
        return ModbusSerialClient(
            link.port,
            framer=FramerType.RTU,
            baudrate=link.baudrate,
            bytesize=link.bytesize,
            parity=link.parity,
            stopbits=link.stopbits,
            timeout=link.timeout_s,
            retries=0,
            trace_packet=self._trace,
        )

    # --- life -----------------------------------------------------------------------------

    def open(self) -> ConveyorClient:
        """Open the port and start polling; `LinkError` if the port cannot be opened now."""
        if self._thread is not None:
            return self
        if self._abandoned is not None:  # a request close() gave up on: let it end first
            self._abandoned.join()
            self._abandoned = None
        if not self._connect():
            raise LinkError(
                f"cannot open the conveyor link {self.link.port!r} ({self._last_error}); "
                "'tofcut ports' lists the serial ports"
            )
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="conveyor-link", daemon=True)
        self._thread.start()
        return self

    def close(self, deadline_s: float = CLOSE_DEADLINE_S) -> None:
        """Stop polling and close the port, within `deadline_s`: a request still in flight
        then (a silent controller, a long `timeout_s`) is abandoned to the link's thread, a
        daemon, which closes the port itself when the request ends."""
        self._stop.set()
        self._wake.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(deadline_s)
            if thread.is_alive():
                self._abandoned = thread
                log.warning(
                    "conveyor link %s: a request was still under way %.1f s after close; "
                    "abandoned (the port closes when it times out)",
                    self.link.port,
                    deadline_s,
                )
            else:
                self._abandoned = None
        elif self._abandoned is None or not self._abandoned.is_alive():
            self._modbus.close()  # type: ignore[no-untyped-call]
        with self._lock:
            self._connected = False
            self._link_up = False
            self._lock.notify_all()

    def __enter__(self) -> ConveyorClient:
        return self.open()

    # --- what the rest of the program reads -----------------------------------------------

    @property
    def stats(self) -> LinkStats:
        with self._lock:
            return self._stats()

    def latest(self) -> BeltReading | None:
        """The newest reading (however old: check its `time_ns`), or None before the first."""
        with self._lock:
            return self._history.latest()

    def reading_at(self, time_ns: int) -> BeltReading | None:
        """The belt at a host time (e.g. a frame's `host_time_ns`): distance interpolated
        between readings, or extrapolated a little past the last; None when unknown."""
        with self._lock:
            return self._history.at(time_ns)

    def wait_for(
        self, predicate: Callable[[BeltReading], bool], timeout_s: float
    ) -> BeltReading | None:
        """Block until the newest reading satisfies `predicate`, or the timeout (None).
        A reading counts once every listener has had it."""

        def found() -> BeltReading | None:
            r = self._delivered
            return r if r is not None and predicate(r) else None

        with self._lock:
            self._lock.wait_for(lambda: found() is not None, timeout_s)
            return found()

    def wait_stats(self, predicate: Callable[[LinkStats], bool], timeout_s: float) -> LinkStats:
        """Block until the link's statistics satisfy `predicate`, or the timeout; the last
        statistics either way."""
        with self._lock:
            self._lock.wait_for(lambda: predicate(self._stats()), timeout_s)
            return self._stats()

    def add_listener(self, listener: Listener) -> None:
        """Call `listener(reading)` on the link's thread after every new reading; it must be
        quick (it delays the next poll)."""
        with self._lock:
            self._listeners.append(listener)

    def divert(self, tag: int = 0) -> None:
        """Queue one diverter command (tag: e.g. the track id, for the log); returns at once.
        A command the link cannot send within `max_command_delay_s` is dropped and counted:
        a late push would hit the wrong object."""
        with self._lock:
            if len(self._commands) >= COMMANDS_KEPT:
                old, _ = self._commands.popleft()
                self._counts["diverter_late"] += 1
                log.error("diverter command for %d dropped: the link is behind", old)
            self._commands.append((tag, time.monotonic()))
        self._wake.set()

    # --- the link's thread ----------------------------------------------------------------

    def _run(self) -> None:
        period = 1.0 / self.link.poll_hz
        beat = self.link.heartbeat_s
        next_poll = time.monotonic()
        next_beat = next_poll if beat > 0 else float("inf")
        while not self._stop.is_set():
            self._wake.clear()
            if not self._connected:
                if not self._connect():
                    self._wake.wait(self.link.reopen_s)
                continue
            command = self._next_command()
            now = time.monotonic()
            try:
                # Diverter commands first; then whichever of heartbeat and poll fell due
                # first, so that neither can starve the other.
                if command is not None:
                    self._write_diverter(*command)
                elif now >= next_beat and next_beat <= next_poll:
                    next_beat = now + beat
                    self._write_heartbeat()
                elif now >= next_poll:
                    next_poll = max(next_poll + period, time.monotonic())
                    self._poll()
                else:
                    self._wake.wait(min(next_poll, next_beat) - now)
            except _Failed:
                pass
        self._modbus.close()  # type: ignore[no-untyped-call]

    def _connect(self) -> bool:
        error = "not there, busy, or refused"  # pymodbus logs the reason and returns False
        try:
            ok = bool(self._modbus.connect())
        except Exception as exc:  # pyserial and sockets raise more than they document
            ok, error = False, str(exc)
        with self._lock:
            if ok:
                if self._ever_connected:
                    self._counts["reopens"] += 1
                    log.info("conveyor link %s reopened", self.link.port)
                self._ever_connected = True
                self._connected = True
            else:
                self._last_error = error
            self._lock.notify_all()
        return ok

    def _next_command(self) -> tuple[int, float] | None:
        with self._lock:
            return self._commands.popleft() if self._commands else None

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if not sending and data:
            self._rx_seen = True
        return data

    def _request(self, what: str, call: Callable[[], ModbusPDU]) -> tuple[ModbusPDU, int]:
        """One request with retries: the reply and the middle of its round trip (host ns)."""
        for attempt in range(self.link.retries + 1):
            if attempt:
                if self._stop.is_set():  # closing: no more attempts
                    raise _Failed
                self._count("retries")
            self._rx_seen = False
            t0 = self._clock_ns()
            try:
                reply = call()
            except ConnectionException as exc:
                self._lost(f"{what}: {exc}")
                raise _Failed from None
            except (ModbusException, OSError) as exc:
                self._fail("bad_frames" if self._rx_seen else "timeouts", f"{what}: {exc}")
                continue
            t1 = self._clock_ns()
            if reply.isError():
                self._fail("exception_replies", f"{what}: exception {reply.exception_code}")
                continue
            with self._lock:
                self._link_up = True
                self._lock.notify_all()
            return reply, (t0 + t1) // 2
        raise _Failed

    def _poll(self) -> None:
        try:
            self._read_belt()
        except _Failed:
            self._count("failed_polls")
            raise

    def _read_belt(self) -> None:
        unit = self.link.unit
        values: dict[int, int] = {}
        stamp = 0
        for start, count in self._plan:
            reply, t_mid = self._request(
                f"read {start}+{count}",
                partial(self._modbus.read_holding_registers, start, count=count, device_id=unit),
            )
            if len(reply.registers) != count:
                self._fail("bad_frames", f"read {start}+{count}: {len(reply.registers)} registers")
                raise _Failed
            values.update(zip(range(start, start + count), reply.registers, strict=True))
            if start <= self.registers.encoder < start + count:
                stamp = t_mid
        self._add_reading(stamp, values)

    def _add_reading(self, stamp: int, values: dict[int, int]) -> None:
        regs = self.registers
        raw = regs.encoder_count(values[regs.encoder], values[regs.encoder + 1])
        status = values[regs.status]
        with self._lock:
            self._unwrapped = unwrap_count(self._unwrapped, self._raw, raw)
            self._raw = raw
            if self._first is None:
                self._first = self._unwrapped
            reading = BeltReading(
                time_ns=stamp,
                count=raw,
                distance_m=(self._unwrapped - self._first) / regs.counts_per_m,
                speed_mps=regs.speed_mps(values[regs.speed]),
                running=bool(status >> regs.running_bit & 1),
                fault=bool(status >> regs.fault_bit & 1),
            )
            last = self._history.latest()
            if last is not None and stamp < last.time_ns:  # the host clock stepped back
                reading = replace(reading, time_ns=last.time_ns)
            self._history.append(reading)
            self._counts["readings"] += 1
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener(reading)
            except Exception:
                log.exception("a conveyor listener failed")
        with self._lock:
            self._delivered = reading
            self._lock.notify_all()

    def _write_heartbeat(self) -> None:
        self._beat = (self._beat + 1) & 0xFFFF
        value, unit = self._beat, self.link.unit
        self._request(
            "heartbeat",
            lambda: self._modbus.write_register(self.registers.heartbeat, value, device_id=unit),
        )
        self._count("heartbeats")

    def _write_diverter(self, tag: int, queued: float) -> None:
        waited = time.monotonic() - queued
        if waited > self._max_command_delay_s:
            self._count("diverter_late")
            log.error("diverter command for %d dropped: %.0f ms late", tag, waited * 1e3)
            return
        regs, unit = self.registers, self.link.unit
        try:
            self._request(
                "diverter",
                lambda: self._modbus.write_register(
                    regs.diverter, regs.diverter_value, device_id=unit
                ),
            )
        except _Failed:
            self._count("diverter_failures")
            # a request abandoned at close ends so, as expected: said only in the debug log
            # (the test or program that closed the link may have closed the log's stream)
            level = logging.DEBUG if self._stop.is_set() else logging.ERROR
            log.log(level, "diverter command for %d failed: %s", tag, self._last_error)
            raise
        self._count("diverter_writes")
        latest = self.latest()
        log.info("diverter fired for %d (encoder %s)", tag, "?" if latest is None else latest.count)

    # --- bookkeeping ----------------------------------------------------------------------

    def _count(self, name: str) -> None:
        with self._lock:
            self._counts[name] += 1
            self._lock.notify_all()

    def _fail(self, name: str, error: str) -> None:
        with self._lock:
            self._counts[name] += 1
            self._last_error = error
            self._link_up = False
            self._lock.notify_all()

    def _lost(self, error: str) -> None:
        self._modbus.close()  # type: ignore[no-untyped-call]
        with self._lock:
            self._counts["disconnects"] += 1
            self._last_error = error
            self._link_up = False
            self._connected = False
            self._lock.notify_all()
        # a request that close() abandoned ends here once the port is gone: no news then
        (log.debug if self._stop.is_set() else log.warning)(
            "conveyor link %s lost: %s", self.link.port, error
        )

    def _stats(self) -> LinkStats:
        return LinkStats(**self._counts, link_up=self._link_up, last_error=self._last_error)
