"""What a `pbo plot` argument asks for: one axis of curves.

An argument is one axis; commas overlay curves in it (`q_m,q_r`). A curve is a variable, an
element of it (`q_m[1]`, `m[0][1]`), or the difference of two of the same shape (`q_m-q_r`,
`q_m[1]-q_r[1]`). A difference of variables from two logs takes the second at the first's times
(linear interpolation): loggers of different periods can still be compared.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from pbo_runtime.reports.data_log import DataLog, LogError

_TERM = r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)"
_CURVE = re.compile(rf"^\s*{_TERM}\s*(?:-\s*{_TERM}\s*)?$")


@dataclass(frozen=True)
class Curves:
    """The lines of one curve asked for: its times, its values (rows, elements) and each line's label."""

    text: str  # as asked: "q_m-q_r"
    time: np.ndarray
    values: np.ndarray
    labels: list[str]
    unit: str


def axis_curves(argument: str, columns: dict[str, DataLog], units: dict[str, str], where: str) -> list[Curves]:
    """Every curve of one argument (`q_m,q_r[1]`); LogError naming what is wrong and what the logs at `where` hold."""
    return [_curves(text.strip(), columns, units, where) for text in argument.split(",") if text.strip()]


def _curves(text: str, columns: dict[str, DataLog], units: dict[str, str], where: str) -> Curves:
    found = _CURVE.match(text)
    if found is None:
        raise LogError(f"'{text}': a curve is a variable (q_m), an element (q_m[1]) or a difference of two (q_m-q_r)")
    name, index, other, other_index = found.groups()
    log, values = _term(name, index, columns, where)
    time = log.rows["time"]
    unit = units.get(name, "")
    if other is not None:
        other_log, subtrahend = _term(other, other_index, columns, where)
        if subtrahend.shape[1:] != values.shape[1:]:
            raise LogError(f"'{text}': {name}{index} has shape {values.shape[1:]} and {other}{other_index} "
                           f"{subtrahend.shape[1:]}: a difference needs the same shape")
        if other_log is not log:
            columns_of = subtrahend.reshape(len(subtrahend), -1).T
            at_our_times = [np.interp(time, other_log.rows["time"], column) for column in columns_of]
            subtrahend = np.stack(at_our_times, axis=1).reshape(len(time), *values.shape[1:])
        values = values - subtrahend
        if units.get(other, "") != unit:
            unit = ""
    shape = values.shape[1:]
    flat = values.reshape(len(values), -1)
    labels = [text + ("".join(f"[{i}]" for i in np.unravel_index(e, shape)) if shape else "") for e in range(flat.shape[1])]
    return Curves(text, time, flat, labels, unit)


def _term(name: str, index: str, columns: dict[str, DataLog], where: str) -> tuple[DataLog, np.ndarray]:
    """A variable's rows, or its element's, with the log that holds it."""
    if name not in columns:
        raise LogError(f"no variable '{name}' in {where} (logged: {', '.join(columns) or 'none'})")
    log = columns[name]
    values = log.rows[name]
    indices = [int(i) for i in re.findall(r"\d+", index)]
    shape = values.shape[1:]
    if len(indices) > len(shape) or any(i >= size for i, size in zip(indices, shape, strict=False)):
        raise LogError(f"{name}{index}: '{name}' has shape {list(shape)}: no such element")
    for i in indices:
        values = values[:, i]
    return log, values
