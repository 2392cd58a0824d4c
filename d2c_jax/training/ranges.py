"""The kinds of valid range a config field can have, and how each is described.

`validation.field_ranges()` gives every field one of these; `problem(value)` is the
phrase after "must be" in the one-line error (`--sac.gamma must be in [0, 1), got 1.5`),
or None for a valid value.
"""

from __future__ import annotations

import dataclasses

_INF = float("inf")


def _is_number(value, integer: bool) -> bool:
    if isinstance(value, bool):
        return False
    return isinstance(value, int) if integer else isinstance(value, (int, float))


def _num(x: float) -> str:
    """A bound as people write it: 1 rather than 1.0."""
    return str(int(x)) if float(x).is_integer() else str(x)


@dataclasses.dataclass(frozen=True)
class Interval:
    """Finite numbers from `lo` to `hi` (None: unbounded on that side); ints if `integer`."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False

    def contains(self, value) -> bool:
        if not _is_number(value, self.integer) or not -_INF < value < _INF:
            return False
        if self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo):
            return False
        return self.hi is None or (value < self.hi if self.hi_open else value <= self.hi)

    def describe(self) -> str:
        lo, hi = self.lo, self.hi
        if lo is not None and hi is not None:
            left, right = "(["[not self.lo_open], ")]"[not self.hi_open]
            return f"in {left}{_num(lo)}, {_num(hi)}{right}"
        kind = "" if self.integer else "a finite number "
        if lo is not None:
            return f"{kind}{'>' if self.lo_open else '>='} {_num(lo)}"
        if hi is not None:
            return f"{kind}{'<' if self.hi_open else '<='} {_num(hi)}"
        return "an integer" if self.integer else "a finite number"

    def problem(self, value) -> str | None:
        if self.contains(value):
            return None
        if self.integer and not _is_number(value, True):
            return f"an integer {self.describe()}"
        return self.describe()


@dataclasses.dataclass(frozen=True)
class OneOf:
    """One of `choices` (Literal and bool fields), compared with their type."""

    choices: tuple

    def describe(self) -> str:
        if self.choices == (True, False):
            return "true or false"
        return "one of " + ", ".join(map(str, self.choices))

    def problem(self, value) -> str | None:
        ok = any(type(value) is type(c) and value == c for c in self.choices)
        return None if ok else self.describe()


@dataclasses.dataclass(frozen=True)
class Text:
    """A non-empty string (env and preset names: the CLI checks them against their lists)."""

    def describe(self) -> str:
        return "a non-empty string"

    def problem(self, value) -> str | None:
        return None if isinstance(value, str) and value else self.describe()


@dataclasses.dataclass(frozen=True)
class OrNone:
    """None, or a value `inner` accepts (`X | None` fields; typed as `none`)."""

    inner: Interval | OneOf | Text

    def describe(self) -> str:
        return f"{self.inner.describe()} or none"

    def problem(self, value) -> str | None:
        return None if value is None or self.inner.problem(value) is None else self.describe()


@dataclasses.dataclass(frozen=True)
class NonEmptyTuple:
    """A non-empty tuple of values `item` accepts (`tuple[X, ...]`; typed comma-separated)."""

    item: Interval | OneOf | Text

    def describe(self) -> str:
        return f"a non-empty comma-separated list, each {self.item.describe()}"

    def problem(self, value) -> str | None:
        ok = isinstance(value, tuple) and value and all(self.item.problem(v) is None for v in value)
        return None if ok else self.describe()


@dataclasses.dataclass(frozen=True)
class SweepPairs:
    """(dotted field, values) pairs (`TrainConfig.sweep`); `sweep.problem` and each
    arm's own validation check the fields and values."""

    def describe(self) -> str:
        return "FIELD=v1,v2,... pairs"

    def problem(self, value) -> str | None:
        ok = isinstance(value, tuple) and all(
            isinstance(p, tuple)
            and len(p) == 2
            and isinstance(p[0], str)
            and isinstance(p[1], tuple)
            for p in value
        )
        return None if ok else self.describe()


Range = Interval | OneOf | Text | OrNone | NonEmptyTuple | SweepPairs
