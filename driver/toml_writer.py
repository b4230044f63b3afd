"""The package's one TOML writer, for the documents it reads back (`config_file.read_toml`):
conveyor maps and scene files. Tables, arrays of tables, and values that are numbers,
strings, booleans or arrays of those, and `#` comments; `tomllib` reads back exactly what
`dumps` wrote. No TOML writer is installed, and these shapes need little.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from typing import TypeGuard

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
    """TOML text for `doc`: each table's plain values first, then its tables (`[a.b]`) and
    arrays of tables (`[[a.b]]`), in the order given. `comments` puts `# ...` lines under a
    table's header (keyed by the header's name, e.g. "belt"; "" for the top of the text).
    ValueError for what TOML cannot hold or this writer does not write (None, an empty key,
    a list that mixes tables and values, a value of another type)."""
    comments = comments or {}
    lines = [f"# {line}".rstrip() for line in comments.get("", [])]
    _table(doc, "", lines, comments)
    return "\n".join(lines) + "\n"


def _table(
    table: Mapping[str, object], path: str, lines: list[str], comments: Mapping[str, Sequence[str]]
) -> None:
    """A table's key/value lines, then its tables and arrays of tables."""
    for key, value in table.items():
        if not isinstance(value, Mapping) and not _is_table_array(value):
            lines.append(f"{_key(key)} = {_value(value, path + key)}")
    for key, value in table.items():
        name = path + _key(key)
        if isinstance(value, Mapping):
            tables, header = [value], f"[{name}]"
        elif _is_table_array(value):
            tables, header = list(value), f"[[{name}]]"
        else:
            continue
        for item in tables:
            if lines:
                lines.append("")
            lines.append(header)
            lines += [f"# {line}".rstrip() for line in comments.get(name, [])]
            _table(item, name + ".", lines, comments)


def _is_table_array(value: object) -> TypeGuard[Sequence[Mapping[str, object]]]:
    return (
        isinstance(value, list | tuple)
        and bool(value)
        and all(isinstance(v, Mapping) for v in value)
    )


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
    if isinstance(value, list | tuple):
        if any(isinstance(item, Mapping) for item in value):
            raise ValueError(f"{where}: a list of tables may hold nothing else")
        return "[" + ", ".join(_value(item, where) for item in value) + "]"
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
