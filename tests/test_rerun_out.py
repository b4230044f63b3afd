"""Rerun output: recordings of an emulated run, read back with rerun's own tools; the queue."""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import itertools
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb
import rerun_cli
from rerun.chunk import RrdReader

from tofcut.driver import Camera
from tofcut.driver.calibration import Calibration
from tofcut.driver.config import CameraConfig, frame_period_for
from tofcut.sim import EmulatedBackend, EmulatedCamera, FrameTruth, open_scene
from tofcut.tools.bench import rerun_memory
from tofcut.tools.pipeline import rerun_log
from tofcut.tools.pipeline.rerun_log import FrameLogger, track_color
from tofcut.tools.pipeline.rerun_sink import RerunOutputError, RerunSink, measure_logging_cost
from tofcut.tools.pipeline.rerun_target import (
    RerunTarget,
    add_rerun_options,
    default_recording_path,
    target_from_args,
)
from tofcut.tools.pipeline.status import PipelineStatus
from tofcut.tracker.tracks import Track, TrackedFrame

HERE = Path(__file__).resolve().parent
RERUN_CLI = Path(rerun_cli.__file__).with_name("rerun")
"""The `rerun` command that comes with rerun-sdk."""
FRAMES = 24
FPS = 5.0
"""A slow frame rate, so the belt carries boxes in and out of view within a few frames."""

Run = list[tuple[TrackedFrame, PipelineStatus]]


# --- an emulated run, tracked by its ground truth -------------------------------------------


def truth_tracks(
    frame_xyz: np.ndarray,
    valid: np.ndarray,
    truth: FrameTruth,
    dt_s: float,
    previous: dict[int, np.ndarray],
) -> list[Track]:
    """The tracks a perfect tracker would report: one per object in view, from the truth."""
    tracks = []
    for obj in truth.objects:
        mask = truth.labels == obj.id
        if not mask.any():
            continue
        rows, cols = np.nonzero(mask)
        before = previous.get(obj.id)
        velocity = np.zeros(3) if before is None else (obj.centroid - before) / dt_s
        tracks.append(
            Track(
                id=obj.id,
                centroid=obj.centroid,
                velocity=velocity,
                box_min=obj.extent_min,
                box_max=obj.extent_max,
                bbox=(int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1),
                pixels=int(mask.sum()),
                points=frame_xyz[mask & valid].astype(np.float32),
            )
        )
    return tracks


def emulated_run(frames: int = FRAMES, fps: float = FPS) -> tuple[Calibration, np.ndarray, Run]:
    """The conveyor through the emulated camera and the real driver, tracked by ground truth."""
    source = open_scene("conveyor", seed=0)
    assert source.belt is not None
    emulator = EmulatedCamera(source, realtime=False, registers=source.settings.registers)
    run: Run = []
    previous: dict[int, np.ndarray] = {}
    with Camera.open(backend=EmulatedBackend([emulator])) as cam:
        c = cam.config
        cam.configure(
            CameraConfig(c.mod_freq_code, c.integration, frame_period_for(fps), c.trigger_mode)
        )
        for frame in cam.frames(count=frames):
            truth = emulator.truth(frame.sequence)
            assert isinstance(truth, FrameTruth)
            tracks = truth_tracks(frame.xyz, frame.valid, truth, 1.0 / fps, previous)
            ids = {t.id for t in tracks}
            tracked = TrackedFrame(
                frame=frame,
                labels=truth.labels.astype(np.uint16),
                tracks=tuple(tracks),
                born=tuple(sorted(ids - previous.keys())),
                ended=tuple(sorted(previous.keys() - ids)),
            )
            previous = {t.id: t.centroid for t in tracks}
            status = PipelineStatus(
                fps=fps,
                latency_s=0.012 + 0.001 * (frame.sequence % 5),
                frames=len(run) + 1,
                dropped=cam.stats.lost,
                tracks=len(tracks),
                belt_speed_mps=source.belt.speed_mps,
            )
            run.append((tracked, status))
        calibration = cam.calibration
    return calibration, source.belt.geometry.direction, run


@pytest.fixture(scope="module")
def run() -> tuple[Calibration, np.ndarray, Run]:
    return emulated_run()


def write_recording(path: Path, calibration: Calibration, belt: np.ndarray, run: Run) -> RerunSink:
    sink = RerunSink(calibration, RerunTarget.save(path), belt, name="test run")
    sink.event("camera stalled a request", "WARN")
    for tracked, status in run:
        sink.log(tracked, status)
    sink.event("camera disconnected", "ERROR")
    sink.close()
    return sink


@pytest.fixture(scope="module")
def recording(tmp_path_factory, run) -> tuple[Path, RerunSink]:
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    sink = write_recording(path, *run)
    return path, sink


# --- reading a recording back with rerun's own reader ---------------------------------------


def reader(path: Path) -> RrdReader:
    with warnings.catch_warnings():  # a file without a footer is read as a "legacy format"
        warnings.filterwarnings("error", "RRD file has no footer")
        return RrdReader(path)


def chunks(path: Path) -> list[rr.chunk.Chunk]:
    return list(reader(path).stream())


def rerun_cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, RERUN_ANALYTICS="0")
    return subprocess.run(
        [str(RERUN_CLI), *args], capture_output=True, text=True, check=False, env=env
    )


def rrd_verify(*paths: Path) -> subprocess.CompletedProcess[str]:
    """Rerun's own check that files load and are interpreted correctly, with its defaults
    (which include a well-formed footer)."""
    return rerun_cli("rrd", "verify", *map(str, paths))


def all_rows(
    path: Path,
    entity: str,
    component: str,
    timeline: str = "sequence",
) -> list[tuple[object, object]]:
    """(time, value) of every temporal row of one component of one entity, on one timeline.

    Each value is the row's list of instances; the time is None where the row is not on the
    timeline (logged before the first frame).
    """
    out = []
    for ch in chunks(path):
        if ch.entity_path != f"/{entity}" or ch.is_static:
            continue
        batch = ch.to_record_batch()
        names = [n for n in batch.schema.names if n.endswith(component)]
        if not names:
            continue
        values = batch.column(names[0]).to_pylist()
        has_time = timeline in batch.schema.names
        times = batch.column(timeline).to_pylist() if has_time else [None] * len(values)
        out += [(t, v) for t, v in zip(times, values, strict=True) if v is not None]
    return out


def static_value(path: Path, entity: str, component: str) -> object:
    """The static value of one component of one entity (the last one logged)."""
    values = []
    for ch in chunks(path):
        if ch.entity_path == f"/{entity}" and ch.is_static:
            batch = ch.to_record_batch()
            names = [n for n in batch.schema.names if n.endswith(component)]
            values += [v for name in names for v in batch.column(name).to_pylist() if v is not None]
    assert values, f"no static {component} on {entity}"
    return values[-1]


def rows_on(path: Path, entity: str, component: str, timeline: str = "sequence") -> dict:
    """{time: value} of one component of one entity, on one timeline."""
    return dict(all_rows(path, entity, component, timeline))


# --- the recording ----------------------------------------------------------------------------


def test_rerun_verifies_the_recording(recording):
    path, _ = recording
    result = rrd_verify(path)
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_file_has_rerun_s_footer_and_reads_as_current_not_legacy(recording):
    path, _ = recording
    assert len(RrdReader(path).recordings()) == 1  # no "legacy format" warning (see `reader`)
    assert "footer" not in rrd_verify(path).stdout + rrd_verify(path).stderr


# --- segments: a long run goes on in new files, each closed with its footer -------------------


def run_cli(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """`tofcut ARGS...` in a process of its own, as a user runs it."""
    code = "import sys; from tofcut.tools.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [sys.executable, "-c", code, *argv],
        capture_output=True, text=True, timeout=600, cwd=cwd, check=False,
    )  # fmt: skip


def segment_frames(paths: list[Path]) -> list[int]:
    return [s for p in paths for s in frame_sequences(p)]


def test_a_run_on_the_command_line_writes_a_file_rerun_verifies_and_reads(tmp_path):
    result = run_cli("track", "emulator:conveyor", "--fast", "--frames", "12", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    (path,) = tmp_path.glob("*.rrd")  # the default: one dated file in the working directory
    assert path.name.startswith("tofcut-")
    assert f"12 of 12 frames written to {path}" in result.stdout
    checked = rrd_verify(path)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    sequences = frame_sequences(path)
    assert sequences == list(range(sequences[0], sequences[0] + 12))
    assert len(reader(path).blueprints()) == 1


def test_a_run_past_the_segment_size_writes_several_files_each_verified(tmp_path):
    out = tmp_path / "run.rrd"
    result = run_cli(
        "track", "emulator:conveyor", "--fast", "--frames", "60", "--save", str(out),
        "--segment-mb", "2",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    paths = sorted(tmp_path.glob("*.rrd"))
    assert len(paths) >= 3
    assert paths == [tmp_path / f"run-{n:04d}.rrd" for n in range(1, len(paths) + 1)]
    assert not out.exists()  # the first file was renamed RUN-0001.rrd
    assert f"60 of 60 frames written to {len(paths)} files" in result.stdout
    assert "rerun " + str(tmp_path / "run-*.rrd") in result.stdout
    checked = rrd_verify(*paths)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    # every frame once, in order, across the files; each file stands alone: one recording
    # (the same for all), its blueprint, and the static data an image needs to be shown
    frames = segment_frames(paths)
    assert frames == sorted(set(frames))
    assert len(frames) == 60
    ids = set()
    for path in paths:
        assert frame_sequences(path)
        (recording,) = reader(path).recordings()
        ids.add(recording.recording_id)
        assert len(reader(path).blueprints()) == 1
        assert static_value(path, "world/camera/depth", "DepthImage:meter") == [1000.0]
        static_value(path, "world/camera", "Pinhole:image_from_camera")
        static_value(path, "world/belt", "Arrows3D:vectors")
        contexts = rows_on(path, "world", "AnnotationContext:context")
        assert min(contexts) == frame_sequences(path)[0]  # the track names from its first frame
    assert len(ids) == 1


def test_a_segment_is_also_closed_after_its_time(tmp_path, run, monkeypatch):
    calibration, belt, frames = run
    monkeypatch.setattr("tofcut.tools.pipeline.rerun_sink.SYNC_FRAMES", 4)
    target = RerunTarget.save(tmp_path / "t.rrd", segment_bytes=0, segment_s=1e-6)
    sink = RerunSink(calibration, target, belt, name="timed")
    for f in frames[:12]:
        sink.log(*f)
    sink.close()
    # the third file is due after its fourth frame, but no frame came for a fourth file
    assert sink.files == [tmp_path / f"t-{n:04d}.rrd" for n in range(1, 4)]
    assert rrd_verify(*sink.files).returncode == 0
    assert [len(frame_sequences(p)) for p in sink.files] == [4, 4, 4]
    assert segment_frames(sink.files) == [t.sequence for t, _ in frames[:12]]
    assert "written to 3 files" in sink.summary()
    # without a bound, one file however long
    single = RerunTarget.save(tmp_path / "one.rrd", segment_bytes=0, segment_s=0)
    with RerunSink(calibration, single, belt) as sink:
        for f in frames:
            sink.log(*f)
    assert sink.files == [tmp_path / "one.rrd"]


KILL_SCRIPT = """
import signal, sys, time
sys.path.insert(0, sys.argv[2])
from test_rerun_out import emulated_run
from tofcut.tools.pipeline.rerun_sink import RerunSink
from tofcut.tools.pipeline.rerun_target import RerunTarget
calibration, belt, run = emulated_run(frames=4)
sink = RerunSink(calibration, RerunTarget.save(sys.argv[1], segment_bytes=1_000_000), belt)
n = 0
while True:
    sink.log(*run[n % len(run)])
    n += 1
    if len(sink.files) == 3:
        print("three files", flush=True)
"""


def test_sigkill_costs_only_the_last_segment_s_footer_and_rerun_recovers_it(tmp_path):
    path = tmp_path / "killed.rrd"
    proc = subprocess.Popen(
        [sys.executable, "-c", KILL_SCRIPT, str(path), str(HERE)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "three files", proc.communicate()
    proc.kill()  # SIGKILL while it writes: nothing gets to close the file
    proc.communicate(timeout=60)
    *closed, last = sorted(tmp_path.glob("killed-*.rrd"))
    assert len(closed) >= 2
    checked = rrd_verify(*closed)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert all(frame_sequences(p) for p in closed)
    # The last file has no footer and may end inside a message; rerun's optimize keeps every
    # whole message and writes a file with a footer.
    fixed = tmp_path / "fixed.rrd"
    repaired = rerun_cli("rrd", "optimize", str(last), "-o", str(fixed))
    assert repaired.returncode == 0, repaired.stderr
    checked = rrd_verify(fixed)
    assert checked.returncode == 0, checked.stdout + checked.stderr


def test_the_recording_holds_every_entity_and_a_blueprint(recording):
    path, _ = recording
    entities = {ch.entity_path for ch in chunks(path)}
    expected = {
        "/world",
        "/world/camera",
        "/world/camera/depth",
        "/world/camera/amplitude",
        "/world/camera/intensity",
        "/world/camera/tracks",
        "/world/points",
        "/world/points/background",
        "/world/tracks",
        "/world/trails",
        "/world/belt",
        "/events/tracks",
        "/events/device",
    } | {f"/status/{name}" for name in rerun_log.SERIES}
    assert expected <= entities
    assert len(reader(path).blueprints()) == 1


def test_every_frame_is_on_both_timelines(recording, run):
    path, sink = recording
    _, _, frames = run
    depth = rows_on(path, "world/camera/depth", "DepthImage:buffer")
    assert sorted(depth) == [t.sequence for t, _ in frames]
    assert sink.stats.written == len(frames)
    assert sink.dropped == 0
    device = rows_on(path, "world/camera/depth", "DepthImage:buffer", timeline="device_time")
    us = dt.timedelta(microseconds=1)
    assert sorted(device) == [t.frame.device_time_us * us for t, _ in frames]
    # and on log_time, at the time each was handed to the sink, in order
    logged = all_rows(path, "world/camera/depth", "DepthImage:buffer", timeline="log_time")
    stamps = [t for t, _ in logged]
    assert len(stamps) == len(frames)
    assert None not in stamps
    assert stamps == sorted(stamps)


def test_every_frame_is_on_the_run_s_index_and_the_host_s_clock(recording, run):
    path, _ = recording
    _, _, frames = run
    # the run-wide index (never back, whatever the camera's sequence does) and the host time
    index = rows_on(path, "world/camera/depth", "DepthImage:buffer", timeline="frame")
    assert sorted(index) == [status.frames - 1 for _, status in frames]
    host = rows_on(path, "world/camera/depth", "DepthImage:buffer", timeline="host_time")
    epoch = dt.datetime(1970, 1, 1)
    assert sorted((t - epoch) // dt.timedelta(microseconds=1) for t in host) == [
        t.frame.host_time_ns // 1000 for t, _ in frames
    ]
    born = all_rows(path, "events/tracks", "TextLog:text", timeline="frame")
    assert born
    assert all(t is not None for t, _ in born)  # events too are placed on the run's index


def test_a_mask_comes_back_with_its_ids_labels_and_colours(recording, run):
    path, _ = recording
    _, _, frames = run
    tracked = frames[12][0]
    assert len(tracked.tracks) >= 3
    buffers = rows_on(path, "world/camera/tracks", "SegmentationImage:buffer")
    h, w = tracked.labels.shape
    mask = np.array(buffers[tracked.sequence], np.uint8).view(np.uint16).reshape(h, w)
    assert np.array_equal(mask, tracked.labels)
    assert set(np.unique(mask)) - {0} == {t.id for t in tracked.tracks}
    # The annotation context in force at that frame names and colours every id in the mask.
    contexts = rows_on(path, "world", "AnnotationContext:context")
    latest = contexts[max(t for t in contexts if t <= tracked.sequence)]
    (context,) = latest
    classes = {c["class_id"]: c["class_description"]["info"] for c in context}
    for i in {t.id for t in tracked.tracks}:
        assert classes[i]["label"] == f"track {i}"
        r, g, b = track_color(i)
        assert classes[i]["color"] == (r << 24) | (g << 16) | (b << 8) | 0xFF


def test_images_come_back_as_logged(recording, run):
    path, _ = recording
    _, _, frames = run
    tracked = frames[12][0]
    f = tracked.frame
    h, w = f.shape

    def image(entity: str, archetype: str, dtype: type) -> np.ndarray:
        # the format is logged once, static; each frame holds only its pixels
        (fmt,) = static_value(path, entity, f"{archetype}:format")
        assert (fmt["width"], fmt["height"]) == (w, h)
        (buffer,) = rows_on(path, entity, f"{archetype}:buffer")[tracked.sequence]
        return np.array(buffer, np.uint8).view(dtype).reshape(h, w)

    # Depth: z in millimetres (meter 1000), to within rounding; 0 ("no depth") where invalid,
    # and where noise at the near end of the range put a valid point behind the camera.
    depth = image("world/camera/depth", "DepthImage", np.uint16)
    assert static_value(path, "world/camera/depth", "DepthImage:meter") == [1000.0]
    z = f.xyz[..., 2]
    shown = f.valid & (z >= 0.0)
    assert shown.sum() > 0.9 * f.valid.size
    assert np.all(depth[~shown] == 0)
    assert np.abs(depth[shown] / 1000.0 - z[shown]).max() <= 0.0005 + 1e-9
    # Amplitude and intensity: 8-bit grey on their fixed square-root scales.
    for entity, counts in (("amplitude", f.amplitude), ("intensity", f.intensity)):
        grey = image(f"world/camera/{entity}", "Image", np.uint8)
        full = rerun_log.IMAGE_FULL_SCALE[entity]
        expected = 255.0 * np.sqrt(np.clip(counts / full, 0.0, 1.0))
        assert np.abs(grey - expected).max() < 1.001  # truncated, in float32
        assert grey.max() > 0


def test_points_boxes_and_trails_carry_the_track_ids(recording, run):
    path, _ = recording
    _, _, frames = run
    tracked = frames[12][0]
    f = tracked.frame
    # Each track's points, with its id as class: `world`'s context gives label and colour.
    classes = np.array(rows_on(path, "world/points", "Points3D:class_ids")[tracked.sequence])
    positions = np.array(rows_on(path, "world/points", "Points3D:positions")[tracked.sequence])
    assert len(positions) == len(classes) == sum(len(t.points) for t in tracked.tracks)
    for t in tracked.tracks:
        assert np.array_equal(positions[classes == t.id], t.points)
    # The background, thinned to every 2nd pixel in u and v, on its own, in one grey.
    background = rows_on(path, "world/points/background", "Points3D:positions")
    s = rerun_log.BACKGROUND_STRIDE
    keep = f.valid[::s, ::s] & (tracked.labels[::s, ::s] == 0)
    expected = f.xyz[::s, ::s][keep].astype(np.float32)
    assert np.array_equal(np.array(background[tracked.sequence], np.float32), expected)
    r, g, b = rerun_log.BACKGROUND_RGB
    grey = (r << 24) | (g << 16) | (b << 8) | 0xFF
    assert static_value(path, "world/points/background", "Points3D:colors") == [grey]
    boxes = rows_on(path, "world/tracks", "Boxes3D:class_ids")[tracked.sequence]
    assert sorted(boxes) == sorted(t.id for t in tracked.tracks)
    trails = rows_on(path, "world/trails", "LineStrips3D:strips")[tracked.sequence]
    older = [t for t in tracked.tracks if t.id not in tracked.born]  # a trail needs 2 points
    assert 0 < len(older) < len(tracked.tracks)
    assert len(trails) == len(older)


def test_track_colours_depend_on_the_id_alone():
    assert track_color(7) == track_color(7)
    assert len({track_color(i) for i in range(1, 200)}) == 199
    assert all(max(track_color(i)) == 255 for i in range(1, 50))  # bright on any background


def test_health_and_events_are_logged(recording, run):
    path, _ = recording
    _, _, frames = run
    # the health every STATUS_EVERY-th frame (nothing was dropped)
    every = [(t, s) for t, s in frames if t.sequence % rerun_log.STATUS_EVERY == 0]
    fps = rows_on(path, "status/fps", "Scalars:scalars")
    assert sorted(fps) == [t.sequence for t, _ in every]
    tracks = rows_on(path, "status/tracks", "Scalars:scalars")
    assert [tracks[t.sequence] for t, _ in every] == [[float(s.tracks)] for _, s in every]
    latency = rows_on(path, "status/latency_ms", "Scalars:scalars")
    assert latency[5] == pytest.approx([frames[5][1].latency_s * 1000])
    born_ended = sorted(
        [(t.sequence, f"track {i} born") for t, _ in frames for i in t.born]
        + [(t.sequence, f"track {i} ended") for t, _ in frames for i in t.ended]
    )
    assert any(t.ended for t, _ in frames)
    assert any(t.born for t, _ in frames[1:])
    logged = all_rows(path, "events/tracks", "TextLog:text")
    assert sorted((t, text) for t, (text,) in logged) == born_ended
    device = all_rows(path, "events/device", "TextLog:text")
    # The first event came before any frame, so it is on no frame timeline.
    assert sorted(device, key=lambda row: row[0] or -1) == [
        (None, ["camera stalled a request"]),
        (frames[-1][0].sequence, ["camera disconnected"]),
    ]
    levels = all_rows(path, "events/device", "TextLog:level")
    assert sorted(level for _, (level,) in levels) == ["ERROR", "WARN"]


# --- the queue: a slow viewer never slows the pipeline; a file loses nothing -----------------


class Stall:
    """Blocks the sink's writer on its first batch of frames until released."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.entered = threading.Event()
        self.release = threading.Event()
        original = FrameLogger.write_frames

        def write_frames(logger: FrameLogger, *args: Any) -> None:
            if not self.entered.is_set():
                self.entered.set()
                assert self.release.wait(60), "the test never released the writer"
            original(logger, *args)

        monkeypatch.setattr(FrameLogger, "write_frames", write_frames)


def frame_sequences(path: Path) -> list[int]:
    return sorted(rows_on(path, "world/camera/depth", "DepthImage:buffer"))


def test_a_stalled_live_sink_drops_the_oldest_frames_and_log_never_waits(
    tmp_path, run, monkeypatch
):
    calibration, belt, frames = run
    stall = Stall(monkeypatch)
    path = tmp_path / "live.rrd"
    sink = RerunSink(calibration, RerunTarget.save(path), belt, queue_frames=4, lossless=False)
    sink.log(*frames[0])
    assert stall.entered.wait(60)  # the worker is now stuck inside the writer
    done = threading.Event()

    def pipeline() -> None:
        for tracked, status in frames[1:]:
            sink.log(tracked, status)
        done.set()

    thread = threading.Thread(target=pipeline, daemon=True)
    thread.start()
    # Every log() returns while the writer is still blocked: the pipeline is never held up.
    assert done.wait(60)
    assert not stall.release.is_set()
    stats = sink.stats
    assert stats.logged == len(frames)
    assert stats.written == 0
    assert stats.dropped == sink.dropped == len(frames) - 1 - 4
    stall.release.set()
    sink.close()
    assert (
        sink.summary()
        == f"rerun: 5 of {len(frames)} frames written to {path}, {stats.dropped} dropped to keep up"
    )
    # The file holds the frame that was being written and the newest four.
    assert frame_sequences(path) == [0, *[t.sequence for t, _ in frames[-4:]]]
    # the drops are logged as soon as a written frame knows of them
    dropped = rows_on(path, "status/rerun_dropped", "Scalars:scalars")
    assert dropped[min(dropped)] == [0.0]
    assert dropped[max(dropped)] == [float(stats.dropped)]


def test_a_file_loses_nothing_even_when_its_writer_stalls(tmp_path, run, monkeypatch):
    calibration, belt, frames = run
    stall = Stall(monkeypatch)
    waiting = threading.Event()
    wait_for_room = RerunSink._wait_for_room

    def noted_wait(sink: RerunSink) -> None:
        waiting.set()
        wait_for_room(sink)

    monkeypatch.setattr(RerunSink, "_wait_for_room", noted_wait)
    path = tmp_path / "file.rrd"
    sink = RerunSink(calibration, RerunTarget.save(path), belt, queue_frames=2)
    assert sink.lossless
    thread = threading.Thread(target=lambda: [sink.log(*f) for f in frames], daemon=True)
    thread.start()
    assert waiting.wait(60)  # the queue is full: log() waits rather than drop
    stall.release.set()
    thread.join(60)
    assert not thread.is_alive()
    sink.close()
    stats = sink.stats
    assert stats.dropped == 0
    assert stats.written == len(frames)
    assert stats.waits >= 1
    assert frame_sequences(path) == [t.sequence for t, _ in frames]


@pytest.mark.parametrize("lossless", [True, False])
def test_a_file_waits_for_rerun_to_write_every_few_frames(tmp_path, run, monkeypatch, lossless):
    calibration, belt, frames = run
    synced_after: list[int] = []
    monkeypatch.setattr("tofcut.tools.pipeline.rerun_sink.SYNC_FRAMES", 5)
    sink = RerunSink(calibration, RerunTarget.save(tmp_path / "x.rrd"), belt, lossless=lossless)
    monkeypatch.setattr(sink._writer, "sync", lambda: synced_after.append(sink._written))
    for f in frames[:12]:
        sink.log(*f)
    sink.close()
    # rerun's own queue to a file is unbounded: a file's worker lets it drain every 5 frames;
    # a live viewer's pushes back by itself.
    assert synced_after == ([5, 10] if lossless else [])


def test_frames_are_written_in_batches_and_a_lone_frame_is_not_held_back(
    tmp_path, run, monkeypatch
):
    calibration, belt, frames = run
    batches: list[list[int]] = []
    written = threading.Event()
    original = FrameLogger.write_frames

    def write_frames(logger: FrameLogger, rows: Any, dropped: int) -> None:
        batches.append([row.tracked.sequence for row in rows])
        original(logger, rows, dropped)
        written.set()

    monkeypatch.setattr(FrameLogger, "write_frames", write_frames)
    # A file: SYNC_FRAMES at a time (the delay is made long, so only the batch size counts);
    # what is left goes when the sink closes.
    monkeypatch.setattr("tofcut.tools.pipeline.rerun_sink.FILE_DELAY_S", 600.0)
    path = tmp_path / "file.rrd"
    sink = RerunSink(calibration, RerunTarget.save(path), belt)
    for tracked, status in frames[:20]:
        sink.log(tracked, status)
    sink.close()
    assert [len(b) for b in batches] == [16, 4]
    assert [i for b in batches for i in b] == [t.sequence for t, _ in frames[:20]]
    assert frame_sequences(path) == [t.sequence for t, _ in frames[:20]]
    # A live viewer: one frame alone is written once it has waited LIVE_DELAY_S, not later.
    batches.clear()
    written.clear()
    sink = RerunSink(calibration, RerunTarget.save(tmp_path / "live.rrd"), belt, lossless=False)
    sink.log(*frames[0])
    assert written.wait(60)
    assert batches == [[frames[0][0].sequence]]
    sink.close()


def test_a_live_viewer_that_never_recovers_cannot_hold_up_close(tmp_path, run, monkeypatch):
    calibration, belt, frames = run
    stall = Stall(monkeypatch)
    monkeypatch.setattr("tofcut.tools.pipeline.rerun_sink.LIVE_CLOSE_TIMEOUT_S", 0.05)
    sink = RerunSink(calibration, RerunTarget.save(tmp_path / "x.rrd"), belt, lossless=False)
    sink.log(*frames[0])
    assert stall.entered.wait(60)
    sink.log(*frames[1])
    sink.log(*frames[2])
    sink.close()  # returns although the writer is still stuck
    assert sink.dropped == 2
    stall.release.set()


def test_a_failing_writer_is_reported_not_hidden(tmp_path, run, monkeypatch):
    calibration, belt, frames = run

    def broken(*args: object) -> None:
        raise OSError("No space left on device")

    monkeypatch.setattr(FrameLogger, "write_frames", broken)
    sink = RerunSink(calibration, RerunTarget.save(tmp_path / "x.rrd"), belt)
    sink.log(*frames[0])
    with pytest.raises(RerunOutputError, match="No space left"):
        sink.close()
    with pytest.raises(RerunOutputError, match="No space left"):
        sink.log(*frames[1])


def test_a_frame_of_another_size_than_the_calibration_is_an_error(tmp_path, run):
    calibration, belt, frames = run
    # The images' format is logged once from the calibration; a frame that does not match it
    # would be shown wrongly, so the output fails and says why.
    tracked, status = frames[1]
    f = tracked.frame
    half = f.shape[1] // 2
    narrow = dataclasses.replace(
        tracked,
        frame=dataclasses.replace(f, header=dataclasses.replace(f.header, width=half)),
        labels=tracked.labels[:, :half],
    )
    sink = RerunSink(calibration, RerunTarget.save(tmp_path / "x.rrd"), belt)
    sink.log(narrow, status)
    with pytest.raises(RerunOutputError, match=rf"frame 1 is \({half}, 144\) pixels"):
        sink.close()


CTRL_C_SCRIPT = """
import signal, sys
sys.path.insert(0, sys.argv[2])
from test_rerun_out import emulated_run
from tofcut.tools.pipeline.rerun_sink import RerunSink
from tofcut.tools.pipeline.rerun_target import RerunTarget
calibration, belt, run = emulated_run(frames=4)
sink = RerunSink(calibration, RerunTarget.save(sys.argv[1]), belt)
for n in range(int(sys.argv[3])):
    sink.log(*run[n % len(run)])
print("logged", flush=True)
signal.pause()  # Ctrl-C lands here; nothing closes the sink but the interpreter's exit
"""


def test_ctrl_c_leaves_a_complete_file_with_every_frame(tmp_path):
    path = tmp_path / "interrupted.rrd"
    frames = 150
    proc = subprocess.Popen(
        [sys.executable, "-c", CTRL_C_SCRIPT, str(path), str(HERE), str(frames)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "logged"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert "KeyboardInterrupt" in err
    result = rrd_verify(path)
    assert result.returncode == 0, result.stdout + result.stderr
    rows = sum(
        ch.num_rows
        for ch in chunks(path)
        if ch.entity_path == "/world/camera/depth" and not ch.is_static
    )
    assert rows == frames


# --- options ---------------------------------------------------------------------------------


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("--fps", type=float)  # a camera option beside them: no clash
    add_rerun_options(parser)
    return parser.parse_args(argv)


NOW = dt.datetime(2026, 5, 4, 13, 2, 1)


def test_no_option_saves_a_dated_file_in_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    target = target_from_args(parse(), NOW)
    assert target == RerunTarget.save(tmp_path / "tofcut-20260504-130201.rrd")
    assert target.lossless
    assert str(target.path) in target.describe()
    assert target_from_args(parse("--headless"), NOW) == RerunTarget("none")
    assert target_from_args(parse("--headless", "--save", "a.rrd"), NOW) == RerunTarget.save(
        "a.rrd"
    )
    target.path.touch()
    assert default_recording_path(NOW).name == "tofcut-20260504-130201-2.rrd"


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--save", "a.rrd"], RerunTarget.save("a.rrd")),
        (["--spawn"], RerunTarget("spawn")),
        (["--connect"], RerunTarget("connect")),
        (
            ["--url", "rerun+http://10.0.0.2:9876/proxy"],
            RerunTarget("connect", url="rerun+http://10.0.0.2:9876/proxy"),
        ),
        (["--connect", "--save", "a.rrd"], RerunTarget("connect")),  # rerun's precedence
        (["--serve"], RerunTarget("serve")),
        (["--stdout", "--serve"], RerunTarget("stdout")),
    ],
)
def test_rerun_options_pick_the_target(argv, expected):
    target = target_from_args(parse(*argv), NOW)
    assert target == expected
    assert target.lossless == (expected.kind == "save")


def test_a_target_saves_exactly_when_it_has_a_path():
    with pytest.raises(ValueError, match="path"):
        RerunTarget("connect", path=Path("x.rrd"))
    with pytest.raises(ValueError, match="path"):
        RerunTarget("save")


# --- the benchmark helper --------------------------------------------------------------------


def test_logging_cost_is_measured_against_tracking_time(run):
    calibration, belt, frames = run
    cost = measure_logging_cost(frames, calibration, tracking_s=2.0, belt_direction=belt)
    assert cost.frames == len(frames)
    assert cost.cpu_s > 0
    assert cost.log_calls_s > 0
    assert cost.file_bytes > 0
    assert 0 < cost.writer_cpu_s <= cost.cpu_s
    assert cost.ratio == pytest.approx(cost.cpu_s / 2.0)
    assert cost.cpu_ms_per_frame == pytest.approx(1000 * cost.cpu_s / len(frames))
    with pytest.raises(ValueError, match="frame"):
        measure_logging_cost([], calibration, tracking_s=1.0)


def test_the_memory_check_replays_a_run_with_time_going_on_and_new_ids(run):
    calibration, belt, frames = run
    base = frames[:6]
    replay = list(rerun_memory.endless(base, 14))
    assert [t.sequence for t, _ in replay] == list(range(14))
    times = [t.frame.device_time_us for t, _ in replay]
    assert all(b > a for a, b in itertools.pairwise(times))
    span = 1 + max(t.id for tracked, _ in base for t in tracked.tracks)
    for i, (tracked, status) in enumerate(replay):
        original = base[i % 6][0]
        offset = span * (i // 6)
        assert [t.id for t in tracked.tracks] == [t.id + offset for t in original.tracks]
        assert np.array_equal(tracked.labels > 0, original.labels > 0)
        assert set(np.unique(tracked.labels)) - {0} == {t.id + offset for t in original.tracks}
        assert tracked.born == tuple(i + offset for i in original.born)
        assert status.frames == i + 1
    grown = rerun_memory.measure(base, calibration, 20, belt)
    assert grown.samples >= 2
    assert grown.peak_b >= grown.start_b > 0


def test_a_sink_from_the_options_says_where_it_writes(tmp_path, monkeypatch, capsys, run):
    calibration, belt, frames = run
    monkeypatch.chdir(tmp_path)
    sink = RerunSink.from_args(parse(), calibration, belt, name="from args")
    (path,) = tmp_path.glob("tofcut-*.rrd")
    assert f"rerun: saving the recording to {path}" in capsys.readouterr().out
    for tracked, status in frames[:2]:
        sink.log(tracked, status)
    sink.close()
    assert sink.summary() == f"rerun: 2 of 2 frames written to {path}"
    assert frame_sequences(path) == [0, 1]


def test_a_frame_without_tracks_clears_the_boxes_and_trails(tmp_path, run):
    calibration, belt, frames = run
    tracked, status = frames[3]
    empty = dataclasses.replace(
        tracked, labels=np.zeros_like(tracked.labels), tracks=(), born=(), ended=()
    )
    path = tmp_path / "empty.rrd"
    with RerunSink(calibration, RerunTarget.save(path), belt) as sink:
        sink.log(*frames[2])
        sink.log(empty, status)
    assert rrd_verify(path).returncode == 0
    boxes = rows_on(path, "world/tracks", "Boxes3D:half_sizes")
    assert len(boxes[2]) == len(frames[2][0].tracks)
    assert boxes[3] == []
    trails = rows_on(path, "world/trails", "LineStrips3D:strips")
    assert trails[3] == []
    mask = rows_on(path, "world/camera/tracks", "SegmentationImage:buffer")[3]
    assert not np.any(np.array(mask, np.uint8))


def test_a_recording_on_stdout_carries_nothing_else(tmp_path):
    # `--stdout` pipes the recording to another program: the run's closing lines go to
    # stderr, or they would trail the recording's bytes
    path = tmp_path / "piped.rrd"
    code = "import sys; from tofcut.tools.cli import main; sys.exit(main(sys.argv[1:]))"
    with path.open("wb") as out:
        result = subprocess.run(
            [sys.executable, "-c", code, "track", "emulator:conveyor", "--fast", "--frames",
             "12", "--stdout"],
            stdout=out, stderr=subprocess.PIPE, text=True, timeout=300,
        )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "tracked 12 frames" in result.stderr
    checked = rrd_verify(path)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert len(frame_sequences(path)) == 12


def test_a_device_timestamp_past_rerun_s_range_costs_that_field_not_the_run(tmp_path, capsys):
    """A u64 device time ≥ 2^63 made rerun fail ('int too big to convert') and `track` exit 1.
    The frame is now logged on its sequence and log time, without device_time, and counted."""
    from dataclasses import replace

    from tofcut.driver.capture import CaptureReader, CaptureWriter
    from tofcut.driver.protocol import HEADER_SIZE, pack_header
    from tofcut.tools.cli import main

    cap = tmp_path / "run.tofcap"
    assert main(["record", "emulator:test-pattern", "-o", str(cap), "--frames", "8", "--fast"]) == 0
    reader = CaptureReader(cap)
    odd = tmp_path / "odd.tofcap"
    odd_sequences = set()
    with CaptureWriter(odd, reader.capture.metadata, reader.capture.calibration_block) as out:
        for i, raw in enumerate(reader.raw_frames()):
            if i in (3, 4):
                stamp = 2**63 + i if i == 3 else 2**64 - 1
                header = replace(raw.header, device_time_us=stamp)
                raw = replace(raw, header=header, wire=pack_header(header) + raw.wire[HEADER_SIZE:])
                odd_sequences.add(raw.sequence)
            out.write(raw)
    rrd = tmp_path / "odd.rrd"
    capsys.readouterr()
    assert main(["track", str(odd), "--save", str(rrd)]) == 0
    printed = capsys.readouterr().out
    assert "8 of 8 frames written" in printed
    assert "2 without a device time" in printed
    on_sequence = rows_on(rrd, "world/camera/depth", "DepthImage:buffer")
    assert len(on_sequence) == 8
    device = all_rows(rrd, "world/camera/depth", "DepthImage:buffer", timeline="device_time")
    assert sum(t is None for t, _ in device) == 2  # the two odd frames, off that timeline
    assert len([t for t, _ in device if t is not None]) == 6


def _listening_sockets() -> set[tuple[str, str]]:
    """(table, local address) of every listening TCP socket this process holds."""
    ours = set()
    for fd in Path("/proc/self/fd").iterdir():
        try:
            link = os.readlink(fd)
        except OSError:
            continue
        if link.startswith("socket:["):
            ours.add(link[8:-1])
    found = set()
    for table in ("tcp", "tcp6"):
        for line in Path(f"/proc/self/net/{table}").read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] == "0A" and cols[9] in ours:  # 0A: LISTEN
                found.add((table, cols[1]))
    return found


def test_serve_listens_on_loopback_only_by_default(monkeypatch):
    web_viewers = []
    monkeypatch.setattr(rr, "serve_web_viewer", lambda **kw: web_viewers.append(kw))
    target = target_from_args(parse("--serve"), NOW)
    assert target == RerunTarget("serve", bind="127.0.0.1")
    assert "to this machine only" in target.describe()
    assert "until Ctrl-C" in target.describe()
    before = _listening_sockets()
    rec = rr.RecordingStream("tofcut-test-serve")
    target = dataclasses.replace(target, port=0)  # any free port
    target.attach(rec, rrb.Blueprint())
    try:
        deadline = time.monotonic() + 10.0
        while not (new := _listening_sockets() - before):
            assert time.monotonic() < deadline, "the gRPC server never listened"
            time.sleep(0.01)
        assert all(table == "tcp" and addr.startswith("0100007F:") for table, addr in new), new
        assert web_viewers == []  # rerun's web viewer binds every interface: not by default
    finally:
        rec.disconnect()


def test_bind_opens_serve_wider_with_a_warning(monkeypatch, capsys):
    sinks, web_viewers = [], []

    class FakeSink:
        def __init__(self, bind_ip: str, port: int) -> None:
            sinks.append((bind_ip, port))
            self.uri = f"rerun+http://{bind_ip}:{port}/proxy"

    monkeypatch.setattr(rr, "GrpcServerSink", FakeSink)
    monkeypatch.setattr(rr, "serve_web_viewer", lambda **kw: web_viewers.append(kw))
    monkeypatch.setattr(rr.RecordingStream, "set_sinks", lambda self, *a, **k: None)
    target = target_from_args(parse("--serve", "--bind", "0.0.0.0"), NOW)
    assert target.bind == "0.0.0.0"
    target.attach(rr.RecordingStream("tofcut-test-bind"), rrb.Blueprint())
    assert sinks == [("0.0.0.0", 9876)]
    assert len(web_viewers) == 1
    warning = capsys.readouterr().err
    assert warning.startswith("warning: --bind 0.0.0.0:")
    assert warning.count("\n") == 1
    with pytest.raises(SystemExit):
        parse("--serve", "--bind", "everywhere")


def test_the_help_says_what_serve_exposes_and_for_how_long():
    parser = argparse.ArgumentParser()
    add_rerun_options(parser)
    text = " ".join(parser.format_help().split())
    assert "without authentication" in text
    assert "until Ctrl-C after it" in text
    assert "127.0.0.1" in text


def test_the_segment_bounds_are_options_with_sensible_defaults():
    default = target_from_args(parse("--save", "a.rrd"), NOW)
    assert default.segment_bytes == 256_000_000
    assert default.segment_s == 600.0
    target = target_from_args(
        parse("--save", "a.rrd", "--segment-mb", "2", "--segment-minutes", "0.5"), NOW
    )
    assert target == RerunTarget.save("a.rrd", segment_bytes=2_000_000, segment_s=30.0)
    assert target.segment_path(3) == Path("a-0003.rrd")
    assert target_from_args(parse("--save", "a.rrd", "--segment-mb", "0"), NOW).segment_bytes == 0
    for bad in ("-1", "nan", "inf", "lots"):
        with pytest.raises(SystemExit):
            parse("--segment-mb", bad)
    parser = argparse.ArgumentParser()
    add_rerun_options(parser)
    text = " ".join(parser.format_help().split())
    assert "default 256 MB" in text
    assert "default 10" in text
    assert "RUN-0001.rrd" in text
