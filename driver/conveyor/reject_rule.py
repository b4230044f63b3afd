"""Which objects to reject: measures of a track over the belt, and rules over those measures.

A rule is text — comparisons of measures with numbers (SI units: m, m², m³), joined by
`and`, `or`, `not` and parentheses, e.g. ``height > 0.08``, ``volume > 0.001 and not
width < 0.1``, ``0.05 < length <= 0.3`` — parsed here without `eval`; or, through the
API, any Python callable taking `TrackMeasures` and returning a bool.
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, NoReturn, Protocol

import numpy as np
import numpy.typing as npt

from tofcut._types import F64
from tofcut.driver.belt import BeltGeometry
from tofcut.driver.errors import ConfigError

HEIGHT_PERCENTILE = 95.0
"""The object's height is this percentile of its points' heights (ignores flying pixels)."""
EXTENT_PERCENTILE = 2.0
"""Extents along and across the belt leave out this percentage of points at each end: mixed
pixels at depth edges land far along their rays and would stretch a min-max extent."""
HULL_BIN_M = 0.002
"""The footprint's hull is taken over per-bin extremes of this width along the belt."""
MAX_NESTING = 64
"""The deepest a rule may nest `not`s and parentheses (each counts one level): the parser and
the rule it builds recurse once per level, so an unbounded depth would end in RecursionError."""


class TrackView(Protocol):
    """What the rules read of a track (`tofcut.tracker.tracks.Track` is one): named here so
    that the driver, which the tracker imports, does not import the tracker."""

    __dataclass_fields__: ClassVar[dict[str, Any]]
    """A dataclass: the rejects keep a copy without its points (`dataclasses.replace`)."""

    @property
    def id(self) -> int: ...
    @property
    def bbox(self) -> tuple[int, int, int, int]: ...
    @property
    def pixels(self) -> int: ...
    @property
    def points(self) -> npt.NDArray[np.float32]: ...
    @property
    def visible(self) -> bool: ...


@dataclass(frozen=True, eq=False)
class TrackMeasures:
    """What a track's points say about the object, in the belt's frame."""

    track_id: int
    height: float
    """m: top of the object above the belt."""
    length: float
    """m: extent along the belt (of all but the outermost `EXTENT_PERCENTILE` % each end)."""
    width: float
    """m: extent across the belt (likewise)."""
    footprint: float
    """m²: area of the points' outline projected on the belt (the hull of those points)."""
    volume: float
    """m³: footprint × height (the prism the object fits in)."""
    pixels: int
    along: float
    """m: the centre of the object's extent along the belt, from the camera's axis."""
    track: TrackView


PROPERTIES = ("height", "length", "width", "footprint", "volume", "pixels")
"""The measures a rule may name."""


def measure_track(track: TrackView, belt: BeltGeometry) -> TrackMeasures | None:
    """A track's measures over the belt; None when it has too few points this frame."""
    points = np.asarray(track.points, dtype=np.float64).reshape(-1, 3)
    if len(points) < 3:
        return None
    along = belt.along(points)
    across = belt.across(points)
    height = max(float(np.percentile(belt.height(points), HEIGHT_PERCENTILE)), 0.0)
    q = (EXTENT_PERCENTILE, 100.0 - EXTENT_PERCENTILE)
    a0, a1 = (float(v) for v in np.percentile(along, q))
    c0, c1 = (float(v) for v in np.percentile(across, q))
    inner = (along >= a0) & (along <= a1) & (across >= c0) & (across <= c1)
    footprint = hull_area(along[inner], across[inner])
    return TrackMeasures(
        track_id=track.id,
        height=height,
        length=a1 - a0,
        width=c1 - c0,
        footprint=footprint,
        volume=footprint * height,
        pixels=track.pixels,
        along=0.5 * (a0 + a1),
        track=track,
    )


def hull_area(x: F64, y: F64) -> float:
    """Area of the convex hull of 2D points (0 for fewer than 3 or collinear)."""
    if len(x) < 3:
        return 0.0
    # Only the lowest and highest point of each narrow bin in x can be on the hull.
    bins = np.floor((x - x.min()) / HULL_BIN_M).astype(np.int64)
    order = np.lexsort((y, bins))
    _, first = np.unique(bins[order], return_index=True)
    last = np.r_[first[1:], len(order)] - 1
    keep = np.unique(np.r_[order[first], order[last]])
    pts = sorted({(float(a), float(b)) for a, b in zip(x[keep], y[keep], strict=True)})
    if len(pts) < 3:
        return 0.0

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while len(out) >= 2 and _cross(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out

    hull = half(pts)[:-1] + half(pts[::-1])[:-1]
    area = 0.0
    for (x0, y0), (x1, y1) in zip(hull, hull[1:] + hull[:1], strict=True):
        area += x0 * y1 - x1 * y0
    return abs(area) / 2.0


def _cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


# --- rules ------------------------------------------------------------------------------

Predicate = Callable[[TrackMeasures], bool]
_Value = Callable[[TrackMeasures], float]

_TOKEN = re.compile(
    r"\s*(?:(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)|(?P<name>[A-Za-z_]\w*)"
    r"|(?P<op><=|>=|==|!=|<|>)|(?P<paren>[()]))"
)
_COMPARE = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
    "==": operator.eq,
    "!=": operator.ne,
}


class RejectRule:
    """A yes/no decision over `TrackMeasures`: parsed from text, or any callable."""

    def __init__(self, predicate: Predicate, text: str) -> None:
        self._predicate = predicate
        self.text = text

    @classmethod
    def parse(cls, text: str) -> RejectRule:
        """A rule from its text (syntax in this module's docstring); `ConfigError` if bad."""
        return cls(_Parser(text).rule(), text)

    @classmethod
    def from_callable(cls, predicate: Predicate, name: str | None = None) -> RejectRule:
        return cls(predicate, name or str(getattr(predicate, "__name__", "callable")))

    def __call__(self, measures: TrackMeasures) -> bool:
        return bool(self._predicate(measures))

    def __repr__(self) -> str:
        return f"RejectRule({self.text!r})"


class _Parser:
    """Recursive descent: or → and → not → comparison chain → number | name | ( or )."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens: list[tuple[str, str]] = []
        pos = 0
        while pos < len(text):
            m = _TOKEN.match(text, pos)
            if m is None or m.lastgroup is None:
                if text[pos:].strip() == "":
                    break
                self._error(f"unexpected {text[pos:].strip()[:10]!r}")
            self.tokens.append((m.lastgroup, m.group(m.lastgroup)))
            pos = m.end()
        self.i = 0
        self.depth = 0

    def _error(self, what: str) -> NoReturn:
        text = self.text if len(self.text) <= 60 else self.text[:60] + "…"
        raise ConfigError(f"reject rule {text!r}: {what}")

    def _peek(self) -> tuple[str, str] | None:
        return self.tokens[self.i] if self.i < len(self.tokens) else None

    def _next(self) -> tuple[str, str]:
        tok = self._peek()
        if tok is None:
            self._error("ends too early")
        self.i += 1
        return tok

    def _keyword(self, word: str) -> bool:
        if self._peek() == ("name", word):
            self.i += 1
            return True
        return False

    def rule(self) -> Predicate:
        if not self.tokens:
            self._error("is empty")
        pred = self._or()
        if (tok := self._peek()) is not None:
            self._error(f"unexpected {tok[1]!r}")
        return pred

    def _or(self) -> Predicate:
        parts = [self._and()]
        while self._keyword("or"):
            parts.append(self._and())
        return parts[0] if len(parts) == 1 else (lambda m: any(p(m) for p in parts))

    def _and(self) -> Predicate:
        parts = [self._not()]
        while self._keyword("and"):
            parts.append(self._not())
        return parts[0] if len(parts) == 1 else (lambda m: all(p(m) for p in parts))

    def _not(self) -> Predicate:
        if self._peek() in (("name", "not"), ("paren", "(")):
            self.depth += 1
            if self.depth > MAX_NESTING:
                self._error(f"nests 'not' and parentheses more than {MAX_NESTING} deep")
            try:
                return self._nested()
            finally:
                self.depth -= 1
        return self._comparison()

    def _nested(self) -> Predicate:
        if self._keyword("not"):
            inner = self._not()
            return lambda m: not inner(m)
        self.i += 1  # the "("
        inner = self._or()
        if self._next() != ("paren", ")"):
            self._error("a '(' is not closed")
        return inner

    def _comparison(self) -> Predicate:
        values = [self._value()]
        ops = []
        while (tok := self._peek()) is not None and tok[0] == "op":
            self.i += 1
            ops.append(_COMPARE[tok[1]])
            values.append(self._value())
        if not ops:
            self._error("needs a comparison such as 'height > 0.08'")
        steps = list(zip(values, ops, values[1:], strict=False))
        return lambda m: all(op(a(m), b(m)) for a, op, b in steps)

    def _value(self) -> _Value:
        kind, text = self._next()
        if kind == "num":
            number = float(text)
            if not math.isfinite(number):
                self._error(f"{text} is not a finite number")
            return lambda m: number
        if kind == "name" and text in PROPERTIES:
            return lambda m: float(getattr(m, text))
        if kind == "name" and text not in ("and", "or", "not"):
            self._error(f"unknown measure {text!r}; known: {', '.join(PROPERTIES)}")
        self._error(f"expected a measure or a number, not {text!r}")
