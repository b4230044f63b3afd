"""The live pipeline's health for one frame, as the outputs (rerun, the console) report it."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PipelineStatus:
    """The live pipeline's health for one processed frame."""

    fps: float  # processed frames per second, recent average
    latency_s: float  # frame arrival on the host → tracks ready
    frames: int  # frames processed so far
    dropped: int  # frames lost so far: device gaps + damaged + dropped by the pipeline queue
    tracks: int  # live tracks
    belt_speed_mps: float | None = None
