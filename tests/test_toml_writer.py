"""The package's TOML writer (`tofcut.driver.toml_writer`), for conveyor maps and scene files:
`tomllib` reads back what it wrote."""

from __future__ import annotations

import math
import tomllib

import pytest

from tofcut.driver.conveyor.config import parse_conveyor_config
from tofcut.driver.toml_writer import dumps


def test_the_toml_writer_round_trips_a_map():
    doc = {
        "link": {"port": 'C:\\ports\\"com3"\n', "baudrate": 38400, "timeout_s": 0.1, "parity": "E"},
        "registers": {"encoder": 100, "counts_per_m": 4096.0, "speed_unit_mps": 1e-05},
        "belt": {
            "direction": [1.0, 1.9e-05, -0.0], "normal": [0, -1, -1], "point": [0.0, 0.5, 1.5],
            "width_m": 0.6, "diverter_m": 1.25,
        },
    }  # fmt: skip
    text = dumps(doc, {"belt": ["speed found: 0.25 m/s"]})
    assert tomllib.loads(text) == doc
    assert "# speed found: 0.25 m/s" in text
    config = parse_conveyor_config(tomllib.loads(text))
    assert config.link.port == doc["link"]["port"]
    assert config.belt is not None
    assert config.belt.width_m == 0.6
    assert config.diverter_m == 1.25


def test_the_toml_writer_writes_plain_values_odd_keys_and_special_floats():
    doc = {"title": "x", "on": True, "odd key": {"a.b": [1, 2.5, "s", False], "n": math.inf}}
    back = tomllib.loads(dumps(doc))
    assert back == doc
    assert math.isnan(tomllib.loads(dumps({"t": {"x": math.nan}}))["t"]["x"])
    assert tomllib.loads(dumps({"t": {"c": "\x01\x7f\té"}})) == {"t": {"c": "\x01\x7f\té"}}


def test_the_toml_writer_writes_a_scene_files_nesting():
    doc = {
        "name": "line",
        "camera": {"position": [0.0, -0.5, 1.2], "lens": {"k1": -0.2}},
        "object": [
            {"name": "arm", "swing": {"axis": [0, 0, 1]}, "part": [{"shape": "capsule"}, {}]},
            {"name": "walker", "waypoints": [[0.0, 1.0, 2.0, 0.0, 90.0], [1.0, 2, 3, 0, 0]]},
        ],
        "empty": {},
    }
    text = dumps(doc, {"": ["a scene", ""]})
    assert tomllib.loads(text) == doc
    assert text.startswith("# a scene\n#\n")


@pytest.mark.parametrize("bad", [{"t": {"x": None}}, {"": 1}, {"t": {"x": [{"a": 1}, 2]}}])
def test_the_toml_writer_refuses_what_toml_does_not_hold(bad):
    with pytest.raises(ValueError, match=r"cannot write|key|tables may hold nothing else"):
        dumps(bad)
