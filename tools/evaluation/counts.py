"""Counts that add up over the lines of a family: `Counts`."""

from __future__ import annotations

from dataclasses import asdict, astuple
from typing import Self


class Counts:
    """A frozen dataclass of integer counts (mix in): added field by field, and written to JSON
    under the fields' names."""

    def __add__(self, other: Self) -> Self:
        mine, theirs = astuple(self), astuple(other)  # type: ignore[call-overload]
        return type(self)(*(a + b for a, b in zip(mine, theirs, strict=True)))

    def to_json(self) -> dict[str, int]:
        counts: dict[str, int] = asdict(self)  # type: ignore[call-overload]
        return counts
