"""Tracker parameters from the command line: `tracker.PARAM=VALUE` (`tofcut track --set`)
and `tracker.PARAM=V1,V2,...` (`tofcut sweep --set`, several making a grid).

PARAM is a field of `TrackerParams` (`beta`, `object_cost`, ...) or of its parts
(`background.rate`, `motion.accel_sigma`); each value is read as the field's type and the
whole set checked by `TrackerParams` itself, so a bad one is a one-line error before any
work starts.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import itertools
import math
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from tofcut.driver.errors import TofcutError
from tofcut.tracker.params import TrackerParams

Value = bool | int | float
PREFIX = "tracker."
NOT_SET = {"rigid": "set by --deformable"}
"""Fields `--set` leaves alone, and why."""


def _fields(cls: type, prefix: str = "") -> dict[str, type]:
    """Every settable field of a parameters dataclass and its parts, by dotted name."""
    hints = typing.get_type_hints(cls)
    out: dict[str, type] = {}
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind):
            out.update(_fields(kind, f"{prefix}{f.name}."))  # type: ignore[arg-type]
        elif f"{prefix}{f.name}" not in NOT_SET:
            out[f"{prefix}{f.name}"] = kind
    return out


FIELDS = _fields(TrackerParams)
"""`TrackerParams`' settable fields: dotted name → type (bool, int or float)."""


class SettingError(TofcutError):
    """Settings that cannot go together (a usage error: exit status 2)."""

    exit_code = 2


@dataclass(frozen=True)
class Setting:
    """One parameter and the values it takes."""

    name: str
    """Dotted, without `tracker.`: `beta`, `background.rate`."""
    values: tuple[Value, ...]

    def __str__(self) -> str:
        return f"{PREFIX}{self.name}=" + ",".join(str(v) for v in self.values)


def _value(name: str, kind: type, text: str) -> Value:
    text = text.strip()
    if kind is bool:
        words = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False}
        if text.lower() not in words:
            raise argparse.ArgumentTypeError(f"{PREFIX}{name}: {text!r} is not true or false")
        return words[text.lower()]
    try:
        value = int(text) if kind is int else float(text)
    except ValueError:
        what = "a whole number" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"{PREFIX}{name}: {text!r} is not {what}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{PREFIX}{name}: {text!r} is not a finite number")
    return value


def setting(text: str) -> Setting:
    """`tracker.PARAM=V1,V2,...` (an argparse type): the parameter named and its values,
    each read as that parameter's type."""
    name, sep, values = text.partition("=")
    name = name.strip()
    if not sep or not name.startswith(PREFIX) or not values.strip():
        raise argparse.ArgumentTypeError(
            f"{text!r}: give tracker.PARAM=VALUE (or VALUE1,VALUE2,... to sweep)"
        )
    name = name.removeprefix(PREFIX)
    if name in NOT_SET:
        raise argparse.ArgumentTypeError(f"{PREFIX}{name} is {NOT_SET[name]}, not --set")
    if name not in FIELDS:
        near = difflib.get_close_matches(name, FIELDS, n=1)
        hint = f"did you mean {PREFIX}{near[0]}?" if near else f"they are: {', '.join(FIELDS)}"
        raise argparse.ArgumentTypeError(f"{PREFIX}{name} is not a tracker parameter ({hint})")
    parsed = tuple(_value(name, FIELDS[name], v) for v in values.split(","))
    return Setting(name, tuple(dict.fromkeys(parsed)))


def one_setting(text: str) -> Setting:
    """`tracker.PARAM=VALUE` (an argparse type): one value only."""
    s = setting(text)
    if len(s.values) != 1:
        raise argparse.ArgumentTypeError(f"{text!r}: one value here (several are for a sweep)")
    return s


def grid(settings: Sequence[Setting]) -> list[dict[str, Value]]:
    """Every combination of the settings' values, the first setting's changing slowest;
    each as {name: value}. Two settings of one parameter are an error."""
    names = [s.name for s in settings]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SettingError(f"{PREFIX}{twice[0]} is set more than once")
    return [dict(zip(names, combo, strict=True)) for combo in
            itertools.product(*(s.values for s in settings))]  # fmt: skip


def applied(params: TrackerParams, values: Mapping[str, Value]) -> TrackerParams:
    """`params` with `values` (dotted names) in place, checked by `TrackerParams` (a bad
    value raises its `SegmentError`)."""
    top: dict[str, Any] = {}
    parts: dict[str, dict[str, Value]] = {}
    for name, value in values.items():
        head, dot, rest = name.partition(".")
        if dot:
            parts.setdefault(head, {})[rest] = value
        else:
            top[name] = value
    for head, inner in parts.items():
        top[head] = dataclasses.replace(getattr(params, head), **inner)
    return dataclasses.replace(params, **top)


def is_default(values: Mapping[str, Value]) -> bool:
    """Whether every value is the tracker's default."""
    default = TrackerParams()
    return all(_get(default, name) == value for name, value in values.items())


def _get(params: Any, name: str) -> Any:
    for part in name.split("."):
        params = getattr(params, part)
    return params


def as_arguments(values: Mapping[str, Value]) -> list[str]:
    """The `tofcut track` arguments that set `values`."""
    return [a for name, v in values.items() for a in ("--set", f"{PREFIX}{name}={v}")]


def label(values: Mapping[str, Value]) -> str:
    """`beta=3.0, object_cost=8`: a setting in a table."""
    return ", ".join(f"{name}={v}" for name, v in values.items())
