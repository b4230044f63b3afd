"""A typed camera configuration, checked before it reaches the camera's registers."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from tofcut.driver.errors import ConfigError
from tofcut.driver.protocol import (
    MAX_FPS,
    MAX_INTEGRATION,
    MOD_FREQ_MHZ,
    RESET_VALUES,
    Register,
    integration_us,
)


class TriggerMode(enum.IntEnum):
    FREE_RUN = 0
    SOFTWARE = 1
    """One frame per TRIGGER request."""
    HARDWARE = 2
    """One frame per pulse on the trigger input."""


FRAME_PERIOD_UNIT_S = 100e-6


@dataclass(frozen=True)
class CameraConfig:
    """The writable registers as values; build one with `CameraConfig.make(...)`.

    Defaults are the camera's reset values: 30 MHz, 3.3 ms integration, 50 fps, free run.
    """

    mod_freq_code: int = RESET_VALUES[Register.MOD_FREQ]
    integration: int = RESET_VALUES[Register.INTEGRATION]
    """INTEGRATION register: each tap integrates 0.3 ms + n × 0.1 ms."""
    frame_period: int = RESET_VALUES[Register.FRAME_PERIOD]
    """FRAME_PERIOD register in units of 100 µs; 0 is as fast as the integration allows."""
    trigger_mode: TriggerMode = TriggerMode.FREE_RUN

    def __post_init__(self) -> None:
        if self.mod_freq_code not in MOD_FREQ_MHZ:
            raise ConfigError(
                f"modulation frequency code {self.mod_freq_code} is not supported; "
                f"choose one of {sorted(MOD_FREQ_MHZ)}"
            )
        if not 0 <= self.integration <= MAX_INTEGRATION:
            raise ConfigError(f"integration register {self.integration} is outside 0..255")
        if not 0 <= self.frame_period <= 0xFFFF:
            raise ConfigError(f"frame period register {self.frame_period} is outside 0..65535")
        object.__setattr__(self, "trigger_mode", TriggerMode(self.trigger_mode))

    @classmethod
    def make(
        cls,
        *,
        mod_freq_mhz: float | None = None,
        mod_freq_code: int | None = None,
        integration_ms: float | None = None,
        frame_rate: float | None = None,
        trigger_mode: TriggerMode | int | str = TriggerMode.FREE_RUN,
    ) -> CameraConfig:
        """Build a configuration from physical values; unset ones keep the reset values.

        `frame_rate` is in frames per second; 0 means as fast as the integration allows.
        """
        if mod_freq_mhz is not None and mod_freq_code is not None:
            raise ConfigError("give the modulation frequency in MHz or as a code, not both")
        code = RESET_VALUES[Register.MOD_FREQ] if mod_freq_code is None else mod_freq_code
        if mod_freq_mhz is not None:
            code = mod_freq_code_for(mod_freq_mhz)
        integration = RESET_VALUES[Register.INTEGRATION]
        if integration_ms is not None:
            integration = integration_for(integration_ms)
        period = RESET_VALUES[Register.FRAME_PERIOD]
        if frame_rate is not None:
            period = frame_period_for(frame_rate)
        if isinstance(trigger_mode, str):
            try:
                trigger_mode = TriggerMode[trigger_mode.upper().replace("-", "_")]
            except KeyError:
                names = ", ".join(m.name.lower() for m in TriggerMode)
                raise ConfigError(f"trigger mode {trigger_mode!r} is not one of {names}") from None
        return cls(code, integration, period, TriggerMode(trigger_mode))

    @property
    def mod_freq_mhz(self) -> float:
        return MOD_FREQ_MHZ[self.mod_freq_code]

    @property
    def integration_ms(self) -> float:
        return integration_us(self.integration) / 1000.0

    @property
    def frame_rate(self) -> float | None:
        """Asked-for frames per second (capped at 54 by the camera); None for 'as fast as'."""
        if self.frame_period == 0:
            return None
        return min(float(MAX_FPS), 1.0 / (self.frame_period * FRAME_PERIOD_UNIT_S))

    def registers(self) -> dict[Register, int]:
        return {
            Register.MOD_FREQ: self.mod_freq_code,
            Register.INTEGRATION: self.integration,
            Register.FRAME_PERIOD: self.frame_period,
            Register.TRIGGER_MODE: int(self.trigger_mode),
        }

    @classmethod
    def from_registers(cls, regs: dict[Register, int]) -> CameraConfig:
        return cls(
            regs[Register.MOD_FREQ],
            regs[Register.INTEGRATION],
            regs[Register.FRAME_PERIOD],
            TriggerMode(regs[Register.TRIGGER_MODE]),
        )

    def describe(self) -> str:
        rate = "max" if self.frame_rate is None else f"{self.frame_rate:g} fps"
        return (
            f"{self.mod_freq_mhz:g} MHz, integration {self.integration_ms:.1f} ms, {rate}, "
            f"trigger {self.trigger_mode.name.lower()}"
        )


def mod_freq_code_for(mhz: float) -> int:
    for code, value in MOD_FREQ_MHZ.items():
        if math.isclose(value, mhz, abs_tol=1e-6):
            return code
    choices = ", ".join(f"{v:g}" for v in sorted(MOD_FREQ_MHZ.values()))
    raise ConfigError(f"{mhz:g} MHz is not a modulation frequency of this camera ({choices})")


def integration_for(ms: float) -> int:
    n = (ms - 0.3) / 0.1
    rounded = round(n)
    if not 0 <= rounded <= MAX_INTEGRATION or abs(n - rounded) > 1e-6:
        raise ConfigError(
            f"integration time {ms:g} ms is not 0.3 ms + n × 0.1 ms with n in 0..255 "
            "(0.3 to 25.8 ms in 0.1 ms steps)"
        )
    return rounded


def frame_period_for(fps: float) -> int:
    if fps == 0:
        return 0
    if not 0 < fps <= MAX_FPS:
        raise ConfigError(f"frame rate {fps:g} fps is outside 0 < fps <= {MAX_FPS}")
    period = round(1.0 / (fps * FRAME_PERIOD_UNIT_S))
    if period > 0xFFFF:
        raise ConfigError(f"frame rate {fps:g} fps is too slow (at least 0.153 fps)")
    return period
