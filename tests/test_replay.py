"""`emulator:FILE.tofcap`: the emulated camera replaying a capture, read by the driver as a
live camera is (tofcut.sim.replay), against the same capture read by `CaptureReader`."""

from __future__ import annotations

import json
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tofcut.driver.capture import CaptureReader, bare_copy
from tofcut.driver.errors import CaptureError, RequestRejected
from tofcut.driver.protocol import HEADER_SIZE, Register, pack_header, parse_header
from tofcut.sim.process import EmulatorProcess
from tofcut.sim.replay import read_index
from tofcut.tools.cli import main
from tofcut.tools.pipeline.sources import Opened, SourceSpec, open_source

FRAMES = 30
RECORD = 8
"""Bytes of a record's host time, before its frame."""


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a run that saves a default .rrd saves it here


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """The emulated conveyor, recorded fast: 30 frames at 50 fps."""
    path = tmp_path_factory.mktemp("replay") / "run.tofcap"
    argv = ["record", "emulator:conveyor", "--fast", "--frames", str(FRAMES), "-o", str(path)]
    assert main(argv) == 0
    return path


@pytest.fixture(scope="module")
def bare(capture, tmp_path_factory) -> Path:
    """The same capture with the camera's own metadata only, as a real camera records."""
    path = tmp_path_factory.mktemp("replay") / "bare.tofcap"
    bare_copy(capture, path)
    return path


def replay(path: Path, **options) -> Opened:
    options = {"realtime": False, "reconnect": True, **options}
    return open_source(SourceSpec("emulator", str(path)), own_process=False, **options)


def payloads(path: Path) -> list[int]:
    """Each recorded frame's payload CRC: which recorded frame a replayed one is."""
    return [raw.header.payload_crc for raw in CaptureReader(path).raw_frames()]


def replayed(opened: Opened, count: int | None = None) -> list[int]:
    """The recorded frames (by their index in the capture) the driver got, in order."""
    recorded = payloads(opened.replay.path)
    return [recorded.index(raw.header.payload_crc) for raw in opened.device.raw_frames(count)]


@pytest.mark.parametrize("which", ["capture", "bare"])
def test_a_replay_gives_the_captures_frames_bit_for_bit(request, which):
    path = request.getfixturevalue(which)
    reader = CaptureReader(path)
    expected = list(reader.frames())
    opened = replay(path)
    try:
        got = list(opened.device.frames())  # it ends with the capture, by itself
        camera = opened.device
        assert camera.calibration_block == reader.capture.calibration_block
        assert camera.info == reader.info
        assert camera.config.registers() == {
            Register[name]: value for name, value in reader.capture.metadata["registers"].items()
        }
    finally:
        opened.close()
    assert len(got) == len(expected) == FRAMES
    for e, g in zip(expected, got, strict=True):
        assert np.array_equal(e.range, g.range)
        assert np.array_equal(e.amplitude, g.amplitude)
        assert np.array_equal(e.valid, g.valid)
        # recorded fast from a fresh camera, replayed fast: even the numbers and times agree
        assert e.header == g.header
    assert (camera.stats.frames, camera.stats.lost, camera.stats.damaged) == (FRAMES, 0, 0)
    assert ("belt" in opened.metadata) == (which == "capture")


def test_a_damaged_transfer_a_stall_and_an_overflow_are_counted_as_with_a_scene(capture):
    opened = replay(capture)
    emulator = opened.emulator
    try:
        got = replayed(opened, 5)
        emulator.damage_next("truncate")  # recorded frame 5 is cut short on the wire
        got += replayed(opened, 5)
        emulator.stall_endpoint(after_packets=3)  # frame 11 is lost mid-transfer
        got += replayed(opened, 5)
        emulator.overflow_fifo(4)  # frames 17-20 are never taken
        got += replayed(opened)
        stats = opened.device.stats
    finally:
        opened.close()
    assert got == [*range(0, 5), *range(6, 11), *range(12, 17), *range(21, FRAMES)]
    assert (stats.damaged, stats.stalls_cleared, stats.device_dropped_flags) == (1, 1, 1)
    assert stats.lost == 1 + 1 + 4 == FRAMES - len(got)  # every frame not replayed, counted


def test_unplugged_in_real_time_the_line_goes_on_and_the_outage_is_estimated(capture):
    opened = replay(capture, realtime=True)
    try:
        first = replayed(opened, 3)
        opened.bus.unplug(opened.emulator)
        back = threading.Timer(0.2, opened.bus.replug, [opened.emulator])
        back.start()  # plugged in again 0.2 s later: 10 frames' time at 50 fps
        rest = replayed(opened)
        back.join()
        stats = opened.device.stats
    finally:
        opened.close()
    assert first == [0, 1, 2]
    assert stats.reconnects == 1
    assert rest == sorted(rest)
    assert rest[-1] == FRAMES - 1  # on, to the capture's end
    missed = FRAMES - len(first) - len(rest)
    assert missed >= 10  # the frames of the time it was away
    assert stats.lost == stats.lost_estimated
    assert abs(stats.lost - missed) <= 2  # the driver's estimate, from the time it was away


def test_a_slower_frame_rate_takes_fewer_frames_and_a_setting_it_cannot_replay_stalls(capture):
    opened = replay(capture)
    camera = opened.device
    try:
        camera.write_register(Register.FRAME_PERIOD, 400)  # 25 fps: every second frame
        got = replayed(opened)
        assert got == list(range(0, FRAMES, 2))
        assert camera.stats.lost == 0  # none was the camera's to send
        for register, value in [(Register.MOD_FREQ, 6), (Register.INTEGRATION, 60),
                                (Register.FRAME_PERIOD, 100)]:  # fmt: skip
            with pytest.raises(RequestRejected):
                camera.write_register(register, value)
    finally:
        opened.close()


def test_a_loop_starts_the_capture_again(capture):
    opened = replay(capture, loop=True)
    try:
        got = [(f.sequence, f.header.payload_crc) for f in opened.device.raw_frames(FRAMES + 3)]
    finally:
        opened.close()
    assert [seq for seq, _ in got] == list(range(FRAMES + 3))
    assert [crc for _, crc in got[FRAMES:]] == payloads(capture)[:3]


def damaged_copy(capture: Path, target: Path, record: int, at: int) -> Path:
    """The capture with one byte of one record's frame flipped."""
    data = bytearray(capture.read_bytes())
    size = len(data)
    frame = (size - CaptureReader(capture)._records_start) // FRAMES - RECORD
    data[size - (FRAMES - record) * (RECORD + frame) + RECORD + at] ^= 0x5A
    target.write_bytes(bytes(data))
    return target


def test_a_damaged_or_cut_short_capture_replays_what_is_whole_and_counts_the_rest(
    capture, tmp_path
):
    bad = damaged_copy(capture, tmp_path / "bad.tofcap", record=7, at=HEADER_SIZE + 100)
    with open(bad, "ab") as f:
        f.write(b"\x00" * 1000)  # a record cut short by a killed recorder
    reader = CaptureReader(bad)
    assert len(list(reader.raw_frames())) == FRAMES - 1
    opened = replay(bad)
    try:
        got = replayed(opened)
        stats = opened.device.stats
    finally:
        opened.close()
    assert len(got) == FRAMES - 1
    assert (stats.damaged, stats.lost) == (reader.stats.damaged, reader.stats.lost) == (1, 1)
    assert (opened.replay.damaged, opened.replay.truncated_bytes) == (1, 1000)


def test_the_command_line_replays_and_says_what_a_capture_lacks(capture, tmp_path, capsys):
    tracks = tmp_path / "replayed.jsonl"
    argv = ["track", f"emulator:{capture}", "--fast", "--tracks-out", str(tracks)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert f"tracked {FRAMES} frames" in out
    assert "dropped by the tracker queue (the tracker fell behind): 0" in out
    assert f"replayed {capture}: {FRAMES} recorded frames" in out
    read = tmp_path / "read.jsonl"
    assert main(["track", str(capture), "--tracks-out", str(read)]) == 0
    lines = [[json.loads(x) for x in p.read_text().splitlines()] for p in (tracks, read)]
    assert [x["tracks"] for x in lines[0]] == [x["tracks"] for x in lines[1]]  # end to end
    capsys.readouterr()

    bad = damaged_copy(capture, tmp_path / "bad.tofcap", record=3, at=HEADER_SIZE + 5)
    assert main(["live", f"emulator:{bad}", "--fast"]) == 1
    captured = capsys.readouterr()
    assert f"tracked {FRAMES - 1} frames" in captured.out
    assert "skipped 1 damaged frames" in captured.out
    assert captured.err.strip().splitlines()[-1].startswith("tofcut: error: the input is damaged")

    assert main(["live", f"emulator:{capture}", "--mod-freq", "15"]) == 1
    assert capsys.readouterr().err.strip() == (
        "tofcut: error: the capture was recorded at 30 MHz: its frames cannot be replayed at 15 MHz"
    )


def rewritten(capture: Path, target: Path, change) -> Path:
    """The capture with its metadata changed by `change(meta)`."""
    reader = CaptureReader(capture)
    meta = dict(reader.capture.metadata)
    change(meta)
    head = json.dumps(meta).encode()
    calib = reader.capture.calibration_block
    records = capture.read_bytes()[reader._records_start :]
    size = len(head).to_bytes(4, "little")
    calib_size = len(calib).to_bytes(4, "little")
    target.write_bytes(b"TOFCAP01" + size + head + calib_size + calib + records)
    return target


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda m: m["registers"].update(MOD_FREQ=3), "register MOD_FREQ is not a value"),
        (lambda m: m["registers"].update(INTEGRATION="30"), "register INTEGRATION is not"),
        (lambda m: m["registers"].update(MOD_FREQ=6), "record 0 was made at MOD_FREQ 1"),
        (lambda m: m.update(protocol=2), "recorded with protocol 2"),
        (lambda m: m.update(width=175), "calibration length"),
    ],
)
def test_what_a_replay_cannot_use_is_one_line(capture, tmp_path, capsys, change, message):
    bad = rewritten(capture, tmp_path / "odd.tofcap", change)
    with pytest.raises(CaptureError, match=message) as info:
        read_index(bad)
    assert "\n" not in str(info.value)
    assert main(["live", f"emulator:{bad}", "--fast"]) == 1
    assert capsys.readouterr().err.strip().splitlines() == [f"tofcut: error: {info.value}"]


def test_registers_missing_from_the_metadata_come_from_the_frames(capture, tmp_path):
    def drop(meta):
        meta["registers"] = {}

    index = read_index(rewritten(capture, tmp_path / "lean.tofcap", drop))
    assert index.registers == read_index(capture).registers


def test_recording_a_replay_gives_the_capture_back_byte_for_byte(capture, tmp_path):
    copy = tmp_path / "copy.tofcap"
    argv = ["record", f"emulator:{capture}", "--fast", "--frames", "100", "-o", str(copy)]
    assert main(argv) == 0  # 100 asked: the recording ends with the capture's 30
    wires = [[raw.wire for raw in CaptureReader(path).raw_frames()] for path in (capture, copy)]
    assert len(wires[1]) == FRAMES
    assert wires[0] == wires[1]
    assert CaptureReader(copy).capture.metadata["source"] == f"emulator:{capture}"


def test_frames_the_recording_lost_are_numbered_and_lost_again(capture, tmp_path):
    data = capture.read_bytes()
    start = CaptureReader(capture)._records_start
    record = (len(data) - start) // FRAMES
    gappy = tmp_path / "gappy.tofcap"  # records 10-12 never reached the recorder
    gappy.write_bytes(data[: start + 10 * record] + data[start + 13 * record :])
    reader = CaptureReader(gappy)
    expected = [raw.sequence for raw in reader.raw_frames()]
    opened = replay(gappy)
    try:
        got = [raw.sequence for raw in opened.device.raw_frames()]
        stats = opened.device.stats
    finally:
        opened.close()
    assert got == expected == [*range(10), *range(13, FRAMES)]
    assert (
        (stats.lost, stats.gaps[-1]) == (reader.stats.lost, reader.stats.gaps[-1]) == (3, (10, 12))
    )


def test_in_real_time_the_replay_runs_in_a_process_of_its_own_and_ends(capture):
    opened = open_source(SourceSpec.parse(f"emulator:{capture}"), realtime=True)
    emulator = opened.emulator
    assert isinstance(emulator, EmulatorProcess)
    try:
        frames = list(opened.device.raw_frames())  # ends with the capture, by itself
    finally:
        opened.close()
    assert [raw.header.payload_crc for raw in frames] == payloads(capture)
    assert emulator.replay_done.is_set()
    assert emulator.exit_status is not None  # closing ended the process


def test_a_gap_no_recording_could_have_is_one_line(capture, tmp_path):
    """A frame whose sequence number says 2^30 frames were lost before it (its header and
    CRCs made whole again) would be numbered one by one: it is refused."""
    data = bytearray(capture.read_bytes())
    start = CaptureReader(capture)._records_start
    record = (len(data) - start) // FRAMES
    at = start + 5 * record + RECORD  # record 5's frame header
    header = parse_header(bytes(data[at : at + HEADER_SIZE]))
    data[at : at + HEADER_SIZE] = pack_header(replace(header, sequence=header.sequence + (1 << 30)))
    odd = tmp_path / "odd.tofcap"
    odd.write_bytes(bytes(data))
    with pytest.raises(CaptureError, match=r"record 5 says 1073741824 frames were lost"):
        read_index(odd)
