"""What happened to a camera's stream, as timestamped events for a pipeline to log.

The driver recovers from unplugs, stalls and hangs on its own; these events say when it
did, why, and what it cost, so that nothing is lost silently.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class EventKind(enum.Enum):
    """The kinds of things that happen to a stream."""

    DISCONNECTED = "disconnected"
    """The camera stopped answering (unplugged, hub reset, hung); recovery begins."""
    RESET = "reset"
    """A USB port reset was sent to a camera that hung or kept stalling."""
    DEVICE_BUSY = "device-busy"
    """The camera is back but another program holds it; the driver keeps trying."""
    RECONNECTED = "reconnected"
    """The same camera (by serial number) is open again, configured and streaming."""
    GAVE_UP = "gave-up"
    """The camera did not come back within the reconnect policy's limit."""
    STALL_CLEARED = "stall-cleared"
    """The frame endpoint stalled (EPIPE) and its halt was cleared."""
    RESUMED = "resumed"
    """The first frame after an outage: how many frames the outage cost."""
    SEQUENCE_RESTART = "sequence-restart"
    """The camera's sequence numbers went backwards without an outage the driver saw."""


@dataclass(frozen=True)
class DeviceEvent:
    """One thing that happened, when the host saw it."""

    kind: EventKind
    host_time_ns: int
    """Host time, ns since the Unix epoch."""
    detail: str
    errno: int | None = None
    """The USB errno behind it, where there was one."""

    def __str__(self) -> str:
        code = f" (errno {self.errno})" if self.errno is not None else ""
        return f"{self.kind.value}: {self.detail}{code}"
