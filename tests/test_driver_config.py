"""The typed camera configuration: conversions and helpful refusals."""

from __future__ import annotations

import pytest

from tofcut.driver.config import CameraConfig, TriggerMode
from tofcut.driver.errors import ConfigError
from tofcut.driver.protocol import Register


def test_defaults_are_the_reset_values():
    config = CameraConfig()
    assert config.registers() == {
        Register.MOD_FREQ: 1,
        Register.INTEGRATION: 30,
        Register.FRAME_PERIOD: 200,
        Register.TRIGGER_MODE: 0,
    }
    assert config.mod_freq_mhz == 30.0
    assert config.integration_ms == pytest.approx(3.3)
    assert config.frame_rate == pytest.approx(50.0)


def test_physical_values_become_registers():
    config = CameraConfig.make(
        mod_freq_mhz=14.5, integration_ms=5.0, frame_rate=25, trigger_mode="software"
    )
    assert config.registers() == {
        Register.MOD_FREQ: 10,
        Register.INTEGRATION: 47,
        Register.FRAME_PERIOD: 400,
        Register.TRIGGER_MODE: 1,
    }
    assert CameraConfig.from_registers(config.registers()) == config
    assert CameraConfig.make(frame_rate=0).frame_rate is None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"mod_freq_mhz": 20}, "not a modulation frequency"),
        ({"mod_freq_code": 3}, "not supported"),
        ({"integration_ms": 3.33}, "0.1 ms steps"),
        ({"integration_ms": 30}, "0.1 ms steps"),
        ({"frame_rate": 60}, "fps"),
        ({"trigger_mode": "sometimes"}, "free_run, software, hardware"),
        ({"mod_freq_mhz": 30, "mod_freq_code": 1}, "not both"),
    ],
)
def test_impossible_values_are_refused_with_a_reason(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        CameraConfig.make(**kwargs)


def test_frame_rate_is_capped_at_54():
    assert CameraConfig(frame_period=100).frame_rate == 54.0
    assert CameraConfig(trigger_mode=2).trigger_mode is TriggerMode.HARDWARE
