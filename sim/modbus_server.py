"""A Modbus RTU server on a pseudo-terminal pair, with the faults a real line has.

The server holds the pty's master; clients open its slave like any serial port (its tty
name, or a stable symlink when `link` is given, as udev gives /dev/serial/by-id/...).
Faults, for tests and demos:

- `inject(Fault.CRC)` etc.: the next replies are garbage, have a bad CRC, are an
  exception reply ("busy"), or the request is lost (no reply, not executed);
- `noise(n)`: n random bytes on the line now, between requests;
- `silent = True`: the controller stops answering (until set back);
- `vanish()` / `reappear()`: the port goes away (the pty is closed and the symlink
  removed, as when a USB adapter is unplugged) and comes back at the same path.

Written on bare file descriptors rather than pymodbus's server so faults can be put on the
wire byte by byte; pymodbus's client checks it against the standard in the tests.
"""

from __future__ import annotations

import enum
import os
import random
import select
import threading
import tty
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from tofcut._closing import Closing
from tofcut.sim.modbus_rtu import (
    ExceptionCode,
    RegisterDevice,
    crc_ok,
    exception_reply,
    request_length,
    serve,
)

SILENCE_S = 0.004
"""A pause this long ends a frame (RTU's 3.5 character times, with room for a pty)."""


class Fault(enum.Enum):
    GARBAGE = "garbage"
    """The reply is replaced by random bytes of the same length."""
    CRC = "crc"
    """The reply's CRC is wrong."""
    EXCEPTION = "exception"
    """The request is refused with a "busy" exception reply (and not executed)."""
    LOST = "lost"
    """The request never arrives: no reply, not executed."""


@dataclass
class ServerStats:
    requests: int = 0
    """Frames with a good CRC addressed to this unit."""
    replies: int = 0
    bad_frames: int = 0
    """Frames dropped for a bad CRC or an incomplete frame."""
    other_units: int = 0
    """Good frames for another unit id (ignored, as on a shared RS-485 bus)."""


class PtyModbusServer(Closing):
    """Serves a `RegisterDevice` as Modbus RTU unit `unit` on a pseudo-terminal."""

    def __init__(
        self,
        device: RegisterDevice,
        *,
        unit: int = 1,
        link: str | Path | None = None,
        seed: int = 0,
    ) -> None:
        self.device = device
        self.unit = unit
        self.link = None if link is None else Path(link)
        self.stats = ServerStats()
        self.silent = False
        self._rng = random.Random(seed)
        self._faults: deque[Fault] = deque()
        self._lock = threading.Lock()
        self._master = -1
        self._slave = -1
        self._tty = ""
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()

    @property
    def port(self) -> str:
        """What a client opens: the stable link if there is one, else the slave's tty."""
        return str(self.link) if self.link is not None else self._tty

    # --- life -----------------------------------------------------------------------------

    def start(self) -> PtyModbusServer:
        """Make the pty (and its link) and serve it on a thread."""
        if self._thread is not None:
            return self
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: bytes as they are
        self._tty = os.ttyname(self._slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self._tty)
            tmp.replace(self.link)
        self._thread = threading.Thread(target=self._run, name="modbus-pty", daemon=True)
        self._thread.start()
        return self

    def vanish(self) -> None:
        """The port goes away: stop serving, close the pty, remove the link."""
        if self._thread is not None:
            os.write(self._wake_w, b"x")
            self._thread.join()
            self._thread = None
            os.close(self._master)
            os.close(self._slave)
        if self.link is not None:
            self.link.unlink(missing_ok=True)

    def reappear(self) -> None:
        """The port comes back (a new pty, at the same link)."""
        self.start()

    def close(self) -> None:
        self.vanish()
        os.close(self._wake_r)
        os.close(self._wake_w)

    def __enter__(self) -> PtyModbusServer:
        return self.start()

    # --- faults ---------------------------------------------------------------------------

    def inject(self, fault: Fault, count: int = 1) -> None:
        """Apply `fault` to the next `count` requests to this unit."""
        with self._lock:
            self._faults.extend([fault] * count)

    def noise(self, nbytes: int) -> None:
        """Put `nbytes` random bytes on the line now."""
        with self._lock:
            junk = self._rng.randbytes(nbytes)
        os.write(self._master, junk)

    def pending_faults(self) -> int:
        with self._lock:
            return len(self._faults)

    def clear_faults(self) -> int:
        """Drop the injected faults no request has used yet; returns how many."""
        with self._lock:
            n = len(self._faults)
            self._faults.clear()
            return n

    # --- the server's thread --------------------------------------------------------------

    def _run(self) -> None:
        buf = bytearray()
        while True:
            ready, _, _ = select.select(
                [self._master, self._wake_r], [], [], SILENCE_S if buf else None
            )
            if self._wake_r in ready:
                os.read(self._wake_r, 64)
                return
            if self._master in ready:
                buf += os.read(self._master, 4096)
                self._frames(buf, silence=False)
            else:
                self._frames(buf, silence=True)

    def _frames(self, buf: bytearray, silence: bool) -> None:
        """Serve every whole request at the start of `buf`; at a silence, drop the rest."""
        while buf:
            n = request_length(buf)
            if n is None and silence:
                n = len(buf)  # an unknown function: the silence says where it ends
            if n is None or len(buf) < n:
                if silence:
                    self.stats.bad_frames += 1
                    buf.clear()
                return
            request = bytes(buf[:n])
            if not crc_ok(request):
                self.stats.bad_frames += 1
                buf.clear()  # resynchronise at the next silence
                return
            del buf[:n]
            self._answer(request)

    def _answer(self, request: bytes) -> None:
        unit = request[0]
        if unit not in (self.unit, 0):
            self.stats.other_units += 1
            return
        self.stats.requests += 1
        if self.silent:
            return
        with self._lock:
            fault = self._faults.popleft() if self._faults else None
        if fault is Fault.LOST:
            return
        if fault is Fault.EXCEPTION:
            reply = exception_reply(unit, request[1], ExceptionCode.BUSY)
        else:
            reply = serve(self.unit, request, self.device)
        if unit == 0:
            return  # broadcast: executed, never answered
        if fault is Fault.GARBAGE:
            with self._lock:
                reply = self._rng.randbytes(len(reply))
        elif fault is Fault.CRC:
            reply = reply[:-1] + bytes([reply[-1] ^ 0xFF])
        os.write(self._master, reply)
        self.stats.replies += 1
