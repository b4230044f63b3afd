"""`devices --json` and `info --json` through the command line: one JSON object each, of
the shape their help documents."""

from __future__ import annotations

import json

import pytest

from tofcut.driver.capture import CaptureReader
from tofcut.tools.cli import main


def printed_json(capsys, argv: list[str]) -> dict:
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)  # the whole of stdout is one object


def test_devices_json_lists_the_emulated_camera(capsys):
    out = printed_json(capsys, ["devices", "--emulator", "--json"])
    assert set(out) == {"cameras", "errors"}
    (cam,) = [c for c in out["cameras"] if c["bus"] == "emulator"]
    assert cam["source"] == "emulator"
    assert (cam["width"], cam["height"], cam["error"]) == (176, 144, None)
    assert cam["firmware"] == f"{cam['firmware_code'] >> 8:x}.{cam['firmware_code'] & 0xFF:02x}"
    assert isinstance(cam["serial"], str)
    assert isinstance(cam["usb_bus"], int)
    assert isinstance(cam["usb_address"], int)
    for error in out["errors"]:  # here: no libusb, or no camera on it
        assert set(error) == {"bus", "error"}
    printed_json(capsys, ["info", cam["source"], "--json"])  # its source opens it


def test_info_json_of_a_camera(capsys):
    out = printed_json(capsys, ["info", "emulator", "--json", "--mod-freq", "15"])
    assert out["kind"] == "camera"
    assert out["source"] == "emulator"
    assert out["configuration"]["mod_freq_mhz"] == 15
    assert out["configuration"]["unambiguous_range_m"] == pytest.approx(9.993, abs=1e-3)
    assert set(out["registers"]) >= {"MOD_FREQ", "INTEGRATION", "FRAME_PERIOD", "TRIGGER_MODE"}
    assert isinstance(out["temperature_c"], float)
    assert out["records"] is None
    calib = out["calibration"]
    assert (calib["width"], calib["height"]) == (out["width"], out["height"])
    assert len(calib["D"]) == 5
    assert calib["distortion_model"] == "plumb_bob"


def test_info_json_of_a_capture(capsys, tmp_path):
    path = tmp_path / "x.tofcap"
    assert main(["record", "emulator", "--frames", "3", "--fast", "-o", str(path)]) == 0
    capsys.readouterr()
    out = printed_json(capsys, ["info", str(path), "--json"])
    reader = CaptureReader(path)
    assert out["kind"] == "capture"
    assert out["source"] == str(path)
    assert out["records"] == 3
    assert out["configuration"] is None
    assert out["temperature_c"] is None
    assert out["registers"] == reader.capture.metadata["registers"]
    assert out["serial"] == reader.serial
    assert out["calibration"]["fx"] == pytest.approx(reader.calibration.fx)
