"""When a frame was taken, on the host's clock: what belt readings must be matched against.

`Frame.host_time_ns` is when the frame arrived — after its exposure, readout, transfer and
parsing, which at 0.25 m/s can be centimetres of belt. The camera stamps the start of the
exposure on its own clock. The offset between the two clocks is taken from the frame that
came quickest among the last `window` (the smallest arrival − exposure difference), so
every delay longer than that one frame's is removed.
"""

from __future__ import annotations

from collections import deque

from tofcut.driver.frames import Frame
from tofcut.driver.protocol import TAPS, integration_us


def exposure_mid_ns(frame: Frame) -> int:
    """Device time (ns) of the middle of a frame's exposure: the mean of its taps' middles."""
    h = frame.header
    return (
        h.device_time_us * 1000
        + (TAPS - 1) * h.tap_interval_us * 500
        + integration_us(h.integration) * 500
    )


class ExposureClock:
    """Host time of each frame's exposure, from the camera's timestamps (one camera).

    `offset_ns`: host time minus device time, when it is known exactly (an emulated camera
    runs on the host's clock); then no offset is estimated.
    """

    def __init__(self, window: int = 500, offset_ns: int | None = None) -> None:
        self._window = window
        self._fixed = offset_ns
        self._offsets: deque[tuple[int, int]] = deque()
        """(index, offset ns), offsets increasing: the sliding window's minimum is first."""
        self._index = 0
        self._last: tuple[int, int] | None = None

    @property
    def offset_ns(self) -> int | None:
        """The fixed host − device offset it was given, or None where it estimates one: what a
        conveyor log keeps so that a replay places frames exactly as the live run did."""
        return self._fixed

    def host_time_ns(self, frame: Frame) -> int:
        """The host time of the middle of `frame`'s exposure."""
        mid_ns = exposure_mid_ns(frame)
        if self._fixed is not None:
            return mid_ns + self._fixed
        last = self._last
        if last is None or (frame.sequence, mid_ns) != last:
            if last is not None and mid_ns < last[1]:  # the camera restarted its clock
                self._offsets.clear()
            self._record(frame.host_time_ns - mid_ns)
            self._last = (frame.sequence, mid_ns)
        return mid_ns + self._offsets[0][1]

    def _record(self, offset: int) -> None:
        q = self._offsets
        while q and q[-1][1] >= offset:
            q.pop()
        q.append((self._index, offset))
        while q[0][0] <= self._index - self._window:
            q.popleft()
        self._index += 1
