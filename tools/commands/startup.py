"""What a command does before its first result, shown as it happens, so that a first run
(which compiles the tracker) does not sit silent.

    startup = begin("live")                     # the command line, before importing it
    current().step("starting the emulated camera")
    current().step("loading the tracker", slow="compiling the tracker (first run)")
    current().done()                            # before the command prints its own lines

On a terminal, one line on stderr names the step and its seconds, redrawn by a thread of
its own until `done()` clears it. Elsewhere (a pipe, a log file) a step that lasts over a
second is logged once, as a progress note (`tofcut: info: compiling the tracker ...`, shown
with `-v`), so that what a script reads on stderr stays as it was. `-q` shows nothing.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from typing import TextIO

STARTING = frozenset({"live", "track"})
"""The commands whose first result takes seconds (imports, the camera, the tracker)."""
REDRAW_S = 0.2
"""How often the terminal line is redrawn."""
SAY_AFTER_S = 1.0
"""Off a terminal, how long a step must last before it is logged."""
WIDTH = 100
_log = logging.getLogger("tofcut.startup")


class Startup:
    """The steps of a command's start, shown on `stream` (see the module docstring)."""

    def __init__(self, stream: TextIO | None = None, *, quiet: bool = False) -> None:
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = self.stream.isatty()
        self._cond = threading.Condition()
        self._text: str | None = None
        self._slow: str | None = None
        self._slow_after_s = 0.0
        self._started = 0.0
        self._said: str | None = None
        self._drawn = False
        self._thread: threading.Thread | None = None

    def step(self, text: str, *, slow: str | None = None, slow_after_s: float = 3.0) -> None:
        """A new step begins; after `slow_after_s` its text becomes `slow` (what a step that
        takes this long is doing: compiling rather than loading)."""
        if self.quiet:
            return
        with self._cond:
            self._text, self._slow, self._slow_after_s = text, slow, slow_after_s
            self._started = time.monotonic()
            self._said = None
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._show, name="tofcut-startup", daemon=True
                )
                self._thread.start()
            self._cond.notify_all()

    def done(self) -> None:
        """The start is over: clear the line (the command's own output follows)."""
        with self._cond:
            self._text = None
            self._cond.notify_all()
            self._clear()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join()

    def _show(self) -> None:
        with self._cond:
            while self._text is not None:
                elapsed = time.monotonic() - self._started
                text = self._text
                if self._slow is not None and elapsed >= self._slow_after_s:
                    text = self._slow
                if self.tty:
                    line = f"tofcut: {text} ... {elapsed:.0f} s"
                    self.stream.write("\r" + line[:WIDTH].ljust(WIDTH))
                    self.stream.flush()
                    self._drawn = True
                elif elapsed >= SAY_AFTER_S and self._said != text:
                    _log.info("%s ...", text)
                    self._said = text
                self._cond.wait(REDRAW_S)

    def _clear(self) -> None:
        if self._drawn:
            self.stream.write("\r" + " " * WIDTH + "\r")
            self.stream.flush()
            self._drawn = False


_current = Startup(quiet=True)


def begin(command: str | None, *, quiet: bool = False, stream: TextIO | None = None) -> Startup:
    """Start showing the start of `command` (if it is one of `STARTING`): it is loading."""
    global _current
    _current.done()
    _current = Startup(stream, quiet=quiet or command not in STARTING)
    _current.step(f"loading tofcut {command}")
    return _current


def current() -> Startup:
    """The start being shown (one that shows nothing when none was begun)."""
    return _current
