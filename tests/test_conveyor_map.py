"""The conveyor as configuration and values: register map, TOML file, belt history, geometry."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest

from tofcut.driver.belt import BeltGeometry, BeltHistory, BeltReading, unwrap_count
from tofcut.driver.conveyor.config import (
    LinkSettings,
    RegisterMap,
    load_conveyor_config,
    parse_conveyor_config,
)
from tofcut.driver.conveyor.exposure_clock import ExposureClock
from tofcut.driver.errors import ConfigError
from tofcut.sim.catalog import open_scene
from tofcut.sim.conveyor import belt_geometry

MAP_FILE = """
[link]
port = "/dev/ttyUSB1"
baudrate = 38400
parity = "N"
unit = 7
poll_hz = 100

[registers]
encoder = 100
encoder_words = "low-first"
speed = 102
status = 103
diverter = 200
heartbeat = 201
counts_per_m = 4096
speed_unit_mps = 0.01

[belt]
direction = [1, 0, 0]
normal = [0, -1, -1]
point = [0, 0.5, 1.5]
diverter_m = 1.25
"""


def test_the_default_map():
    m = RegisterMap()
    assert m.addresses() == {"encoder": 0, "speed": 2, "status": 3, "diverter": 10, "heartbeat": 11}
    assert m.read_plan() == [(0, 4)]  # one request: encoder, speed and status together
    assert m.encoder_registers(0x0001_2345) == (0x0001, 0x2345)
    assert m.encoder_count(0x0001, 0x2345) == 0x0001_2345
    assert m.speed_register(0.25) == 250
    assert m.speed_mps(m.speed_register(-0.12)) == pytest.approx(-0.12)
    assert m.speed_register(100.0) == 0x7FFF  # saturates rather than wrapping
    assert m.status_word(running=True, fault=True) == 0b11
    link = LinkSettings(port="/dev/ttyUSB0")
    assert (link.baudrate, link.parity, link.bytesize, link.stopbits, link.unit) == (
        19200, "E", 8, 1, 1,
    )  # fmt: skip


def test_the_read_plan_keeps_the_encoder_in_one_request():
    m = RegisterMap(encoder=500, speed=0, status=502, diverter=20, heartbeat=21)
    assert m.read_plan() == [(0, 1), (500, 3)]
    m = RegisterMap(encoder=9, speed=3, status=1, diverter=20, heartbeat=21)
    assert m.read_plan() == [(1, 10)]


def test_a_map_file(tmp_path):
    path = tmp_path / "line.toml"
    path.write_text(MAP_FILE)
    config = load_conveyor_config(path)
    assert config.link == LinkSettings(
        port="/dev/ttyUSB1", baudrate=38400, parity="N", unit=7, poll_hz=100.0
    )
    assert config.registers.encoder_count(0x2345, 0x0001) == 0x0001_2345
    assert config.registers.counts_per_m == 4096.0
    assert config.diverter_m == 1.25
    # The optical axis meets the 45° belt plane through (0, 0.5, 1.5) at z = 2.
    np.testing.assert_allclose(config.belt.origin, [0.0, 0.0, 2.0])
    np.testing.assert_allclose(config.belt.normal, [0.0, -(0.5**0.5), -(0.5**0.5)])


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"link": {"parity": "X"}}, "parity must be N, E or O"),
        ({"link": {"baud": 9600}}, "unknown key 'baud'; did you mean baudrate?"),
        ({"link": {"unit": 0}}, "unit must be an integer in 1..247"),
        ({"link": {"poll_hz": 0}}, "poll_hz must be in 0.1..1000"),
        ({"link": {"poll_hz": 1e300}}, "poll_hz must be in 0.1..1000"),
        ({"link": {"poll_hz": 10**400}}, "poll_hz must be a finite number"),
        ({"link": {"timeout_s": 60}}, "timeout_s must be in 0.001..10"),
        ({"link": {"timeout_s": 1e-7}}, "timeout_s must be in 0.001..10"),
        ({"link": {"heartbeat_s": 1e-6}}, "heartbeat_s must be in 0.01..3600 (or 0: none)"),
        ({"link": {"heartbeat_s": -1}}, "heartbeat_s must be in 0.01..3600"),
        ({"link": {"reopen_s": 1e9}}, "reopen_s must be in 0.01..60"),
        ({"link": {"port": "tcp://:x"}}, "is not tcp://HOST:PORT"),
        ({"registers": {"speed": 1}}, "registers overlap"),
        ({"registers": {"encoder": 65535}}, "needs two registers"),
        ({"registers": {"counts_per_m": 0}}, "counts_per_m must be a positive number"),
        ({"registers": {"encoder_words": "middle"}}, "encoder_words"),
        ({"registers": {"diverter": "ten"}}, "must be an integer"),
        ({"belt": {"direction": [1, 0, 0]}}, "give direction, normal and point together"),
        ({"belt": {"direction": [0, 0, 1], "normal": [0, 0, 1], "point": [0, 0, 1]}},
         "must not be along its normal"),
        ({"conveyor": {}}, "unknown table [conveyor]; known: [belt], [link], [registers]"),
        ({"links": {}}, "unknown table [links]; did you mean [link]?"),
    ],
)  # fmt: skip
def test_bad_map_files_are_refused_clearly(doc, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_conveyor_config(doc)


def test_a_missing_or_broken_map_file(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.toml"):
        load_conveyor_config(tmp_path / "nope.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[link\n")
    with pytest.raises(ConfigError, match=r"broken\.toml"):
        load_conveyor_config(broken)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "not a text file"),
        (b"[link]\nport = '\x00'\n", "not a text file"),
        (b"a = " + b"[" * 5000 + b"]" * 5000, "nested too deep"),
        (b"# " + b"x" * (2 << 20), "larger than"),
        (b"[link]\npoll_hz = " + b"9" * 5000, "integer string conversion"),
    ],
    ids=["binary", "nul", "deep", "huge", "long-int"],
)
def test_a_map_file_that_is_not_a_map_is_a_one_line_error(tmp_path, data, message):
    path = tmp_path / "map.toml"
    path.write_bytes(data)
    with pytest.raises(ConfigError, match=re.escape(message)) as info:
        load_conveyor_config(path)
    assert "\n" not in str(info.value)
    assert str(info.value).startswith(str(path))


def test_tcp_addresses():
    assert LinkSettings(port="tcp://10.0.0.5:1502").tcp_address() == ("10.0.0.5", 1502)
    assert LinkSettings(port="tcp://gateway").tcp_address() == ("gateway", 502)
    assert not LinkSettings(port="/dev/ttyUSB0").is_tcp


def test_encoder_unwrapping():
    assert unwrap_count(None, None, 123) == 123
    assert unwrap_count(2**32 - 10, 2**32 - 10, 5) == 2**32 + 5  # forward through the wrap
    assert unwrap_count(2**32 + 5, 5, 2**32 - 10) == 2**32 - 10  # and back
    assert unwrap_count(100, 100, 40) == 40  # a belt may run backwards


def reading(t_ns: int, distance: float, speed: float = 0.5) -> BeltReading:
    return BeltReading(t_ns, round(distance * 1e4), distance, speed, True, False)


def test_the_belt_at_a_frame_time_is_interpolated_between_readings():
    h = BeltHistory(capacity=3, max_extrapolation_s=0.1)
    assert h.at(0) is None
    for t, d in [(0, 0.0), (20_000_000, 0.01), (40_000_000, 0.02), (60_000_000, 0.03)]:
        h.append(reading(t, d))
    assert len(h) == 3  # the oldest went
    assert h.at(10_000_000) is None  # before the history
    assert h.at(30_000_000).distance_m == pytest.approx(0.015)
    assert h.at(30_000_000).count == 100  # count and speed: the reading before
    assert h.at(60_000_000 + 50_000_000).distance_m == pytest.approx(0.055)  # extrapolated
    assert h.at(60_000_000 + 150_000_000) is None  # too long after the last: unknown
    with pytest.raises(ValueError, match="time order"):
        h.append(reading(0, 0.0))


def test_the_emulated_scene_belt_in_camera_coordinates():
    scene = open_scene("conveyor").scene
    g = belt_geometry(scene)
    # The scene's world x is the camera's x; the belt's top (z = 0) is 0 m high.
    np.testing.assert_allclose(g.direction, [1.0, 0.0, 0.0], atol=1e-12)
    world_point = np.array([0.3, 0.1, 0.0])
    cam = scene.camera_from_world.apply(world_point)
    assert float(g.height(cam)) == pytest.approx(0.0, abs=1e-12)
    assert float(g.along(cam) - g.along(scene.camera_from_world.apply(np.zeros(3)))) == (
        pytest.approx(0.3)
    )
    above = scene.camera_from_world.apply(world_point + np.array([0.0, 0.0, 0.14]))
    assert float(g.height(above)) == pytest.approx(0.14)
    # The zero of along-belt positions is on the camera's optical axis.
    np.testing.assert_allclose(g.origin[:2], [0.0, 0.0], atol=1e-12)


def test_geometry_from_a_plane_is_orthonormal():
    g = BeltGeometry.from_plane(np.array([1.0, 0.2, 0.1]), np.array([0, -2.0, -1.0]),
                                np.array([0.0, 0.0, 2.0]))  # fmt: skip
    assert np.linalg.norm(g.direction) == pytest.approx(1.0)
    assert g.direction @ g.normal == pytest.approx(0.0, abs=1e-12)
    assert float(g.height(g.origin)) == 0.0


def fake_frame(sequence: int, device_ms: float, delay_ms: float, host0_ns: int = 10**18):
    """A frame as the exposure clock sees it: taps of 2 ms (integration 17), 3 ms apart."""
    header = SimpleNamespace(
        device_time_us=round(device_ms * 1000), tap_interval_us=3000, integration=17
    )
    mid_ms = device_ms + 1.5 * 3 + 1.0
    host = host0_ns + round((mid_ms + delay_ms) * 1e6)
    return SimpleNamespace(header=header, sequence=sequence, host_time_ns=host)


def test_the_exposure_clock_removes_the_delay_of_the_quickest_frame():
    clock = ExposureClock(window=3)
    delays = [30.0, 12.0, 50.0, 12.5, 40.0, 45.0, 41.0]
    times = []
    for i, delay in enumerate(delays):
        frame = fake_frame(i, 20.0 * i, delay)
        times.append(clock.host_time_ns(frame))
        assert clock.host_time_ns(frame) == times[-1]  # asking twice changes nothing
    true_mid = [10**18 + round((20.0 * i + 5.5) * 1e6) for i in range(len(delays))]
    # Each frame is placed as if it had come as quickly as the quickest of the last three.
    quickest = [30.0, 12.0, 12.0, 12.0, 12.5, 12.5, 40.0]
    for t, mid, q in zip(times, true_mid, quickest, strict=True):
        assert t == mid + round(q * 1e6)
    restarted = fake_frame(0, 0.0, 25.0, host0_ns=2 * 10**18)  # the camera's clock restarts
    assert clock.host_time_ns(restarted) == 2 * 10**18 + round((5.5 + 25.0) * 1e6)
