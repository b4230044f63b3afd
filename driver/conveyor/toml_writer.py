"""A small TOML writer for the shapes a conveyor map has: top-level tables of numbers,
strings, booleans and lists of those (and top-level values before them). No TOML writer is
installed, and these shapes need little: `tomllib` reads back exactly what `dumps` wrote.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence

Scalar = bool | int | float | str
Value = Scalar | Sequence[Scalar]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_ESCAPES = {
    '"': '\\"',
    "\\": "\\\\",
    "\b": "\\b",
    "\t": "\\t",
    "\n": "\\n",
    "\f": "\\f",
    "\r": "\\r",
}


def dumps(doc: Mapping[str, object], comments: Mapping[str, Sequence[str]] | None = None) -> str:
    """TOML text for `doc`: its plain values first, then one `[table]` per mapping, in the
    order given. `comments` puts `# ...` lines under a table's header (keyed by the table's
    name; "" for the top). ValueError for anything else than these shapes (a table within a
    table, a list of tables, a value of another type)."""
    comments = comments or {}
    plain = [(k, v) for k, v in doc.items() if not isinstance(v, Mapping)]
    tables = [(k, v) for k, v in doc.items() if isinstance(v, Mapping)]
    lines = [f"# {line}" for line in comments.get("", [])]
    lines += [f"{_key(k)} = {_value(v, k)}" for k, v in plain]
    for name, table in tables:
        if lines:
            lines.append("")
        lines.append(f"[{_key(name)}]")
        lines += [f"# {line}" for line in comments.get(name, [])]
        for key, value in table.items():
            if isinstance(value, Mapping):
                raise ValueError(f"{name}.{key}: tables within tables are not written")
            lines.append(f"{_key(key)} = {_value(value, f'{name}.{key}')}")
    return "\n".join(lines) + "\n"


def _key(key: str) -> str:
    if not isinstance(key, str) or not key:
        raise ValueError(f"a TOML key must be a non-empty string, not {key!r}")
    return key if _BARE_KEY.fullmatch(key) else _string(key)


def _value(value: object, where: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)  # the shortest text that reads back as the same float
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, Sequence):
        items = []
        for item in value:
            if isinstance(item, Mapping | list | tuple):
                raise ValueError(f"{where}: only lists of numbers, strings and booleans")
            items.append(_value(item, where))
        return "[" + ", ".join(items) + "]"
    raise ValueError(f"{where}: cannot write a {type(value).__name__} to TOML")


def _string(text: str) -> str:
    out = []
    for ch in text:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'
