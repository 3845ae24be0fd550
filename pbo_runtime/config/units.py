"""Quantities in YAML files: a number in SI units, or a string with a unit.

Control engineers write `period: 1 ms`, `rate: 1 kHz`, `bandwidth: 40 MB/s`,
`lock_overhead: 16 B`; the runtime works in seconds, hertz, bytes per second and bytes.
Sizes are decimal SI (kB = 1000 B) unless written in binary units (KiB = 1024 B).
"""

from __future__ import annotations

import functools
import math
import re

TIME = "time"
FREQUENCY = "frequency"
DATA_RATE = "data_rate"
SIZE = "size"

_SIZE_UNITS: dict[str, float] = {
    "B": 1.0,
    "kB": 1e3,
    "KB": 1e3,
    "MB": 1e6,
    "GB": 1e9,
    "KiB": 1024.0,
    "MiB": 1024.0**2,
    "GiB": 1024.0**3,
}

UNITS: dict[str, dict[str, float]] = {
    TIME: {
        "s": 1.0,
        "sec": 1.0,
        "ms": 1e-3,
        "us": 1e-6,
        "µs": 1e-6,
        "μs": 1e-6,
        "ns": 1e-9,
        "min": 60.0,
        "h": 3600.0,
    },
    FREQUENCY: {"Hz": 1.0, "hz": 1.0, "kHz": 1e3, "KHz": 1e3, "khz": 1e3, "MHz": 1e6},
    DATA_RATE: {f"{unit}/s": factor for unit, factor in _SIZE_UNITS.items()},
    SIZE: _SIZE_UNITS,
}

_EXPECTED = {
    TIME: "a time like '1 ms' or a number of seconds",
    FREQUENCY: "a frequency like '1 kHz' or a number of hertz",
    DATA_RATE: "a data rate like '40 MB/s' or a number of bytes per second",
    SIZE: "a size like '16 B' or a number of bytes",
}

_KIND_NAME = {TIME: "a time", FREQUENCY: "a frequency", DATA_RATE: "a data rate", SIZE: "a size"}

# A number, then optionally a unit (with or without a space): "1ms", "1 ms", "1.5e-3 s", ".5 kHz".
_QUANTITY = re.compile(r"^\s*([+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*(\S.*?)?\s*$")


def parse_quantity(value: object, kind: str) -> float:
    """The value in SI units, or ValueError saying what was expected and what was found."""
    if type(value) is str:  # a file repeats the same few ('1 ms' for hundreds of tasks): parse each once
        return _parse_text(value, kind)
    return _parse(value, kind)


@functools.lru_cache(maxsize=4096)
def _parse_text(value: str, kind: str) -> float:
    return _parse(value, kind)  # a ValueError is raised again each time, never remembered


def _parse(value: object, kind: str) -> float:
    if kind not in UNITS:
        raise ValueError(f"unknown quantity kind {kind!r} (valid: {', '.join(UNITS)})")
    expected = _EXPECTED[kind]
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise ValueError(f"expected {expected}, got: {_show(value)}")
    if isinstance(value, (int, float)):
        number = float(value)
        unit = None
    else:
        match = _QUANTITY.match(value)
        if match is None:
            raise ValueError(f"expected {expected}, got: {value!r}")
        number = float(match.group(1))
        unit = match.group(2)
    if not math.isfinite(number):
        raise ValueError(f"expected {expected}, got: {_show(value)} (not a finite number)")
    if unit is None:
        return number
    units = UNITS[kind]
    if unit in units:
        return number * units[unit]
    other = unit_kind(unit)
    if other is not None:
        raise ValueError(f"expected {expected}, got: {value!r} (that is {_KIND_NAME[other]})")
    raise ValueError(f"expected {expected}, got: {value!r} (units: {', '.join(_unique(units))})")


def unit_kind(unit: str) -> str | None:
    """Which kind of quantity a unit measures, if any (so a message can say 'that is a frequency')."""
    for kind, units in UNITS.items():
        if unit in units:
            return kind
    return None


def _unique(units: dict[str, float]) -> list[str]:
    # Spelling variants (µs/μs, KHz/khz) clutter the list of choices; show the canonical first ones.
    shown: list[str] = []
    for name in units:
        if name in ("μs", "KHz", "khz", "hz", "KB", "sec"):
            continue
        shown.append(name)
    return shown


def _show(value: object) -> str:
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    if value is None:
        return "nothing (null)"
    return repr(value)
