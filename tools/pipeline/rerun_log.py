"""What a tracked run looks like in rerun: entity paths, archetypes, track colours, the layout.

World coordinates are the camera's (spec §7: x right, y down, z forward, metres), declared
as `ViewCoordinates.RDF`, so the 3D view is upright as the camera sees it, and the pinhole at
`world/camera` links the 2D and 3D views. Everything here runs on the sink's worker thread.
"""

from __future__ import annotations

import colorsys
import functools
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import rerun as rr
import rerun.blueprint as rrb
from rerun.components import (
    ClassIdBatch,
    HalfSize3DBatch,
    ImageBufferBatch,
    LineStrip3DBatch,
    Position3DBatch,
    ScalarBatch,
    TextBatch,
)

from tofcut.driver.calibration import Calibration
from tofcut.driver.frames import Frame
from tofcut.tools.pipeline.frame_stamp import frame_index
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import TrackedFrame

APP_ID = "tofcut"
WORLD = "world"
CAMERA = "world/camera"
DEPTH = "world/camera/depth"
AMPLITUDE = "world/camera/amplitude"
INTENSITY = "world/camera/intensity"
MASKS = "world/camera/tracks"
POINTS = "world/points"
BACKGROUND = "world/points/background"
BOXES = "world/tracks"
TRAILS = "world/trails"
BELT = "world/belt"
STATUS = "status"
TRACK_EVENTS = "events/tracks"
DEVICE_EVENTS = "events/device"
SEQUENCE = "sequence"
"""Timeline of the device's frame sequence numbers."""
FRAME = "frame"
"""Timeline of the run-wide frame index (`tofcut.tools.pipeline.frame_stamp`): from 0, never
back."""
HOST_TIME = "host_time"
"""Timeline of when each frame arrived on the host (UTC, the clock of `host_time_ns`)."""
DEVICE_TIME = "device_time"
"""Timeline of the device's timestamps (time since the camera powered up)."""
MAX_DEVICE_TIME_US = (2**63 - 1) // 1000
"""Rerun keeps durations as signed 64-bit nanoseconds: a device timestamp (a u64 of µs on the
wire, spec §6) above this (about 292,000 years) cannot be put on the `device_time` timeline.
Such a frame is logged without it (on its sequence and log time) and counted."""


def device_time_ok(frame_row: FrameRow) -> bool:
    """Whether the row's device timestamp fits rerun's `device_time` timeline."""
    return 0 <= frame_row.tracked.frame.device_time_us <= MAX_DEVICE_TIME_US


LOG_TIME = "log_time"
"""Rerun's own timeline of wall-clock time: a frame's rows are at the time the frame was
handed to the output, what `rr.log` logs (events, contexts) at the time it is logged."""

SERIES = {
    "fps": "frames per second",
    "latency_ms": "latency (ms)",
    "dropped_frames": "frames lost",
    "tracks": "live tracks",
    "belt_speed_mps": "belt speed (m/s)",
    "rerun_dropped": "frames rerun output dropped",
}
"""Time series under `status/`: entity name → what it shows."""

TRAIL_FRAMES = 30
"""A trail shows where a track's centroid was over this many frames."""
STATUS_EVERY = 5
"""The pipeline's health is logged every this many frames (10 a second at 50 fps), and at
once when the rerun output itself drops frames: enough for its plots."""
BACKGROUND_STRIDE = 2
"""Background points are thinned to every this-many-th pixel in u and in v."""
BACKGROUND_RGB = (96, 96, 96)
"""The background's points: dim grey (one colour, logged once)."""
IMAGE_FULL_SCALE = {"amplitude": 8191.5, "intensity": 16383.0}
"""Counts shown as white: amplitude is at most half, intensity at most all of a 14-bit tap."""
BELT_ARROW_M = 0.3
BELT_RGB = (40, 40, 40)
EYE_POSITION = (0.5, -0.9, -0.3)
EYE_TARGET = (0.0, 0.1, 1.25)
"""The 3D view's default eye: above and behind the camera, off to one side (camera frame)."""

POINT_POSITIONS = rr.Points3D.descriptor_positions()
POINT_CLASSES = rr.Points3D.descriptor_class_ids()
BOX_CENTERS = rr.Boxes3D.descriptor_centers()
BOX_HALF_SIZES = rr.Boxes3D.descriptor_half_sizes()
BOX_CLASSES = rr.Boxes3D.descriptor_class_ids()
BOX_LABELS = rr.Boxes3D.descriptor_labels()
TRAIL_STRIPS = rr.LineStrips3D.descriptor_strips()
TRAIL_CLASSES = rr.LineStrips3D.descriptor_class_ids()
SCALARS = rr.Scalars.descriptor_scalars()
"""The archetypes' own component descriptors, for rows built straight from arrays."""


def track_color(track_id: int) -> tuple[int, int, int]:
    """A bright colour that depends on the id alone (golden-ratio hues), so it never changes."""
    hue = (0.1 + track_id * 0.618033988749895) % 1.0
    r, g, b = colorsys.hsv_to_rgb(hue, 0.8, 1.0)
    return (round(255 * r), round(255 * g), round(255 * b))


def track_label(track_id: int) -> str:
    return f"track {track_id}"


def annotation_context(track_ids: Iterable[int]) -> rr.AnnotationContext:
    """Class 0 is the see-through background; each track id gets its label and colour."""
    classes: list[rr.AnnotationInfo] = [rr.AnnotationInfo(0, "background", (0, 0, 0, 0))]
    classes += [
        rr.AnnotationInfo(i, track_label(i), track_color(i)) for i in sorted(set(track_ids))
    ]
    return rr.AnnotationContext(classes)


def under(root: str, path: str) -> str:
    """An entity path inside a camera's tree (`cameras/SERIAL`); `root` "" is the top."""
    return f"{root}/{path}" if root else path


def camera_layout(root: str = "", name: str | None = None) -> rrb.Container:
    """One camera's views: images with the masks and the 3D scene on top; health and
    events below."""
    at = functools.partial(under, root)
    camera, depth, amplitude, intensity, masks = (
        at(p) for p in (CAMERA, DEPTH, AMPLITUDE, INTENSITY, MASKS)
    )
    status = at(STATUS)
    images = rrb.Vertical(
        rrb.Spatial2DView(name="depth and tracks", origin=camera, contents=[depth, masks]),
        rrb.Horizontal(
            rrb.Spatial2DView(
                name="amplitude and tracks", origin=camera, contents=[amplitude, masks]
            ),
            rrb.Spatial2DView(name="intensity", origin=camera, contents=[intensity]),
        ),
        row_shares=[3, 2],
    )
    scene = rrb.Spatial3DView(
        name="3D",
        origin=at(WORLD),
        # The point cloud is the driver's exact one; the depth image's back-projection would
        # repeat it through rerun's distortion-free pinhole, and grey images would hide the
        # masks in the camera's frustum.
        contents=[f"+ {at(WORLD)}/**", f"- {depth}", f"- {amplitude}", f"- {intensity}"],
        eye_controls=rrb.EyeControls3D(
            position=EYE_POSITION, look_target=EYE_TARGET, eye_up=(0.0, -1.0, 0.0)
        ),
    )
    no_legend = rrb.PlotLegend(visible=False)
    health = rrb.Horizontal(
        rrb.TimeSeriesView(name="frames per second", origin=f"{status}/fps", plot_legend=no_legend),
        rrb.TimeSeriesView(
            name="latency (ms)", origin=f"{status}/latency_ms", plot_legend=no_legend
        ),
        rrb.TimeSeriesView(
            name="tracks and lost frames",
            origin=status,
            contents=[f"{status}/tracks", f"{status}/dropped_frames", f"{status}/rerun_dropped"],
        ),
        rrb.TimeSeriesView(
            name="belt speed (m/s)", origin=f"{status}/belt_speed_mps", plot_legend=no_legend
        ),
        rrb.TextLogView(name="events", origin=at("events")),
        column_shares=[1, 1, 1, 1, 2],
    )
    return rrb.Vertical(
        rrb.Horizontal(images, scene, column_shares=[2, 3]), health, row_shares=[3, 1], name=name
    )


def default_blueprint(roots: Sequence[str] = ("",)) -> rrb.Blueprint:
    """The layout of one camera; of several (their trees' `roots`), a tab each."""
    if len(roots) == 1:
        top: rrb.Container = camera_layout(roots[0])
    else:
        top = rrb.Tabs(*(camera_layout(r, r.rpartition("/")[2]) for r in roots))
    return rrb.Blueprint(
        top, rrb.TimePanel(timeline=SEQUENCE, state="collapsed"), collapse_panels=True
    )


def gray8(values: npt.ArrayLike, full_scale: float) -> npt.NDArray[np.uint8]:
    """Counts as 8-bit grey on a fixed square-root scale: comparable across frames and runs.

    255·√(v/full) as √(v·255²/full), in place in float32: a third less of the worker's time.
    `values` may be a list of frames' counts, converted in one go.
    """
    scaled = np.array(values, np.float32)
    np.multiply(scaled, np.float32(255.0**2 / full_scale), out=scaled)
    np.clip(scaled, 0.0, 255.0**2, out=scaled)
    np.sqrt(scaled, out=scaled)
    return scaled.astype(np.uint8)


def depth_mm(f: Frame) -> npt.NDArray[np.uint16]:
    """z of each valid point in millimetres, 0 where invalid (rerun's "no depth").

    Rerun's depth images hold z, the distance along the optical axis; the camera's range is
    along the pixel's ray (spec §7), so z comes from the frame's points.
    """
    z = np.where(f.valid, f.xyz[..., 2], 0.0)
    return np.clip(np.rint(z * 1000.0), 0, 65535).astype(np.uint16)


def cloud(
    tracked: TrackedFrame,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint16], npt.NDArray[np.float32]]:
    """Each track's points and, for each point, its track's id (its class); and the
    background's points, thinned."""
    f = tracked.frame
    s = BACKGROUND_STRIDE
    keep = f.valid[::s, ::s] & (tracked.labels[::s, ::s] == 0)
    pixels = thinned_pixels(tracked.labels.shape)[keep]
    background = np.take(f.xyz.reshape(-1, 3), pixels, axis=0).astype(np.float32)
    tracks = [t for t in tracked.tracks if len(t.points)]
    if not tracks:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.uint16), background
    positions = np.concatenate([t.points.astype(np.float32, copy=False) for t in tracks])
    ids = np.repeat(np.array([t.id for t in tracks], np.uint16), [len(t.points) for t in tracks])
    return positions, ids, background


@functools.cache
def thinned_pixels(shape: tuple[int, int]) -> npt.NDArray[np.intp]:
    """Flat indices of every `BACKGROUND_STRIDE`-th pixel in u and v: taking points by index
    from the whole (H·W, 3) array is faster than boolean indexing of a strided view."""
    s = BACKGROUND_STRIDE
    return np.arange(shape[0] * shape[1]).reshape(shape)[::s, ::s]


@dataclass(frozen=True, eq=False)
class FrameRow:
    """One tracked frame for the recording, with the pipeline's health as it was then."""

    tracked: TrackedFrame
    status: PipelineStatus
    log_time_ns: int
    """Wall-clock time (ns since the Unix epoch) the frame was handed to the output: its
    `log_time`."""


class ImageColumn:
    """One image entity whose pixels go in columns: the archetype's other fields (format,
    meter) are logged once, static, for the camera's size, as rerun advises for columns."""

    def __init__(self, rec: rr.RecordingStream, entity: str, template: rr.AsComponents) -> None:
        fields = []
        for batch in template.as_component_batches():
            descriptor = batch.component_descriptor()
            if descriptor.component.endswith(":buffer"):
                self.buffer = descriptor
            else:
                fields.append(batch)
        self.entity = entity
        self.fields = fields
        self.log_static(rec)

    def log_static(self, rec: rr.RecordingStream) -> None:
        """The fields other than the pixels, static (again at the start of each file)."""
        rec.log(self.entity, self.fields, static=True)

    def column(self, pixels: npt.NDArray[Any]) -> rr.ComponentColumn:
        """(frames, H, W) pixels as one buffer per row."""
        data = np.ascontiguousarray(pixels).reshape(len(pixels), -1).view(np.uint8)
        return rr.DescribedComponentBatch(ImageBufferBatch(data), self.buffer).partition()


class FrameLogger:
    """Logs tracked frames, pipeline health and events to one recording stream.

    Frames go in batches, one `send_columns` per entity for the lot: rerun's per-call cost
    (in Python, in its batcher, in waking its threads) is paid once per batch, not per frame.
    The rows are the archetypes' own components under their own descriptors.
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        calibration: Calibration,
        belt_direction: npt.ArrayLike | None = None,
        root: str = "",
    ) -> None:
        """`root`: the camera's tree (`cameras/SERIAL`) in a recording of several; "" (one
        camera) logs at the top."""
        self.rec = rec
        self.calibration = calibration
        self._at = functools.partial(under, root)
        self.belt_direction = (
            None if belt_direction is None else np.asarray(belt_direction, np.float64)
        )
        self._trails: dict[int, deque[npt.NDArray[np.float32]]] = {}
        self._context_ids: frozenset[int] | None = None
        self._belt_logged = False
        self._belt_arrow: rr.Arrows3D | None = None
        self._dropped_logged = 0
        self.odd_device_times = 0
        """Frames logged without a device time: theirs is past `MAX_DEVICE_TIME_US`."""
        self._log_static()
        shape = (calibration.height, calibration.width)
        self._depth = ImageColumn(
            rec, self._at(DEPTH), rr.DepthImage(np.zeros(shape, np.uint16), meter=1e3)
        )
        self._amplitude = ImageColumn(rec, self._at(AMPLITUDE), rr.Image(np.zeros(shape, np.uint8)))
        self._intensity = ImageColumn(rec, self._at(INTENSITY), rr.Image(np.zeros(shape, np.uint8)))
        self._masks = ImageColumn(
            rec, self._at(MASKS), rr.SegmentationImage(np.zeros(shape, np.uint16))
        )

    def restart(self) -> None:
        """Log again what a new file of the recording needs before its first frame (the
        sink's next segment starts empty but for the store info and blueprint): the static
        data, the belt's arrow; the annotation context goes with the next frame."""
        self._log_static()
        for column in (self._depth, self._amplitude, self._intensity, self._masks):
            column.log_static(self.rec)
        if self._belt_arrow is not None:
            self.rec.log(self._at(BELT), self._belt_arrow, static=True)
        self._context_ids = None

    def _log_static(self) -> None:
        c = self.calibration
        self.rec.log(self._at(WORLD), rr.ViewCoordinates.RDF, static=True)
        self.rec.log(
            self._at(CAMERA),
            rr.Pinhole(
                focal_length=[c.fx, c.fy],
                principal_point=[c.cx, c.cy],
                resolution=[c.width, c.height],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.4,
            ),
            static=True,
        )
        for name, title in SERIES.items():
            self.rec.log(self._at(f"{STATUS}/{name}"), rr.SeriesLines(names=title), static=True)
        # One colour for every background point: rerun applies a single value to them all.
        self.rec.log(
            self._at(BACKGROUND), rr.Points3D.from_fields(colors=[BACKGROUND_RGB]), static=True
        )

    def write_frames(self, rows: Sequence[FrameRow], sink_dropped: int) -> None:
        """Everything about these frames (in order), each at its sequence number, device time
        and log time; `sink_dropped` is what the output had dropped before them."""
        if not rows:
            return
        shape = (self.calibration.height, self.calibration.width)
        for row in rows:
            if row.tracked.frame.shape != shape or row.tracked.labels.shape != shape:
                raise ValueError(
                    f"frame {row.tracked.sequence} is {row.tracked.frame.shape[::-1]} pixels; "
                    f"the recording's images are {shape[::-1]} (the calibration's)"
                )
        ok = [device_time_ok(row) for row in rows]
        if not all(ok):  # one odd timestamp must not end the run: those frames go without it
            self.odd_device_times += ok.count(False)
            start = 0
            for i in range(1, len(rows) + 1):
                if i == len(rows) or ok[i] != ok[start]:
                    self._write_run(rows[start:i], sink_dropped, device_time=ok[start])
                    start = i
            return
        self._write_run(rows, sink_dropped, device_time=True)

    def _write_run(self, rows: Sequence[FrameRow], sink_dropped: int, device_time: bool) -> None:
        """`write_frames` for frames that all have, or all lack, a usable device time."""
        for row in rows:
            self._log_frame_events(row, device_time)
        frames = [row.tracked.frame for row in rows]
        times = time_columns(rows, device_time)
        send = self.rec.send_columns
        # Each frame's depth and cloud one after the other: its points are read from memory once.
        depths = []
        clouds = []
        for row in rows:
            depths.append(depth_mm(row.tracked.frame))
            clouds.append(cloud(row.tracked))
        send(self._at(DEPTH), times, [self._depth.column(np.stack(depths))])
        amplitude = gray8([f.amplitude for f in frames], IMAGE_FULL_SCALE["amplitude"])
        send(self._at(AMPLITUDE), times, [self._amplitude.column(amplitude)])
        intensity = gray8([f.intensity for f in frames], IMAGE_FULL_SCALE["intensity"])
        send(self._at(INTENSITY), times, [self._intensity.column(intensity)])
        labels = np.array([row.tracked.labels for row in rows], np.uint16)
        send(self._at(MASKS), times, [self._masks.column(labels)])
        lengths = [len(positions) for positions, _, _ in clouds]
        send(
            self._at(POINTS),
            times,
            [
                rr.DescribedComponentBatch(
                    Position3DBatch(np.concatenate([p for p, _, _ in clouds])), POINT_POSITIONS
                ).partition(lengths),
                rr.DescribedComponentBatch(
                    ClassIdBatch(np.concatenate([c for _, c, _ in clouds])), POINT_CLASSES
                ).partition(lengths),
            ],
        )
        background = [b for _, _, b in clouds]
        send(
            self._at(BACKGROUND),
            times,
            [
                rr.DescribedComponentBatch(
                    Position3DBatch(np.concatenate(background)), POINT_POSITIONS
                ).partition([len(b) for b in background])
            ],
        )
        self._send_tracks(rows, times)
        self._send_status(rows, sink_dropped, device_time)

    def write_event(self, text: str, level: str) -> None:
        """A device or pipeline event, at the time of the last frame written."""
        self.rec.log(self._at(DEVICE_EVENTS), rr.TextLog(text, level=level))

    def sync(self) -> None:
        """Wait until everything logged so far has reached the sinks (a file: written)."""
        self.rec.flush()

    def close(self, timeout_s: float | None, keep_serving: bool = False) -> None:
        """Flush, then close the sinks: a file is complete (rerun writes its footer).

        `keep_serving` leaves a gRPC server up for viewers that connect after the run (it
        stops when the recording stream is collected, at the latest at exit).
        """
        try:
            if timeout_s is None:
                self.rec.flush()
            else:
                self.rec.flush(timeout_sec=timeout_s)
        finally:
            if not keep_serving:
                self.rec.disconnect()

    def _log_frame_events(self, row: FrameRow, device_time: bool = True) -> None:
        """What happens at one frame rather than in every frame: the annotation context when
        the ids change, births and ends, the belt's arrow; at the frame's sequence number,
        run-wide index, host time and device time (their log time is rerun's own: when they
        are logged)."""
        rec = self.rec
        tracked = row.tracked
        rec.set_time(SEQUENCE, sequence=tracked.sequence)
        rec.set_time(FRAME, sequence=frame_index(row.status))
        rec.set_time(HOST_TIME, timestamp=np.datetime64(tracked.frame.host_time_ns, "ns"))
        if device_time:
            rec.set_time(DEVICE_TIME, duration=np.timedelta64(tracked.frame.device_time_us, "us"))
        else:
            rec.disable_timeline(DEVICE_TIME)
        ids = frozenset(t.id for t in tracked.tracks) | frozenset(tracked.born)
        if ids != self._context_ids:  # ids never repeat; every id in the masks is a track's
            rec.log(self._at(WORLD), annotation_context(ids))
            self._context_ids = ids
        for i in tracked.born:
            rec.log(self._at(TRACK_EVENTS), rr.TextLog(f"{track_label(i)} born", level="INFO"))
        for i in tracked.ended:
            rec.log(self._at(TRACK_EVENTS), rr.TextLog(f"{track_label(i)} ended", level="INFO"))
        if self.belt_direction is not None and not self._belt_logged:
            self._log_belt(tracked)

    def _send_tracks(self, rows: Sequence[FrameRow], times: list[rr.TimeColumn]) -> None:
        """Each frame's boxes and trails (an empty row clears them)."""
        tracks = [t for row in rows for t in row.tracked.tracks]
        counts = [len(row.tracked.tracks) for row in rows]
        strips: list[npt.NDArray[np.float32]] = []
        strip_ids: list[int] = []
        strip_counts: list[int] = []
        for row in rows:
            before = len(strips)
            for t in self._advance_trails(row.tracked):
                if len(self._trails[t]) > 1:
                    strips.append(np.array(self._trails[t]))
                    strip_ids.append(t)
            strip_counts.append(len(strips) - before)
        mins = np.array([t.box_min for t in tracks], np.float64).reshape(-1, 3)
        maxs = np.array([t.box_max for t in tracks], np.float64).reshape(-1, 3)
        labels = [
            track_label(t.id) if t.visible else f"{track_label(t.id)} (hidden)" for t in tracks
        ]
        batches = [
            (Position3DBatch((mins + maxs) / 2), BOX_CENTERS),
            (HalfSize3DBatch((maxs - mins) / 2), BOX_HALF_SIZES),
            (ClassIdBatch(np.array([t.id for t in tracks], np.uint16)), BOX_CLASSES),
            (TextBatch(labels), BOX_LABELS),
        ]
        self.rec.send_columns(
            self._at(BOXES),
            times,
            [rr.DescribedComponentBatch(*b).partition(counts) for b in batches],
        )
        self.rec.send_columns(
            self._at(TRAILS),
            times,
            [
                rr.DescribedComponentBatch(LineStrip3DBatch(strips), TRAIL_STRIPS).partition(
                    strip_counts
                ),
                rr.DescribedComponentBatch(
                    ClassIdBatch(np.array(strip_ids, np.uint16)), TRAIL_CLASSES
                ).partition(strip_counts),
            ],
        )

    def _advance_trails(self, tracked: TrackedFrame) -> list[int]:
        """Add each live track's centroid to its trail, forget ended tracks; the live ids."""
        for i in tracked.ended:
            self._trails.pop(i, None)
        live = [t.id for t in tracked.tracks]
        for i in self._trails.keys() - set(live):
            del self._trails[i]
        for t in tracked.tracks:
            self._trails.setdefault(t.id, deque(maxlen=TRAIL_FRAMES)).append(
                np.asarray(t.centroid, np.float32)
            )
        return live

    def _log_belt(self, tracked: TrackedFrame) -> None:
        """The belt's direction, drawn once from the middle of the first frame's points."""
        assert self.belt_direction is not None
        f = tracked.frame
        origin = np.median(f.xyz[f.valid], axis=0) if f.valid.any() else np.zeros(3)
        direction = self.belt_direction / np.linalg.norm(self.belt_direction)
        self._belt_arrow = rr.Arrows3D(
            origins=[origin],
            vectors=[direction * BELT_ARROW_M],
            labels=["belt"],
            colors=[BELT_RGB],
            radii=[0.006],
        )
        self.rec.log(self._at(BELT), self._belt_arrow, static=True)
        self._belt_logged = True

    def _send_status(
        self, rows: Sequence[FrameRow], sink_dropped: int, device_time: bool = True
    ) -> None:
        """The health at every STATUS_EVERY-th frame, and at the first frame that knows of
        new drops by the output itself."""
        picked = [
            row
            for i, row in enumerate(rows)
            if row.tracked.sequence % STATUS_EVERY == 0
            or (i == 0 and sink_dropped != self._dropped_logged)
        ]
        self._dropped_logged = sink_dropped
        for name in SERIES:
            at: list[FrameRow] = []
            values: list[float] = []
            for row in picked:
                value = status_value(row.status, name, sink_dropped)
                if value is not None:
                    at.append(row)
                    values.append(value)
            if at:
                self.rec.send_columns(
                    self._at(f"{STATUS}/{name}"),
                    time_columns(at, device_time),
                    [rr.DescribedComponentBatch(ScalarBatch(values), SCALARS).partition()],
                )


def time_columns(rows: Sequence[FrameRow], device_time: bool = True) -> list[rr.TimeColumn]:
    """The frames' sequence numbers, device times (unless not `device_time`), run-wide
    indices, host times and log times, as rerun's index columns."""
    frames = [row.tracked.frame for row in rows]
    columns = [
        rr.TimeColumn(SEQUENCE, sequence=[f.sequence for f in frames]),
        rr.TimeColumn(FRAME, sequence=[frame_index(row.status) for row in rows]),
        rr.TimeColumn(HOST_TIME, timestamp=np.array([f.host_time_ns for f in frames], "M8[ns]")),
        rr.TimeColumn(LOG_TIME, timestamp=np.array([row.log_time_ns for row in rows], "M8[ns]")),
    ]
    if device_time:
        us = np.array([f.device_time_us for f in frames], "m8[us]")
        columns.insert(1, rr.TimeColumn(DEVICE_TIME, duration=us))
    return columns


def status_value(status: PipelineStatus, name: str, sink_dropped: int) -> float | None:
    """One series of `SERIES` at one frame; None where it is not known (no belt speed)."""
    values = {
        "fps": status.fps,
        "latency_ms": status.latency_s * 1000.0,
        "dropped_frames": status.dropped,
        "tracks": status.tracks,
        "belt_speed_mps": status.belt_speed_mps,
        "rerun_dropped": sink_dropped,
    }
    value = values[name]
    return None if value is None else float(value)
