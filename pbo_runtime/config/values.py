"""What a value for a state variable may hold, checked the same way wherever it comes from.

A variable's `initial:` value and a job's object in an application step (the checker), and a
job's object or an event's values sent at run time over the control queue (job control), are
all numbers of the variable's dtype: integers within the dtype's range for integer dtypes,
true/false for bool, and finite numbers (no NaN, no Inf) for float dtypes. A non-finite number
would travel on to an actuator, so it is refused where it enters, never carried.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from pbo_runtime.objects.ranges import Range, number_text

INT_RANGE = {
    "int8": (-(2**7), 2**7 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint8": (0, 2**8 - 1),
    "uint16": (0, 2**16 - 1),
    "uint32": (0, 2**32 - 1),
    "uint64": (0, 2**64 - 1),
}


def describe(value: object) -> str:
    """A short, plain description of a value for 'got: ...' (the checker's words too)."""
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"true/false ({str(value).lower()})"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, str):
        return f"the text {value!r}"
    if isinstance(value, int):
        return f"the integer {value}"
    if isinstance(value, float):
        return f"the number {value}"
    return f"{type(value).__name__} {value!r}"


def element_problem(leaf: Any, dtype: str) -> str:
    """Why `leaf` cannot be one element of a `dtype` variable; "" if it can."""
    if dtype == "bool":
        return "" if isinstance(leaf, bool) else f"bool elements must be true or false, got: {describe(leaf)}"
    if isinstance(leaf, bool) or not isinstance(leaf, (int, float)):
        return f"{dtype} elements must be numbers, got: {describe(leaf)}"
    if dtype in INT_RANGE:
        if not isinstance(leaf, int):
            return f"{dtype} elements must be integers, got: {describe(leaf)}"
        low, high = INT_RANGE[dtype]
        if not low <= leaf <= high:
            return f"{dtype} elements must lie in [{low}, {high}], got: {leaf}"
        return ""
    if isinstance(leaf, float) and not math.isfinite(leaf):
        return f"{dtype} elements must be finite numbers, got: {_written(leaf)}"
    if isinstance(leaf, int) and abs(leaf) > int(np.finfo(dtype).max):
        digits = len(str(abs(leaf)))
        return f"{dtype} elements must be finite numbers, got: an integer of {digits} digits, beyond the largest {dtype}"
    return ""


def non_finite(leaf: Any) -> bool:
    """A float that is NaN or +-Inf (what E314 refuses)."""
    return isinstance(leaf, float) and not math.isfinite(leaf)


def _written(value: float) -> str:
    """NaN and Inf the way YAML writes them, which is how a user meets them."""
    if math.isnan(value):
        return ".nan (not a number)"
    return ".inf" if value > 0 else "-.inf"


def nested_shape(value: Any) -> tuple[int, ...] | None:
    """The shape of a nested list, () for a scalar, None if ragged."""
    if not isinstance(value, (list, tuple)):
        return ()
    if not value:
        return (0,)
    inner = [nested_shape(v) for v in value]
    if any(s is None or s != inner[0] for s in inner):
        return None
    first = inner[0]
    assert first is not None
    return (len(value), *first)


def leaves(value: Any) -> Iterable[Any]:
    """The numbers of a nested list, in order (a scalar is its own one leaf)."""
    if isinstance(value, (list, tuple)):
        for v in value:
            yield from leaves(v)
    else:
        yield value


def as_value(value: Any, dtype: str, shape: Sequence[int], what: str) -> np.ndarray:
    """`value` (a number, or a flat or nested list) as an array of the variable's dtype and shape.

    ValueError names `what` and what is wrong: not numbers, a number out of the dtype's range, a
    non-finite float, a ragged list, or not as many values as the variable has elements. A
    single number fills every element, as an `initial:` value does.
    """
    size = math.prod(shape)
    if isinstance(value, dict):
        raise ValueError(f"{what} must be numbers, got: a mapping")
    try:
        found = nested_shape(value)
    except RecursionError:  # lists in lists a thousand deep: no variable has that many dimensions
        raise ValueError(f"{what} is lists nested too deeply to be a variable's value") from None
    if found is None:
        raise ValueError(f"{what} is a ragged list; rows must have equal lengths")
    count = math.prod(found)
    if isinstance(value, (list, tuple)) and count != size:
        raise ValueError(f"{what}: the variable takes {size} values (shape {list(shape)}), got {count}")
    for position, leaf in enumerate(leaves(value), 1):
        problem = element_problem(leaf, dtype)
        if problem:
            raise ValueError(f"{what}: {problem}" + (f" (value {position})" if count > 1 else ""))
    array = np.empty(tuple(shape), dtype=dtype)
    array[...] = np.asarray(value, dtype=dtype).reshape(found if found == () else tuple(shape))
    return array


def outside_range(type_name: str, allowed: Range, value: float, position: int = 0) -> str:
    """What is wrong with an element of an object outside its type's range: the same words from
    `pbo check`, `pbo job`, the HMI's object editor. `position` counts from 1 (0: the only one)."""
    element = f"element {position} " if position else ""
    return f"{element}must be {allowed.text()} (the range of object type '{type_name}'), got: {number_text(value)}"


def range_problem(array: np.ndarray, type_name: str, allowed: Range | None) -> str:
    """'' if every element of `array` is in `allowed` (or none is declared), else what `outside_range` says of the first."""
    if allowed is None:
        return ""
    flat = array.reshape(-1)
    for position, element in enumerate(flat.tolist(), 1):
        if not allowed.admits(element):
            return outside_range(type_name, allowed, element, position if flat.size > 1 else 0)
    return ""
