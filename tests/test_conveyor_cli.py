"""The conveyor on the command line: `tofcut ports`, the options, and the emulated line."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader
from serial.tools.list_ports_common import ListPortInfo

from tofcut.driver.belt import BeltReading
from tofcut.driver.conveyor.reject_rule import TrackMeasures
from tofcut.driver.conveyor.rejects import RejectEvent
from tofcut.driver.errors import ConfigError
from tofcut.tools.cli import main
from tofcut.tools.commands.ports import describe_port
from tofcut.tools.pipeline.conveyor_line import (
    add_conveyor_options,
    conveyor_config,
    log_reading,
    log_reject,
    open_conveyor,
)
from tofcut.tracker.tracks import Track

WAIT_S = 5.0


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_conveyor_options(parser)
    return parser.parse_args(argv)


def test_tofcut_ports_lists_what_the_system_has(capsys):
    assert main(["ports"]) == 0
    assert capsys.readouterr().out.strip()  # a port per line, or "no serial ports found"
    port = ListPortInfo("/dev/ttyUSB0")
    port.vid, port.pid, port.serial_number, port.description = 0x0403, 0x6001, "A10K", "FT232R"
    assert describe_port(port) == "/dev/ttyUSB0  usb 0403:6001  serial A10K  FT232R"


def test_options_override_the_map_file(tmp_path):
    path = tmp_path / "line.toml"
    path.write_text('[link]\nparity = "O"\nbaudrate = 9600\n[belt]\ndiverter_m = 2.0\n')
    args = parse("--conveyor", "/dev/ttyUSB3", "--conveyor-map", str(path), "--baud", "57600",
                 "--diverter-distance", "1.5")  # fmt: skip
    config = conveyor_config(args, args.conveyor)
    assert (config.link.port, config.link.baudrate, config.link.parity) == (
        "/dev/ttyUSB3", 57600, "O",
    )  # fmt: skip
    assert config.diverter_m == 1.5


def test_no_conveyor_unless_asked():
    assert open_conveyor(parse()) is None
    with pytest.raises(ConfigError, match="--reject needs a conveyor"):
        open_conveyor(parse("--reject", "height > 0.1"))
    with pytest.raises(ConfigError, match="not both"):
        open_conveyor(parse("--conveyor", "/dev/null", "--conveyor-emulator"))


@pytest.mark.tofcut_camera("conveyor", realtime=True)
def test_the_emulated_line_follows_the_emulated_scene(tofcut_camera):
    opened = tofcut_camera.opened
    camera = opened.emulator
    args = parse("--conveyor-emulator", "--reject", "height > 0.2", "--diverter-distance", "1.0")
    with open_conveyor(args, opened) as line:
        reading = line.client.wait_for(lambda r: True, WAIT_S)
        assert reading.speed_mps == pytest.approx(0.25)  # the scene's belt speed
        # The controller's belt runs on the camera's clock: travel = speed × device time.
        assert line.emulated.distance_m() == pytest.approx(0.25 * camera.now_us() * 1e-6, abs=0.01)
        with opened.device as cam:
            (frame,) = cam.frames(count=1)
        assert line.frame_time_ns(frame) <= frame.host_time_ns  # taken before it arrived
        prior = line.velocity_prior(frame)
        np.testing.assert_allclose(prior.mean, [0.25, 0.0, 0.0], atol=1e-12)
        assert line.rejects.rule.text == "height > 0.2"
        assert line.rejects.diverter_m == 1.0
        assert "conveyor " in line.summary()
        assert "rejects: 0 fired" in line.summary()


def test_rejects_and_readings_show_in_rerun(tmp_path):
    rec = rr.RecordingStream("tofcut-test")
    memory = rr.memory_recording(rec)
    reading = BeltReading(1_700_000_000_000_000_000, 1234, 0.1234, 0.25, True, False)
    track = Track(3, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), (0, 0, 1, 1), 10,
                  np.zeros((10, 3), np.float32))  # fmt: skip
    measures = TrackMeasures(3, 0.12, 0.2, 0.1, 0.02, 0.0024, 10, 0.5, track)
    event = RejectEvent(3, 1.5, 1.503, 15030, reading.time_ns, measures)
    log_reading(reading, rec)
    log_reject(event, rec)
    path = tmp_path / "line.rrd"
    path.write_bytes(memory.drain_as_bytes())
    logged = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name.startswith(("Scalars:", "TextLog:text")):
                logged[chunk.entity_path] = batch.column(name).to_pylist()
    assert logged["/conveyor/speed_mps"] == [[0.25]]
    assert logged["/conveyor/distance_m"] == [[0.1234]]
    (text,) = logged["/conveyor/rejects"]
    assert text[0].startswith("reject track 3: height 0.120 m")
    assert "encoder 15030" in text[0]
