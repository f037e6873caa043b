"""The one check of every number a user gives, on the command line or in a config file:
finite, of the right kind, and in its range.  A failure is a ``ValueError`` whose one-line
message names the value.

The integer ranges end where the arrays the numbers size or seed do: counts are int32 on
the devices, seeds a uint32 PRNG key.
"""

from __future__ import annotations

import dataclasses
import math

INT32_MAX = 2**31 - 1
UINT32_MAX = 2**32 - 1


@dataclasses.dataclass(frozen=True)
class Range:
    """Which numbers a value may take: an interval, closed unless ``open_low``/``open_high``,
    of integers when ``integer``."""

    low: float = -math.inf
    high: float = math.inf
    open_low: bool = False
    open_high: bool = False
    integer: bool = False

    def holds(self, value: float) -> bool:
        above = value > self.low if self.open_low else value >= self.low
        below = value < self.high if self.open_high else value <= self.high
        return above and below

    def describe(self) -> str:
        kind = "an integer" if self.integer else "a finite number"
        written = (lambda x: str(int(x))) if self.integer else (lambda x: f"{x:g}")
        bounds = []
        if self.low > -math.inf:
            bounds.append(f"{'>' if self.open_low else '>='} {written(self.low)}")
        if self.high < math.inf:
            bounds.append(f"{'<' if self.open_high else '<='} {written(self.high)}")
        return f"{kind} {' and '.join(bounds)}" if bounds else kind


FINITE = Range()
POSITIVE = Range(low=0.0, open_low=True)
NON_NEGATIVE = Range(low=0.0)
COUNT = Range(low=1, high=INT32_MAX, integer=True)
NON_NEGATIVE_COUNT = Range(low=0, high=INT32_MAX, integer=True)
INDEX = NON_NEGATIVE_COUNT
SEED = Range(low=0, high=UINT32_MAX, integer=True)


def problem(value: object, rule: Range) -> str | None:
    """Why ``value`` is not a number that ``rule`` allows; None when it is one."""
    kinds = (int,) if rule.integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds):
        return f"must be {rule.describe()}, got {value!r}"
    # An int is finite (and may be too large for a float to hold).
    if (isinstance(value, float) and not math.isfinite(value)) or not rule.holds(value):
        return f"must be {rule.describe()}, got {value!r}"
    return None


def check(name: str, value: object, rule: Range) -> int | float:
    """``value`` if it is a number that ``rule`` allows, else a ``ValueError`` naming ``name``."""
    why = problem(value, rule)
    if why is not None:
        raise ValueError(f"{name}: {why}")
    return int(value) if rule.integer else float(value)


def parse(text: str, rule: Range) -> int | float:
    """The number written as ``text`` (a command-line flag's), else a ``ValueError`` saying why."""
    try:
        value = int(text) if rule.integer else float(text)
    except ValueError:
        raise ValueError(f"must be {rule.describe()}, got {text!r}") from None
    why = problem(value, rule)
    if why is not None:
        raise ValueError(why)
    return value
