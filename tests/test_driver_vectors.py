"""The spec's normative vectors (copied from shared/spec/vectors into tests/vectors)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tofcut.driver.calibration import pack_calibration, parse_calibration
from tofcut.driver.capture import CaptureReader
from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.errors import CaptureError, ProtocolError
from tofcut.driver.frames import RawFrame
from tofcut.driver.protocol import HEADER_SIZE, pack_header, pack_info, parse_header, parse_info

VECTORS = Path(__file__).parent / "vectors"
EXPECTED = json.loads((VECTORS / "expected.json").read_text())


def _frame_bytes() -> bytes:
    return (VECTORS / "frame_8x6.bin").read_bytes()


def _calib():
    return parse_calibration((VECTORS / "calib_8x6.bin").read_bytes(), 8, 6)


def _raw() -> RawFrame:
    data = _frame_bytes()
    header = parse_header(data)
    taps = np.frombuffer(data, "<u2", offset=HEADER_SIZE).reshape(4, 6, 8)
    return RawFrame(header, taps, data, 0)


def test_get_info_example_round_trips_bit_for_bit():
    data = bytes.fromhex(EXPECTED["get_info_example_hex"])
    info = parse_info(data)
    assert (info.serial_text, info.width, info.height, info.max_fps) == ("4000002F", 176, 144, 54)
    assert info.firmware == 0x0104
    assert pack_info(info) == data


def test_get_info_rejects_a_bad_crc():
    data = bytearray.fromhex(EXPECTED["get_info_example_hex"])
    data[9] ^= 1
    with pytest.raises(ProtocolError, match="CRC"):
        parse_info(bytes(data))


def test_calibration_parses_and_packs_bit_for_bit():
    data = (VECTORS / "calib_8x6.bin").read_bytes()
    calib = parse_calibration(data, 8, 6)
    want = EXPECTED["calib_8x6.bin"]
    assert calib.fx == pytest.approx(want["fx"])
    assert calib.fy == pytest.approx(want["fy"])
    assert (calib.cx, calib.cy) == pytest.approx((want["cx"], want["cy"]))
    assert calib.distortion == pytest.approx(tuple(want["k1k2p1p2k3"]))
    assert calib.distance_offset_m == pytest.approx(want["distance_offset_m"])
    assert calib.mod_code == want["mod_freq_code"]
    assert pack_calibration(calib) == data


def test_calibration_rejects_a_bad_crc_and_a_wrong_sensor():
    data = bytearray((VECTORS / "calib_8x6.bin").read_bytes())
    with pytest.raises(ProtocolError, match="is for 8x6"):
        parse_calibration(bytes(data), 176, 144)
    data[100] ^= 0xFF
    with pytest.raises(ProtocolError, match="CRC"):
        parse_calibration(bytes(data), 8, 6)


def test_frame_header_parses_and_packs_bit_for_bit():
    data = _frame_bytes()
    header = parse_header(data)
    want = EXPECTED["frame_8x6.bin"]["header"]
    got = {
        "seq": header.sequence,
        "ts_us": header.device_time_us,
        "mod_code": header.mod_code,
        "integ": header.integration,
        "flags": header.flags,
        "temp": header.temperature_c,
        "tap_interval_us": header.tap_interval_us,
    }
    assert got == want
    assert pack_header(header) == data[:HEADER_SIZE]


@pytest.mark.parametrize("name", ["phase", "amplitude", "intensity", "range", "xyz"])
def test_demodulation_matches_the_expected_arrays(name):
    frame = demodulate(_raw(), Optics.from_calibration(_calib()))
    want = np.array(EXPECTED["frame_8x6.bin"][name])
    tolerance = {"range": 1e-6, "amplitude": 1e-5, "xyz": 1e-6}.get(name, 1e-6)
    np.testing.assert_allclose(getattr(frame, name), want, rtol=0, atol=tolerance)


def test_valid_mask_matches():
    frame = demodulate(_raw(), Optics.from_calibration(_calib()))
    np.testing.assert_array_equal(frame.valid, np.array(EXPECTED["frame_8x6.bin"]["valid"]))


def test_small_capture_replays_as_the_spec_says():
    reader = CaptureReader(VECTORS / "small.tofcap")
    want = EXPECTED["small.tofcap"]
    assert reader.capture.metadata == want["metadata"]
    frames = list(reader.frames())
    assert [f.sequence for f in frames] == [w["header"]["seq"] for w in want["frames_read"]]
    for frame, w in zip(frames, want["frames_read"], strict=True):
        assert frame.header.flags == w["header"]["flags"]
        assert frame.device_time_us == w["header"]["ts_us"]
        np.testing.assert_allclose(frame.range, np.array(w["range"]), atol=1e-6, rtol=0)
        np.testing.assert_allclose(frame.amplitude, np.array(w["amplitude"]), atol=1e-5, rtol=0)
        np.testing.assert_array_equal(frame.valid, np.array(w["valid"]))
        np.testing.assert_allclose(frame.xyz, np.array(w["xyz"]), atol=1e-6, rtol=0)
    assert reader.stats.damaged == want["damaged_frames_dropped"] == 1
    assert reader.stats.lost == 1
    assert list(reader.stats.gaps) == [(2, 2)]
    assert reader.truncated_bytes > 0


def test_a_capture_with_another_magic_is_refused(tmp_path):
    bad = tmp_path / "bad.tofcap"
    data = bytearray((VECTORS / "small.tofcap").read_bytes())
    data[0:8] = b"NOTACAP!"
    bad.write_bytes(bytes(data))
    with pytest.raises(CaptureError, match="magic"):
        CaptureReader(bad)


def test_vectors_copy_matches_the_shared_spec_when_present():
    """tests/vectors is a copy; if the shared spec sits beside the repository, they agree."""
    shared = Path(__file__).resolve().parents[2] / "shared" / "spec" / "vectors"
    if not shared.is_dir():
        shared = VECTORS  # a clone without shared/: the copy is all there is
    for path in VECTORS.iterdir():
        assert (shared / path.name).read_bytes() == path.read_bytes(), path.name
