"""Where a tracked frame stands: the run's own index, the camera's clock and the host's.

Every output row carries these (JSONL tracks, rerun's timelines; MOT and MOTS rows carry
the index, as their formats' frame number). The run-wide index counts the frames tracked
in the run from 0, so it never goes back: the camera's sequence number and timestamp
restart at 0 when the camera reboots, and a run that reconnects goes on through that.
The host time is when the frame arrived on the host (`time.time_ns()`, ns since the Unix
epoch, UTC), the clock a PLC's or MES's log can be matched against.
"""

from __future__ import annotations

from dataclasses import dataclass

from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import TrackedFrame


def frame_index(status: PipelineStatus) -> int:
    """The run-wide index of the frame `status` reports on (it counts that frame too)."""
    return status.frames - 1


@dataclass(frozen=True)
class FrameStamp:
    """One tracked frame's place in the run, on the camera's clock and on the host's."""

    frame: int
    """Run-wide index from 0: frames tracked before this one in the run."""
    seq: int
    """The camera's sequence number (restarts at 0 when the camera does)."""
    device_time_us: int
    """The camera's timestamp, µs since it powered up (restarts with it)."""
    host_time_ns: int
    """When the frame arrived on the host: ns since the Unix epoch (UTC)."""

    @classmethod
    def of(cls, tracked: TrackedFrame, status: PipelineStatus) -> FrameStamp:
        frame = tracked.frame
        return cls(frame_index(status), frame.sequence, frame.device_time_us, frame.host_time_ns)

    def to_json(self) -> dict[str, int]:
        """The stamp's fields in `--tracks-out`'s order."""
        return {
            "frame": self.frame,
            "seq": self.seq,
            "device_time_us": self.device_time_us,
            "host_time_ns": self.host_time_ns,
        }
