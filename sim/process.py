"""The emulated camera in a process of its own, behind the same pyusb backend.

    camera = EmulatorProcess(functools.partial(open_scene, "conveyor", 0))
    Camera.open(backend=EmulatedBackend([camera]))      # the driver cannot tell
    camera.close()

On a machine with few cores, rendering a scene in the tracker's process takes the core (and
the GIL) the tracker needs; here a child process owns the scene's renderer, the device's
clock and its FIFO, and this object forwards what the bus asks of the camera — control
transfers, bulk reads, plugging, the faults tests inject — so it is used exactly as an
`EmulatedCamera` is. In real time the child renders each frame as its exposure ends
(`EmulatedCamera(render_ahead=True)`), so a parent slow to ask costs no rendering time; on
the virtual clock (`realtime=False`) it renders on demand, as in-process, bit for bit alike.

The child is a fresh interpreter (`python -c`, as multiprocessing's spawn, but without
importing the parent's `__main__`: the `tofcut` script would import the whole command line
again). It talks over two socket pairs, one for control and one for the bulk pipe, so a bulk
read waiting for a frame never holds up a control request (as on USB). A frame's bytes
cross in a shared buffer (a memfd both map; `tofcut.tools.bench.transfer` measured it at half
the parent's CPU time of the socket), read by read: the parent copies one read out before
it asks for the next, so one buffer is enough.

The child dies with the parent: it exits when its control socket reaches end of file, and
when the parent's process ends (a pidfd, for a socket some other child inherited). It sits
in a process group of its own, so Ctrl-C at a terminal reaches only the parent, which then
closes it. Its start-up errors come back as one line (`EmulatorProcessError`).
"""

from __future__ import annotations

import contextlib
import mmap
import os
import pickle
import select
import socket
import subprocess
import sys
import tempfile
import threading
import weakref
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from tofcut._closing import Closing
from tofcut.driver.errors import TofcutError
from tofcut.driver.protocol import DeviceInfo
from tofcut.sim.device import (
    EMULATOR_SERIAL,
    BulkOverflow,
    BulkTimeout,
    Detached,
    EmulatedCamera,
    ReplayEnded,
    Stall,
)
from tofcut.sim.source import TapSource

SHARED_BYTES = 8 << 20
"""The shared buffer: bulk reads up to this size cross in it (pages are only touched as
used); a larger read goes through the socket."""
START_TIMEOUT_S = 60.0
"""How long the child may take to start Python, build its scene and answer."""
ANSWER_GRACE_S = 10.0
"""How much longer than a bulk read's own timeout the child may take to answer it."""
CLOSE_TIMEOUT_S = 2.0
"""How long closing waits for the child to exit before it is killed."""
_DEVICE_ERRORS = (Stall, BulkTimeout, Detached, BulkOverflow, ValueError)
"""What the device raises on purpose: handed back to the caller as it is."""
_FORWARDED = frozenset(
    {
        "control_in", "control_out", "clear_halt", "usb_reset", "attach", "detach",
        "pulse_trigger_input", "damage_next", "stall_endpoint", "time_out_next", "hang",
        "overflow_fifo", "truth", "now_us",
    }
)  # fmt: skip
"""The camera's methods the proxy forwards."""
_READABLE = frozenset({"frames_sent", "frames_dropped", "boots", "frame_period_us"})
"""The camera's values the proxy reads."""


class EmulatorProcessError(TofcutError):
    """The emulated camera's process did not start, or ended when it should not have."""


class EmulatorProcess(Closing):
    """An emulated camera (`EmulatedCamera`) running in a child process; this is its proxy.

    `make_source` builds the scene (or the `Recording` to replay) in the child: it is
    pickled, so a module-level function or a `functools.partial` of one. `source`, if
    given, is this process's copy of that scene, for what the caller reads of it
    (metadata, the belt); nothing renders it here.
    The other arguments are `EmulatedCamera`'s. Close it (or use it as a context manager)
    to end the child; it also ends when this object is collected or the interpreter exits.
    """

    def __init__(
        self,
        make_source: Callable[[], TapSource],
        *,
        source: TapSource | None = None,
        serial: int = EMULATOR_SERIAL,
        firmware: int = 0x0104,
        realtime: bool = True,
        registers: dict[Any, int] | None = None,
        fifo_frames: int | None = None,
        start_timeout_s: float = START_TIMEOUT_S,
    ) -> None:
        self.source = source
        self.realtime = realtime
        self.replay_done = threading.Event()
        """Set when the camera replays a recording, has sent its last frame and was asked
        for more (`EmulatedCamera.replay_done`)."""
        self._closed = False
        self._control_lock = threading.Lock()
        self._bulk_lock = threading.Lock()
        kwargs: dict[str, Any] = dict(
            serial=serial, firmware=firmware, realtime=realtime, registers=registers
        )
        if fifo_frames is not None:
            kwargs["fifo_frames"] = fifo_frames
        recipe = pickle.dumps((make_source, kwargs))
        self._shared_fd = _anonymous_file("tofcut-emulator-frames", SHARED_BYTES)
        self._shared = mmap.mmap(self._shared_fd, SHARED_BYTES)
        self._view = memoryview(self._shared)
        self._stderr_fd = _anonymous_file("tofcut-emulator-stderr")
        control, control_child = socket.socketpair()
        bulk, bulk_child = socket.socketpair()
        fds = [control_child.fileno(), bulk_child.fileno(), self._shared_fd]
        code = (
            f"import sys; sys.path[:] = {sys.path!r}; "
            f"from tofcut.sim.process import serve; serve({os.getpid()}, *{fds!r})"
        )
        try:
            self._child = subprocess.Popen(
                [sys.executable, "-c", code],
                pass_fds=fds,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=self._stderr_fd,
                process_group=0,
            )
        finally:
            control_child.close()
            bulk_child.close()
        self._control = Connection(control.detach())
        self._bulk = Connection(bulk.detach())
        self._finalizer = weakref.finalize(self, _shut_down, self._child, self._control, self._bulk)
        try:
            self.info: DeviceInfo = self._start(recipe, start_timeout_s)
        except BaseException:
            self.close()
            raise

    def _start(self, recipe: bytes, timeout_s: float) -> DeviceInfo:
        """Hand the child its camera and wait until it is ready; its device info."""
        try:
            self._control.send_bytes(recipe)
            if not self._control.poll(timeout_s):
                raise EmulatorProcessError(
                    f"the emulated camera's process did not start within {timeout_s:g} s"
                )
            status, value = self._control.recv()
        except (EOFError, OSError):
            raise self._died("could not start") from None
        if status != "ready":
            raise EmulatorProcessError(f"the emulated camera's process could not start: {value}")
        assert isinstance(value, DeviceInfo)
        return value

    # --- lifetime -------------------------------------------------------------------------

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self._child.pid

    @property
    def exit_status(self) -> int | None:
        """The child's exit status once it has ended (negative: the signal that ended it)."""
        return self._child.poll()

    def close(self) -> None:
        """End the child (at once: a bulk read waiting in it is not waited for); idempotent."""
        if self._closed:
            return
        self._closed = True
        self._finalizer()
        with contextlib.suppress(OSError, ValueError, BufferError):
            self._view.release()
            self._shared.close()
        for fd in (self._shared_fd, self._stderr_fd):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _died(self, what: str) -> EmulatorProcessError:
        """The error for a child that is gone: its exit status and the last line it wrote."""
        try:
            status = self._child.wait(CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            status = None
        how = "" if status is None else f" (exit status {status})"
        last = self._last_error_line()
        return EmulatorProcessError(
            f"the emulated camera's process {what}{how}" + (f": {last}" if last else "")
        )

    def _last_error_line(self) -> str:
        with contextlib.suppress(OSError):
            size = os.fstat(self._stderr_fd).st_size
            tail = os.pread(self._stderr_fd, 4096, max(0, size - 4096))
            lines = [x.strip() for x in tail.decode("utf-8", "replace").splitlines()]
            return next((x for x in reversed(lines) if x), "")
        return ""

    # --- forwarding -----------------------------------------------------------------------

    def _call(self, *request: Any) -> Any:
        with self._control_lock:
            if self._closed:
                raise Detached
            try:
                self._control.send(request)
                status, value = self._control.recv()
            except (EOFError, OSError):
                if self._closed:
                    raise Detached from None
                raise self._died("ended unexpectedly") from None
        if status == "raise":
            raise value
        return value

    def _forward(self, name: str, *args: Any, **kwargs: Any) -> Any:
        return self._call("call", name, args, kwargs)

    def control_in(self, request: int, value: int, index: int, length: int) -> bytes:
        """A vendor IN request; its answer."""
        return bytes(self._forward("control_in", request, value, index, length))

    def control_out(self, request: int, value: int, index: int, data: bytes) -> None:
        """A vendor OUT request."""
        self._forward("control_out", request, value, index, data)

    def clear_halt(self) -> None:
        """The host's CLEAR_FEATURE(ENDPOINT_HALT) on the frame endpoint."""
        self._forward("clear_halt")

    def usb_reset(self) -> None:
        """A USB port reset: the firmware restarts."""
        self._forward("usb_reset")

    def attach(self) -> None:
        """The cable is plugged in (the bus's `plug`)."""
        self._forward("attach")

    def detach(self, *, power_loss: bool = True) -> None:
        """The cable is pulled (the bus's `unplug`)."""
        self._forward("detach", power_loss=power_loss)

    def pulse_trigger_input(self) -> None:
        """A pulse on the hardware trigger input."""
        self._forward("pulse_trigger_input")

    def damage_next(self, kind: str = "payload", count: int = 1) -> None:
        """Fault: damage the next `count` frames on the wire (`EmulatedCamera.damage_next`)."""
        self._forward("damage_next", kind, count)

    def stall_endpoint(self, count: int = 1, after_packets: int = 0) -> None:
        """Fault: halt the frame endpoint (`EmulatedCamera.stall_endpoint`)."""
        self._forward("stall_endpoint", count, after_packets)

    def time_out_next(self, count: int = 1) -> None:
        """Fault: the next `count` bulk reads time out."""
        self._forward("time_out_next", count)

    def hang(self) -> None:
        """Fault: the firmware hangs until a reset or power cycle."""
        self._forward("hang")

    def overflow_fifo(self, frames: int) -> None:
        """Fault: `frames` frames are dropped for want of FIFO room."""
        self._forward("overflow_fifo", frames)

    def truth(self, sequence: int) -> object | None:
        """Ground truth of a recently sent frame, else None."""
        truth: object | None = self._forward("truth", sequence)
        return truth

    def now_us(self) -> int:
        """Device time, µs since power-on."""
        return int(self._forward("now_us"))

    @property
    def frames_sent(self) -> int:
        """Frames the camera has put on the wire."""
        return int(self._call("get", "frames_sent"))

    @property
    def frames_dropped(self) -> int:
        """Frames the camera dropped for want of FIFO room."""
        return int(self._call("get", "frames_dropped"))

    @property
    def boots(self) -> int:
        """Times the firmware started."""
        return int(self._call("get", "boots"))

    @property
    def frame_period_us(self) -> int:
        """Time between frame starts."""
        return int(self._call("get", "frame_period_us"))

    def bulk_read_into(self, out: memoryview, timeout_ms: int) -> int:
        """One bulk IN transfer of up to `len(out)` bytes, landed in `out`."""
        with self._bulk_lock:
            if self._closed:
                raise Detached
            try:
                self._bulk.send((len(out), timeout_ms))
                if not self._bulk.poll(timeout_ms / 1000 + ANSWER_GRACE_S):
                    raise EmulatorProcessError(
                        "the emulated camera's process stopped answering bulk reads"
                    )
                status, value = self._bulk.recv()
                if status == "shared":
                    out[:value] = self._view[:value]
                elif status == "socket":
                    self._bulk.recv_bytes_into(out)
            except (EOFError, OSError, ValueError):
                if self._closed:
                    raise Detached from None
                raise self._died("ended unexpectedly") from None
        if status == "raise":
            if isinstance(value, ReplayEnded):
                self.replay_done.set()
            raise value
        return int(value)

    def bulk_read(self, size: int, timeout_ms: int) -> bytes:
        """What one bulk IN transfer of `size` bytes returns."""
        out = bytearray(size)
        return bytes(out[: self.bulk_read_into(memoryview(out), timeout_ms)])


def _shut_down(child: subprocess.Popen[bytes], control: Connection, bulk: Connection) -> None:
    """Ask the child to exit, kill it if it does not, then close the sockets (a bulk read
    waiting on one sees its end of file first)."""
    with contextlib.suppress(OSError, EOFError):
        control.send(("exit",))
    try:
        child.wait(CLOSE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()
    for conn in (control, bulk):
        with contextlib.suppress(OSError):
            conn.close()


def _anonymous_file(name: str, size: int = 0) -> int:
    """A file descriptor of a file with no name (a memfd where there are memfds)."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create(name)
    else:
        with tempfile.TemporaryFile(prefix=name) as f:
            fd = os.dup(f.fileno())
    os.ftruncate(fd, size)
    return fd


# --- the child ------------------------------------------------------------------------------


def serve(parent_pid: int, control_fd: int, bulk_fd: int, shared_fd: int) -> None:
    """The child's life: build the camera, serve the bulk pipe on a thread and control
    requests here, and exit when the parent says so or is gone."""
    _exit_with(parent_pid)
    control = Connection(control_fd)
    try:
        make_source, kwargs = pickle.loads(control.recv_bytes())
        camera = EmulatedCamera(make_source(), render_ahead=True, **kwargs)
    except EOFError:
        os._exit(0)
    except BaseException as exc:
        text = str(exc).strip().splitlines()
        control.send(("failed", text[0] if text else type(exc).__name__))
        os._exit(1)
    shared = mmap.mmap(shared_fd, SHARED_BYTES)
    threading.Thread(
        target=_serve_bulk, args=(camera, Connection(bulk_fd), shared), daemon=True
    ).start()
    control.send(("ready", camera.info))
    while True:
        try:
            request = control.recv()
        except (EOFError, OSError):
            os._exit(0)
        if request[0] == "exit":
            os._exit(0)
        try:
            reply = ("ok", _answer(camera, request))
        except _DEVICE_ERRORS as exc:
            reply = ("raise", exc)
        except Exception as exc:  # a bug here: told to the caller, the child serves on
            reply = ("raise", EmulatorProcessError(f"the emulated camera failed: {exc!r}"))
        control.send(reply)


def _answer(camera: EmulatedCamera, request: tuple[Any, ...]) -> Any:
    kind, name = request[0], request[1]
    if kind == "call" and name in _FORWARDED:
        args, kwargs = request[2], request[3]
        return getattr(camera, name)(*args, **kwargs)
    if kind == "get" and name in _READABLE:
        return getattr(camera, name)
    raise ValueError(f"the emulated camera has no {kind} {name!r}")


def _serve_bulk(camera: EmulatedCamera, bulk: Connection, shared: mmap.mmap) -> None:
    while True:
        try:
            size, timeout_ms = bulk.recv()
        except (EOFError, OSError):
            os._exit(0)
        try:
            piece = camera.bulk_read(size, timeout_ms)
        except _DEVICE_ERRORS as exc:
            bulk.send(("raise", exc))
            continue
        if len(piece) <= len(shared):
            shared[: len(piece)] = piece
            bulk.send(("shared", len(piece)))
        else:
            bulk.send(("socket", len(piece)))
            bulk.send_bytes(piece)


def _exit_with(parent_pid: int) -> None:
    """Exit when the parent's process ends, whoever else holds its sockets."""
    if os.getppid() != parent_pid:
        os._exit(0)  # the parent is gone already
    try:
        pidfd = os.pidfd_open(parent_pid)
    except (AttributeError, OSError):
        return  # no pidfds here: the control socket's end of file is the sign

    def wait() -> None:
        select.select([pidfd], [], [])
        os._exit(0)

    threading.Thread(target=wait, name="tofcut-parent-watch", daemon=True).start()
