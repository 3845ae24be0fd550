"""A parameter's range: the numbers `pbo check`, `pbo set`, the API and a task's init accept.

A Params field declares it with `param` (a `dataclasses.field` that also says its range and its
shape), and every door builds parameters through `objects.module.build_params`, which refuses a
number outside it with the parameter's name and the range. A float is finite whether a range is
declared or not: NaN never, and infinity only where the range's upper end is `math.inf` itself,
closed (`at_most=math.inf`: "no limit").
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from pbo_runtime.errors import ParamError


@dataclasses.dataclass(frozen=True)
class Range:
    """An interval of numbers, each end closed or open; an end at infinity is open unless given closed."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = True
    high_open: bool = True

    def admits(self, value: float) -> bool:
        if value != value:  # NaN is in no range
            return False
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def text(self) -> str:
        """The range in words an engineer reads at once: 'in [0, 1e+06]', 'in (0, 100]', '> 0, or .inf for no limit'."""
        low_finite, high_finite = math.isfinite(self.low), math.isfinite(self.high)
        if low_finite and high_finite:
            opening, closing = "(" if self.low_open else "[", ")" if self.high_open else "]"
            return f"in {opening}{number_text(self.low)}, {number_text(self.high)}{closing}"
        words = "a finite number" if self.high_open or high_finite else "a number"
        if low_finite:
            words += f" {'>' if self.low_open else '>='} {number_text(self.low)}"
        elif high_finite:
            words += f" {'<' if self.high_open else '<='} {number_text(self.high)}"
        if not self.high_open and not high_finite:
            words += ", or .inf for no limit"
        return words

    def schema(self) -> dict[str, float]:
        """The range as JSON Schema keywords (minimum, exclusiveMaximum, ...): its finite ends."""
        keywords: dict[str, float] = {}
        if math.isfinite(self.low):
            keywords["exclusiveMinimum" if self.low_open else "minimum"] = self.low
        if math.isfinite(self.high):
            keywords["exclusiveMaximum" if self.high_open else "maximum"] = self.high
        return keywords


FINITE = Range()  # what a float parameter that declares no range takes


class OutOfRange(ParamError):
    """A parameter's number outside its range (or not finite): says which parameter, which element
    of a list (`index`), and the range, so the checker points at the very value."""

    def __init__(self, message: str, where: str, allowed: Range, got: str) -> None:
        super().__init__(message)
        self.where = where  # as the message names it: 'PidJoint.kp[2]'
        self.got = got  # the value as the message shows it: '1e+308', '.nan (not a number)'
        self.param = ""  # the field, set by convert_param
        self.index: tuple[int, ...] = ()  # the element of a list parameter, outermost first
        self.allowed = allowed


def param(default: Any = dataclasses.MISSING, *, at_least: float | None = None, above: float | None = None,
          at_most: float | None = None, below: float | None = None, shape: tuple[int | str, ...] | None = None) -> Any:
    """A Params field with its range (and, for a list, its shape: sizes or dim names, as a port's).

        kp: Gain = param(400.0, at_least=0, at_most=1e6, shape=("NDOF",))  # N m / rad
        max_velocity: float = param(1.0, above=0, at_most=100)  # rad/s
        max_torque: float = param(math.inf, above=0, at_most=math.inf)  # N m; .inf: no limit

    A list parameter's range holds for each of its numbers; an integer's as a float's.
    """
    if (at_least is not None and above is not None) or (at_most is not None and below is not None):
        raise TypeError("give one lower end (at_least or above) and one upper end (at_most or below)")
    low = at_least if at_least is not None else above
    high = at_most if at_most is not None else below
    allowed = Range(-math.inf if low is None else float(low), math.inf if high is None else float(high),
                    low_open=at_least is None, high_open=at_most is None)
    if not allowed.low < allowed.high:
        raise TypeError(f"a parameter's range must not be empty, got: {allowed.text()}")
    metadata: dict[str, Any] = {"range": allowed}
    if shape is not None:
        metadata["shape"] = shape
    return dataclasses.field(default=default, metadata=metadata)


def number_text(value: float) -> str:
    """A number as an operator reads and writes it: 400, 1e+06, 0.001; .nan and .inf as YAML spells them."""
    if isinstance(value, int) and not isinstance(value, bool):
        digits = str(abs(value))
        sign = "-" if value < 0 else ""
        return f"{sign}{digits}" if len(digits) <= 20 else f"{sign}{digits[0]}.{digits[1:4]}e+{len(digits) - 1} (an integer)"
    if value != value:
        return ".nan"
    if math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    short = f"{value:g}"
    return short if float(short) == value else repr(float(value))


def check_number(value: float, allowed: Range | None, where: str) -> None:
    """Raise OutOfRange unless `value` is in `allowed` (a float without one: finite)."""
    allowed = allowed or FINITE
    if allowed.admits(value):
        return
    got = number_text(value) + (" (not a number)" if value != value else "")
    raise OutOfRange(f"{where} must be {allowed.text()}, got: {got}", where, allowed, got)
