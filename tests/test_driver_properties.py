"""Hostile input, generated: the frame parser, the capture reader and the calibration reader
take random, truncated and mutated bytes and answer only with their documented errors,
never hold more than a frame's worth of bytes, and still deliver every good frame."""

from __future__ import annotations

import json
import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tofcut.driver.calibration import pack_calibration, parse_calibration
from tofcut.driver.capture import MAGIC, CaptureReader, CaptureWriter
from tofcut.driver.demod import Optics
from tofcut.driver.errors import CaptureError, ProtocolError
from tofcut.driver.protocol import (
    CALIB_HEADER_SIZE,
    MAX_SENSOR_PIXELS,
    MOD_FREQ_MHZ,
    DeviceInfo,
    FrameHeader,
    crc32,
    pack_header,
    pack_info,
    parse_info,
)
from tofcut.driver.stream import FrameParser
from tofcut.sim.pattern import pattern_calibration

W, H = 8, 6
CALIB = pack_calibration(pattern_calibration(W, H, seed=3))
INFO = DeviceInfo(1, 0x104, 0x4000002F, W, H, len(CALIB), 54)
FRAME_SIZE = INFO.frame_size

# Deterministic and quick: the same examples every run, a few seconds for the whole module.
FAST = settings(
    max_examples=60,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


def wire_frame(seq: int) -> bytes:
    """A good frame: 14-bit counts, as the sensor sends them."""
    rng = np.random.default_rng([7, seq])
    payload = rng.integers(0, 16383, (4, H, W), dtype=np.uint16).astype("<u2").tobytes()
    header = FrameHeader(
        sequence=seq,
        device_time_us=20_000 * seq,
        width=W,
        height=H,
        mod_code=1,
        integration=30,
        flags=0,
        temperature_c=36.5,
        tap_interval_us=3500,
        payload_size=len(payload),
        payload_crc=crc32(payload),
    )
    return pack_header(header) + payload


# --- mutations of one frame ---------------------------------------------------------------

mutation = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, FRAME_SIZE - 1), st.integers(1, 255)),
    st.tuples(st.just("cut"), st.integers(0, FRAME_SIZE - 1)),
    st.tuples(st.just("delete"), st.integers(0, FRAME_SIZE - 1), st.integers(1, 600)),
    st.tuples(
        st.just("insert"), st.integers(0, FRAME_SIZE - 1), st.binary(min_size=1, max_size=80)
    ),
)


def mutate(frame: bytes, how: tuple) -> bytes:
    kind, pos, *arg = how
    if kind == "flip":
        return frame[:pos] + bytes([frame[pos] ^ arg[0]]) + frame[pos + 1 :]
    if kind == "cut":
        return frame[:pos]
    if kind == "delete":
        return frame[:pos] + frame[pos + arg[0] :]
    return frame[:pos] + arg[0] + frame[pos:]


def damaged_stream(n: int, mutations: dict[int, tuple]) -> tuple[list[bytes], list[bytes]]:
    """The frames as sent, and what arrived of each."""
    sent = [wire_frame(i) for i in range(n)]
    arrived = [mutate(f, mutations[i]) if i in mutations else f for i, f in enumerate(sent)]
    return sent, arrived


def survivors(sent: list[bytes], arrived: list[bytes]) -> list[int]:
    """Frames whose bytes all arrived, in one piece (maybe with junk around them)."""
    return [i for i, (s, a) in enumerate(zip(sent, arrived, strict=True)) if s in a]


def check_accounting(parser: FrameParser, got: list) -> None:
    seqs = [f.sequence for f in got]
    stats = parser.stats
    assert stats.frames == len(got)
    if seqs:
        missing = sorted(set(range(seqs[0], seqs[-1] + 1)) - set(seqs))
        assert stats.lost == len(missing)
        assert [s for a, b in stats.gaps for s in range(a, b + 1)] == missing
    assert stats.lost_estimated == 0


# --- the frame parser ---------------------------------------------------------------------


@FAST
@given(st.binary(max_size=3 * FRAME_SIZE), st.lists(st.integers(0, 3 * FRAME_SIZE), max_size=8))
def test_random_bytes_make_no_frames_and_are_not_hoarded(data, cuts):
    parser = FrameParser(INFO)
    pos = 0
    for cut in [*sorted(cuts), len(data)]:
        assert parser.feed(data[pos:cut], 0) == []
        pos = max(pos, cut)
        assert parser.pending < FRAME_SIZE
    parser.end_transfer()
    assert parser.pending == 0


@FAST
@given(
    st.integers(3, 7).flatmap(
        lambda n: st.tuples(st.just(n), st.dictionaries(st.integers(0, n - 1), mutation))
    ),
    st.lists(st.integers(0, 10 * FRAME_SIZE), max_size=12),
)
def test_a_mutated_byte_stream_still_yields_every_intact_frame(case, cuts):
    """No transfer boundaries (a capture read as one stream, or a sloppy host): the parser
    must resynchronise on its own. Two good frames close the stream."""
    n, mutations = case
    sent, arrived = damaged_stream(n, mutations)
    tail = [wire_frame(n), wire_frame(n + 1)]
    stream = b"".join(arrived + tail)
    parser = FrameParser(INFO)
    got = []
    pos = 0
    for cut in [*sorted(cuts), len(stream)]:
        got += parser.feed(stream[pos:cut], 0)
        pos = max(pos, cut)
        assert parser.pending < FRAME_SIZE
    want = [*survivors(sent, arrived), n, n + 1]
    assert [f.sequence for f in got] == want
    assert [f.wire for f in got] == [(sent + tail)[i] for i in want]
    check_accounting(parser, got)


@FAST
@given(
    st.integers(2, 7).flatmap(
        lambda n: st.tuples(st.just(n), st.dictionaries(st.integers(0, n - 1), mutation))
    ),
    st.sampled_from([512, 1024, FRAME_SIZE + 512]),
)
def test_each_transfer_is_one_frame_and_damage_is_counted(case, read_size):
    """As the camera reads: one transfer per frame, in reads of `read_size` bytes."""
    n, mutations = case
    sent, arrived = damaged_stream(n, mutations)
    parser = FrameParser(INFO)
    got = []
    for transfer in arrived:
        for start in range(0, max(len(transfer), 1), read_size):
            got += parser.feed(transfer[start : start + read_size], 0)
        parser.end_transfer()
        assert parser.pending == 0
    want = survivors(sent, arrived)
    assert [f.sequence for f in got] == want
    for frame in got:
        np.testing.assert_array_equal(
            frame.taps.ravel(), np.frombuffer(sent[frame.sequence][64:], "<u2")
        )
    check_accounting(parser, got)
    broken = [i for i in range(n) if i not in want and arrived[i]]
    assert parser.stats.damaged >= len(broken)
    if not any(how[0] == "insert" for how in mutations.values()):
        assert parser.stats.damaged == len(broken)


BAD_FIELDS = {
    "width": st.sampled_from([0, 1, W + 1, 4096, 65535]),
    "height": st.sampled_from([0, H - 1, 65535]),
    "taps": st.sampled_from([0, 3, 255]),
    "mod_code": st.integers(0, 255).filter(lambda code: code not in MOD_FREQ_MHZ),
    "payload_size": st.sampled_from([0, 1, INFO.payload_size - 2, 2**31, 2**32 - 1]),
}


@st.composite
def headers(draw: st.DrawFn) -> tuple[FrameHeader, bytes]:
    """A header with a valid CRC whose fields are right except for a few broken ones, and a
    payload that may be short, long or not match its CRC."""
    broken = draw(st.sets(st.sampled_from([*BAD_FIELDS, "crc", "length"]), max_size=2))
    fields = {
        "sequence": draw(st.integers(0, 2**32 - 1)),
        "device_time_us": draw(st.integers(0, 2**64 - 1)),
        "width": W,
        "height": H,
        "taps": 4,
        "mod_code": draw(st.sampled_from(sorted(MOD_FREQ_MHZ))),
        "integration": draw(st.integers(0, 255)),
        "flags": draw(st.integers(0, 255)),
        "temperature_c": draw(st.integers(-32768, 32767)) / 100,
        "tap_interval_us": draw(st.integers(0, 65535)),
        "payload_size": INFO.payload_size,
    }
    for name in broken & set(BAD_FIELDS):
        fields[name] = draw(BAD_FIELDS[name])
    size = INFO.payload_size
    if "length" in broken:
        size = draw(st.integers(0, size + 10).filter(lambda n: n != INFO.payload_size))
    payload = draw(st.binary(min_size=size, max_size=size))
    crc = crc32(payload) ^ (draw(st.integers(1, 2**32 - 1)) if "crc" in broken else 0)
    return FrameHeader(**fields, payload_crc=crc), payload


@settings(FAST, max_examples=200)
@given(headers())
def test_headers_with_a_valid_crc_but_any_fields_are_checked_against_the_device(case):
    """A header that passes its CRC is still only trusted as far as GET_INFO allows."""
    header, payload = case
    frame = pack_header(header) + payload
    parser = FrameParser(INFO)
    got = parser.feed(frame + wire_frame(9), 0)
    assert parser.pending < FRAME_SIZE
    acceptable = (
        (header.width, header.height, header.taps) == (W, H, 4)
        and header.payload_size == len(payload) == INFO.payload_size
        and header.mod_code in MOD_FREQ_MHZ
        and header.payload_crc == crc32(payload)
    )
    assert [f.wire for f in got] == ([frame] if acceptable else []) + [wire_frame(9)]
    if acceptable:
        assert got[0].header == header


# --- the capture reader -------------------------------------------------------------------


def write_capture(path: Path, n: int, meta: dict | None = None, calib: bytes = CALIB) -> list:
    parser = FrameParser(INFO)
    raws = parser.feed(b"".join(wire_frame(i) for i in range(n)), 0)
    meta = meta or {
        "serial": "4000002F",
        "firmware": 0x104,
        "protocol": 1,
        "width": W,
        "height": H,
        "registers": {"TRIGGER_MODE": 0},
    }
    with CaptureWriter(path, meta, calib) as writer:
        for i, raw in enumerate(raws):
            writer.write(type(raw)(raw.header, raw.taps, raw.wire, 1000 + i))
    return raws


def open_and_read(path: Path) -> tuple[CaptureReader, list] | None:
    """Open and replay a capture; None when it is refused (with a CaptureError only)."""
    try:
        reader = CaptureReader(path)
    except CaptureError:
        return None
    return reader, list(reader.raw_frames())


@pytest.fixture(scope="module")
def good_capture(tmp_path_factory) -> tuple[bytes, int, list]:
    path = tmp_path_factory.mktemp("cap") / "good.tofcap"
    raws = write_capture(path, 5)
    data = path.read_bytes()
    head = len(data) - 5 * (8 + FRAME_SIZE)
    return data, head, raws


@FAST
@given(st.binary(max_size=2000), st.booleans())
def test_random_files_are_refused_with_a_capture_error(tmp_path, data, with_magic):
    path = tmp_path / "random.tofcap"
    path.write_bytes((MAGIC if with_magic else b"") + data)
    result = open_and_read(path)
    if result is not None:  # only a file with a well-formed head could open at all
        assert result[1] == []


@FAST
@given(cut=st.integers(0, 10**6))
def test_a_capture_cut_anywhere_replays_every_whole_record(tmp_path, good_capture, cut):
    data, head, raws = good_capture
    cut %= len(data) + 1
    path = tmp_path / "cut.tofcap"
    path.write_bytes(data[:cut])
    result = open_and_read(path)
    if cut < head:
        assert result is None
        return
    assert result is not None
    reader, got = result
    whole, rest = divmod(cut - head, 8 + FRAME_SIZE)
    assert [f.wire for f in got] == [r.wire for r in raws[:whole]]
    assert reader.truncated_bytes == rest
    assert reader.stats.damaged == 0


@FAST
@given(pos=st.integers(0, 10**6), xor=st.integers(1, 255))
def test_a_flipped_byte_costs_at_most_its_own_record(tmp_path, good_capture, pos, xor):
    data, head, raws = good_capture
    pos %= len(data)
    damaged = bytearray(data)
    damaged[pos] ^= xor
    path = tmp_path / "flip.tofcap"
    path.write_bytes(bytes(damaged))
    result = open_and_read(path)
    if pos < head:  # the head: refused, or still readable (e.g. another serial number)
        if result is not None:
            assert [f.wire for f in result[1]] == [r.wire for r in raws]
        return
    assert result is not None
    reader, got = result
    record, offset = divmod(pos - head, 8 + FRAME_SIZE)
    keep = [r.wire for i, r in enumerate(raws) if i != record or offset < 8]
    assert [f.wire for f in got] == keep
    assert reader.stats.damaged == (1 if offset >= 8 else 0)
    assert reader.stats.lost == (1 if offset >= 8 and 0 < record < 4 else 0)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=12,
)


GOOD_META = {
    "serial": "4000002F",
    "firmware": 0x104,
    "protocol": 1,
    "width": W,
    "height": H,
    "max_fps": 54,
    "registers": {"TRIGGER_MODE": 0},
}
tricky = st.sampled_from(
    ["-1", " 1_0", "0" * 9, "4000002f", "", True, 0, -5, 4097, 1.5, 2**70, "abc", None, [], {}]
)


@FAST
@given(
    st.dictionaries(
        st.sampled_from([*GOOD_META, "extra"]), st.one_of(tricky, json_values), max_size=2
    ),
    st.sets(st.sampled_from(list(GOOD_META)), max_size=1),
)
def test_any_metadata_is_refused_or_read_consistently(tmp_path, changes, removed):
    meta = {k: v for k, v in {**GOOD_META, **changes}.items() if k not in removed}
    path = tmp_path / "meta.tofcap"
    write_capture(path, 2, meta=meta)
    result = open_and_read(path)
    if result is not None:
        reader, got = result
        assert (reader.info.width, reader.info.height) == (W, H)
        assert 0 <= reader.info.serial <= 0xFFFFFFFF
        assert [f.sequence for f in got] == [0, 1]


def test_deeply_nested_metadata_is_a_capture_error(tmp_path):
    path = tmp_path / "nested.tofcap"
    meta = b"[" * 200_000 + b"]" * 200_000
    path.write_bytes(MAGIC + struct.pack("<I", len(meta)) + meta)
    with pytest.raises(CaptureError, match="JSON"):
        CaptureReader(path)


BIG_META = {"serial": "1", "firmware": 1, "protocol": 1, "width": 1448, "height": 1448,
            "registers": {}}  # fmt: skip
BIG_CALIB = CALIB_HEADER_SIZE + 2 * 1448 * 1448  # the largest sensor the protocol allows


@pytest.mark.parametrize(
    ("meta_len", "calib_len"),
    [(2**20, None), (None, 2**32 - 1), (None, BIG_CALIB)],
    ids=["metadata-longer-than-the-file", "calibration-length-wrong", "calibration-past-the-end"],
)
def test_lengths_in_the_file_are_checked_before_anything_is_allocated(
    tmp_path, meta_len, calib_len
):
    meta = json.dumps(BIG_META).encode()
    data = MAGIC + struct.pack("<I", meta_len or len(meta)) + meta
    if calib_len is not None:
        data += struct.pack("<I", calib_len) + bytes(100)
    path = tmp_path / "lengths.tofcap"
    path.write_bytes(data)
    tracemalloc.start()
    try:
        with pytest.raises(CaptureError):
            CaptureReader(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200_000  # the lengths claim up to 4 GiB; nothing near that is touched


@pytest.mark.parametrize("size", [(4096, 4096), (2048, 1025), (1449, 1448)])
def test_a_sensor_larger_than_the_protocol_allows_is_refused(tmp_path, size):
    """READ_FLASH's 16-bit block number bounds the calibration block, so the pixels."""
    w, h = size
    assert w * h > MAX_SENSOR_PIXELS
    meta = json.dumps({**BIG_META, "width": w, "height": h}).encode()
    path = tmp_path / "big.tofcap"
    path.write_bytes(MAGIC + struct.pack("<I", len(meta)) + meta)
    with pytest.raises(CaptureError, match=f"more than {MAX_SENSOR_PIXELS} pixels"):
        CaptureReader(path)
    info = DeviceInfo(1, 1, 1, w, h, CALIB_HEADER_SIZE + 2 * w * h, 54)
    with pytest.raises(ProtocolError, match="pixels"):
        parse_info(pack_info(info))
    header = struct.pack("<4sHHHHB3x9ff4x", b"SRCB", 1, CALIB_HEADER_SIZE, w, h, 1, *[1.0] * 10)
    with pytest.raises(ProtocolError, match="pixels"):
        parse_calibration(header + struct.pack("<I", 0))


def test_the_largest_sensor_is_1448_square():
    assert 1448 * 1448 <= MAX_SENSOR_PIXELS < 1449 * 1448
    assert CALIB_HEADER_SIZE + 2 * MAX_SENSOR_PIXELS <= 64 * 0x10000


# --- the calibration reader ---------------------------------------------------------------


@FAST
@given(st.binary(max_size=300), st.sampled_from([(None, None), (W, H), (1, 1)]))
def test_random_calibration_bytes_are_a_protocol_error(data, size):
    with pytest.raises(ProtocolError):
        parse_calibration(data, *size)


@FAST
@given(pos=st.integers(0, len(CALIB) - 1), xor=st.integers(1, 255))
def test_any_flipped_byte_in_a_calibration_block_is_caught(pos, xor):
    damaged = bytearray(CALIB)
    damaged[pos] ^= xor
    with pytest.raises(ProtocolError):
        parse_calibration(bytes(damaged), W, H)


@FAST
@given(st.integers(0, len(CALIB) - 1), st.binary(max_size=4))
def test_a_calibration_block_cut_or_grown_is_caught(cut, extra):
    with pytest.raises(ProtocolError):
        parse_calibration(CALIB[:cut], W, H)
    if extra:
        with pytest.raises(ProtocolError):
            parse_calibration(CALIB + extra, W, H)


any_f32 = st.floats(width=32)
CALIB_BAD = {
    "version": st.integers(0, 65535).filter(lambda v: v != 1),
    "header": st.integers(0, 65535).filter(lambda v: v != CALIB_HEADER_SIZE),
    "size": st.sampled_from([(0, 3), (3, 0), (65535, 65535), (W + 1, H)]),
    "mod_code": st.integers(0, 255).filter(lambda code: code not in MOD_FREQ_MHZ),
    "focal": st.lists(any_f32, min_size=2, max_size=2),
    "centre": st.lists(any_f32, min_size=2, max_size=2),
    "lens": st.lists(any_f32, min_size=6, max_size=6),
}


@st.composite
def calibration_blocks(draw: st.DrawFn) -> tuple[dict, bytes]:
    """A block with a valid CRC: plausible fields, except a few drawn from anywhere."""
    broken = draw(st.sets(st.sampled_from(list(CALIB_BAD)), max_size=2))
    fields = {
        "version": 1,
        "header": CALIB_HEADER_SIZE,
        "size": draw(st.sampled_from([(W, H), (1, 1), (5, 3)])),
        "mod_code": draw(st.sampled_from(sorted(MOD_FREQ_MHZ))),
        "focal": draw(st.lists(st.floats(0.5, 1e4, width=32), min_size=2, max_size=2)),
        "centre": draw(st.lists(st.floats(-10, 20, width=32), min_size=2, max_size=2)),
        "lens": draw(st.lists(st.floats(-1, 1, width=32), min_size=6, max_size=6)),
    }
    for name in broken:
        fields[name] = draw(CALIB_BAD[name])
    w, h = fields["size"]
    floats = fields["focal"] + fields["centre"] + fields["lens"]
    head = struct.pack(
        "<4sHHHHB3x10f4x", b"SRCB", fields["version"], fields["header"], w, h,
        fields["mod_code"], *floats,
    )  # fmt: skip
    body = np.arange(min(h, 16) * min(w, 16), dtype="<i2").tobytes()
    return fields, head + struct.pack("<I", crc32(head + body)) + body


@settings(FAST, max_examples=80)
@given(calibration_blocks())
def test_a_calibration_block_with_a_valid_crc_but_any_fields(case):
    """Past its CRC, a block is checked field by field; one that parses gives usable optics
    or a ProtocolError, never a crash or non-finite rays."""
    fields, block = case
    try:
        calib = parse_calibration(block)
    except ProtocolError:
        return
    assert (calib.width, calib.height) == fields["size"]
    assert calib.mod_code in MOD_FREQ_MHZ
    assert min(calib.fx, calib.fy) > 0
    with np.errstate(all="ignore"):
        try:
            optics = Optics.from_calibration(calib)
        except ProtocolError:
            return
    assert optics.rays.shape == (*reversed(fields["size"]), 3)
    assert np.isfinite(optics.rays).all()
    np.testing.assert_allclose(np.linalg.norm(optics.rays, axis=-1), 1.0)
