"""The frame parser: reassembly, resynchronisation, loss accounting, size checks."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.driver.protocol import (
    FRAME_MAGIC,
    HEADER_SIZE,
    DeviceInfo,
    FrameHeader,
    crc32,
    pack_header,
)
from tofcut.driver.stream import FrameParser

W, H = 8, 6
INFO = DeviceInfo(1, 0x104, 1, W, H, 64 + 2 * W * H, 54)


def wire_frame(seq: int, *, flags: int = 0, payload_size: int | None = None, seed: int = 0):
    rng = np.random.default_rng([seed, seq])
    payload = rng.integers(0, 16383, (4, H, W), dtype=np.uint16).astype("<u2").tobytes()
    header = FrameHeader(
        sequence=seq,
        device_time_us=1000 * seq,
        width=W,
        height=H,
        mod_code=1,
        integration=30,
        flags=flags,
        temperature_c=36.5,
        tap_interval_us=3500,
        payload_size=len(payload) if payload_size is None else payload_size,
        payload_crc=crc32(payload),
    )
    return pack_header(header) + payload


def feed_all(parser: FrameParser, data: bytes, cuts: list[int]):
    out = []
    pos = 0
    for cut in [*sorted(cuts), len(data)]:
        out += parser.feed(data[pos:cut], 0)
        pos = cut
    return out


def test_frames_arriving_in_random_pieces_are_reassembled():
    stream = b"".join(wire_frame(i) for i in range(20))
    rng = np.random.default_rng(1)
    for _ in range(20):
        parser = FrameParser(INFO)
        cuts = sorted(rng.choice(len(stream), size=rng.integers(1, 60), replace=False).tolist())
        frames = feed_all(parser, stream, cuts)
        assert [f.sequence for f in frames] == list(range(20))
        assert parser.stats.lost == parser.stats.damaged == parser.stats.bytes_skipped == 0
        assert parser.pending == 0
    assert frames[7].wire == wire_frame(7)
    np.testing.assert_array_equal(
        frames[7].taps, np.frombuffer(wire_frame(7), "<u2", offset=HEADER_SIZE).reshape(4, H, W)
    )


@pytest.mark.parametrize(
    "damage",
    [
        lambda f: f[:100] + bytes([f[100] ^ 1]) + f[101:],  # payload byte
        lambda f: f[:9] + bytes([f[9] ^ 1]) + f[10:],  # header byte (sequence)
        lambda f: f[: len(f) // 2],  # cut short
        lambda f: b"\x00garbage" + f[30:],  # a lost start
    ],
    ids=["payload", "header", "truncated", "lost-start"],
)
def test_a_damaged_frame_is_dropped_and_the_stream_goes_on(damage):
    frames = [wire_frame(i) for i in range(6)]
    frames[3] = damage(frames[3])
    parser = FrameParser(INFO)
    got = parser.feed(b"".join(frames), 0)
    assert [f.sequence for f in got] == [0, 1, 2, 4, 5]
    assert parser.stats.lost == 1
    assert list(parser.stats.gaps) == [(3, 3)]
    assert parser.stats.frames == 5


def test_garbage_full_of_frame_magic_is_one_damaged_frame_not_one_per_match():
    """Between two good frames, a record of garbage made of nothing but the frame's magic
    (thousands of false starts, each failing its header check) costs one damaged frame."""
    parser = FrameParser(INFO)
    garbage = FRAME_MAGIC * 20000
    got = parser.feed(wire_frame(0) + garbage + wire_frame(1), 0)
    assert [f.sequence for f in got] == [0, 1]
    assert parser.stats.damaged == 1
    assert parser.stats.lost == 0


def test_sequence_gaps_are_counted_with_their_ranges():
    parser = FrameParser(INFO)
    parser.feed(b"".join(wire_frame(i) for i in (0, 1, 5, 6, 9)), 0)
    assert parser.stats.lost == 5
    assert list(parser.stats.gaps) == [(2, 4), (7, 8)]


def test_sequence_wraps_around_without_a_loss():
    parser = FrameParser(INFO)
    got = parser.feed(wire_frame(0xFFFFFFFF) + wire_frame(0), 0)
    assert len(got) == 2
    assert parser.stats.lost == 0


def test_a_header_claiming_a_huge_payload_is_rejected_before_any_allocation():
    huge = wire_frame(0, payload_size=2**31)
    parser = FrameParser(INFO)
    got = parser.feed(huge + wire_frame(1), 0)
    assert [f.sequence for f in got] == [1]
    assert parser.stats.damaged == 1
    # it never waited for 2 GiB to arrive: nothing is held back
    assert parser.pending == 0


def test_drop_flag_is_counted():
    parser = FrameParser(INFO)
    parser.feed(wire_frame(0) + wire_frame(3, flags=4), 0)
    assert parser.stats.device_dropped_flags == 1
    assert parser.stats.lost == 2


def test_host_time_is_that_of_the_piece_that_completed_the_frame():
    data = wire_frame(0)
    parser = FrameParser(INFO)
    assert parser.feed(data[:100], 111) == []
    (frame,) = parser.feed(data[100:], 222)
    assert frame.host_time_ns == 222
