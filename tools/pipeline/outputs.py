"""The outputs a tracking run writes to besides files: the rerun sink and the conveyor line,
each as a pipeline `Output` (`tofcut track`, `live` and `soak` and the live bench use them)."""

from __future__ import annotations

from tofcut.tools.pipeline.conveyor_line import ConveyorLine
from tofcut.tools.pipeline.rerun_sink import NullSink, RerunSink
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import TrackedFrame


class RerunOutput:
    """The rerun sink as a pipeline output."""

    def __init__(self, sink: RerunSink | NullSink) -> None:
        self.sink = sink

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        self.sink.log(tracked, status)

    def close(self) -> None:
        self.sink.close()


class ConveyorOutput:
    """The conveyor line as the first output: every tracked frame goes to the reject rule
    right after tracking; closing it stops the link before rerun closes, so a reject fired
    at the end still reaches the recording."""

    def __init__(self, line: ConveyorLine) -> None:
        self.line = line

    def write(self, tracked: TrackedFrame, status: PipelineStatus) -> None:
        self.line.observe(tracked)

    def close(self) -> None:
        self.line.close()
