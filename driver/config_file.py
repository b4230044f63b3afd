"""Reading the package's TOML files (conveyor maps, scene files) defensively: a bounded size,
UTF-8 text, bounded nesting, and unknown keys named with the nearest known one."""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def show(value: object) -> str:
    """A value for a one-line message: its repr, cut short."""
    text = repr(value)
    return text if len(text) <= 40 else text[:40] + "…"


def as_float(value: object) -> float | None:
    """A TOML number as a float (inf where an integer is too large for one); None for
    anything else, a bool included (`true` is not 1 in a configuration file)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        return float(value)
    except OverflowError:
        return math.inf


def read_toml(path: str | Path, max_bytes: int) -> dict[str, Any]:
    """A TOML file's document. `ValueError` with a one-line message for a file larger than
    `max_bytes`, not UTF-8 text, not TOML, or nested too deep for the parser; `OSError` if
    it cannot be read."""
    with Path(path).open("rb") as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise ValueError(f"larger than {max_bytes} bytes: not a configuration file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"not a text file (byte {exc.start} is {data[exc.start]:#04x}, not UTF-8)"
        ) from None
    if "\x00" in text:
        raise ValueError("not a text file (it has NUL bytes)")
    try:
        return tomllib.loads(text)
    except ValueError as exc:  # TOMLDecodeError, or an integer too long to convert
        raise ValueError(str(exc).splitlines()[0] if str(exc) else "not TOML") from None
    except RecursionError:
        raise ValueError("arrays or tables nested too deep") from None


def load_toml(
    path: str | Path,
    max_bytes: int,
    parse: Callable[[dict[str, Any]], T],
    error: type[Exception],
) -> T:
    """`parse` of a TOML file's document (`read_toml`). What goes wrong, reading the file or
    in `parse` (which raises `error`), is an `error` in one line that names the file."""
    p = Path(path)
    try:
        doc = read_toml(p, max_bytes)
    except OSError as exc:
        raise error(f"{p}: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise error(f"{p}: {exc}") from None
    try:
        return parse(doc)
    except error as exc:
        raise error(f"{p}: {exc}") from None


def unknown_keys(
    table: dict[str, Any], allowed: Iterable[str], forms: dict[str, str] | None = None
) -> str:
    """'' when every key of `table` is allowed; else a one-line message naming the first
    unknown key (as a table, `[name]` or `[[name]]`, when it is one) and the nearest allowed
    one, e.g. "unknown table [[objects]]; did you mean [[object]]?". `forms`: how to write
    an allowed name in the message (default: the name itself); `"""
    allowed = sorted(allowed)
    unknown = sorted(set(table) - set(allowed))
    if not unknown:
        return ""
    forms = forms or {}
    key = unknown[0]
    shown = key if len(key) <= 40 else key[:40] + "…"
    value = table[key]
    if isinstance(value, dict):
        what = f"table [{shown}]"
    elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        what = f"table [[{shown}]]"
    else:
        what = f"key {shown!r}"
    close = difflib.get_close_matches(key, allowed, n=1)
    if close:
        hint = f"; did you mean {forms.get(close[0], close[0])}?"
    else:
        hint = f"; known: {', '.join(forms.get(a, a) for a in allowed)}"
    more = f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""
    return f"unknown {what}{more}{hint}"
