"""What the camera and conveyor rigs share: their error, and a fault's delayed end."""

from __future__ import annotations

import threading
from collections.abc import Callable

from tofcut.driver.errors import TofcutError


class RigError(TofcutError, ValueError):
    """A rig or fault asked for something it cannot do."""


class Later:
    """An action run on its own thread after a delay, or at once when `cancel` is set;
    `join` waits for it and raises what it raised."""

    def __init__(self, seconds: float, action: Callable[[threading.Event], None]) -> None:
        self.cancel = threading.Event()
        self._error: BaseException | None = None

        def run() -> None:
            self.cancel.wait(seconds)
            try:
                action(self.cancel)
            except BaseException as exc:
                self._error = exc

        self._thread = threading.Thread(target=run, name="tofcut-fault", daemon=True)
        self._thread.start()

    def join(self) -> None:
        self._thread.join()
        if self._error is not None:
            error, self._error = self._error, None
            raise error


def end_all(pending: list[Later]) -> None:
    """End every fault still to end, at once, and wait for each; raises what one raised."""
    for later in pending:
        later.cancel.set()
    for later in pending:
        later.join()


def check_seconds(what: str, seconds: float | None) -> None:
    """A fault's duration: None (the block's), or 0..3600 s (`RigError` otherwise)."""
    if seconds is not None and (
        isinstance(seconds, bool)
        or not isinstance(seconds, int | float)
        or not 0 <= seconds <= 3600
    ):
        raise RigError(
            f"{what}: seconds must be in 0..3600 (or None: the block's length), not {seconds!r:.40}"
        )
