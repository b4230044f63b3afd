"""Ctrl-C as a request to stop: the run ends after the frame in hand and says what it did.

    with CtrlC() as ctrl_c:
        run(..., should_stop=lambda s: ctrl_c.requested or ...)

The first Ctrl-C only sets `requested`; a second one raises `KeyboardInterrupt` as usual
(a camera that sends no more frames cannot hold the user hostage). Outside the main
thread, where Python delivers no signal, it does nothing.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType
from typing import Any


class CtrlC:
    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None
        self._installed = False

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> CtrlC:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(self, *exc: object) -> None:
        if self._installed:
            previous = signal.default_int_handler if self._previous is None else self._previous
            signal.signal(signal.SIGINT, previous)
            self._installed = False
