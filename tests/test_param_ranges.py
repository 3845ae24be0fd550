"""A module parameter's range (`pbo_runtime.param`): how it reads, what it admits, and that every
number parameter of every shipped module declares one and refuses NaN and infinity.

The doors that take a parameter all build it through `build_params`: the file (tests/test_checker.py),
the live verbs (tests/test_live_changes.py), a running demo (tests/test_operator_end_to_end.py).
"""

from __future__ import annotations

import dataclasses
import math
import re
import typing

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pbo_runtime import param
from pbo_runtime.errors import ParamError
from pbo_runtime.objects import registry
from pbo_runtime.objects.module import param_fields, param_ranges
from pbo_runtime.objects.ranges import OutOfRange, Range, number_text


def _takes(hint: typing.Any, kind: type) -> bool:
    return hint is kind or any(_takes(arg, kind) for arg in typing.get_args(hint) if arg is not Ellipsis)


def _takes_a_list(hint: typing.Any) -> bool:
    return typing.get_origin(hint) in (tuple, list) or any(_takes_a_list(arg) for arg in typing.get_args(hint))


def _number_params() -> list[tuple[str, type, str, typing.Any]]:
    """(module, its class, parameter, type hint) for every number parameter of every shipped module."""
    found = []
    for name in registry.names(registry.MODULES):
        cls = registry.module_class(name)
        if not dataclasses.is_dataclass(cls.Params):
            continue
        hints = typing.get_type_hints(cls.Params)
        for field in param_fields(cls.Params):
            if _takes(hints[field], float) or _takes(hints[field], int):
                found.append((name, cls, field, hints[field]))
    return found


NUMBER_PARAMS = _number_params()
FLOAT_PARAMS = [entry for entry in NUMBER_PARAMS if _takes(entry[3], float)]


def test_every_number_parameter_of_every_shipped_module_declares_its_range():
    assert len(NUMBER_PARAMS) > 40
    undeclared = [f"{module}.{field}" for module, cls, field, _ in NUMBER_PARAMS if field not in param_ranges(cls.Params)]
    assert undeclared == []


def _as_written(hint: typing.Any, number: float, in_a_list: bool) -> typing.Any:
    """`number` as a file gives it to a parameter of this type: itself, or in a list (a list of lists)."""
    if typing.get_origin(hint) in (tuple, list):
        return [_as_written(typing.get_args(hint)[0], number, False)]
    return [number] if in_a_list else number


@settings(max_examples=300, deadline=None, derandomize=True)
@given(entry=st.sampled_from(FLOAT_PARAMS), value=st.sampled_from([math.nan, math.inf, -math.inf]), in_a_list=st.booleans())
def test_no_float_parameter_accepts_a_value_that_is_not_finite_unless_it_says_inf_is_no_limit(entry, value, in_a_list):
    _module, cls, field, hint = entry
    in_a_list = in_a_list and _takes_a_list(hint)
    allowed = param_ranges(cls.Params)[field]
    if value == math.inf and allowed.admits(math.inf):  # 'no limit': max_torque, max_lead, ...
        assert allowed.high == math.inf and not allowed.high_open
        return
    with pytest.raises(OutOfRange, match=rf"^{cls.__name__}\.{field}(\[0\])* must be .*, got: {re.escape(number_text(value))}"):
        cls.build_params({field: _as_written(hint, value, in_a_list)})


@settings(max_examples=400, deadline=None, derandomize=True)
@given(entry=st.sampled_from(NUMBER_PARAMS),
       value=st.one_of(st.floats(allow_nan=False, allow_infinity=False), st.integers(-10**400, 10**400)))
def test_a_number_outside_a_parameters_range_is_refused_naming_the_range_and_one_inside_is_not(entry, value):
    _module, cls, field, hint = entry
    allowed = param_ranges(cls.Params)[field]
    if not _takes(hint, float) and isinstance(value, float):
        return  # an integer parameter refuses a float for its type, not its range
    as_float = float(value) if abs(value) < 1e308 else math.inf if value > 0 else -math.inf
    try:
        cls.build_params({field: _as_written(hint, value, False)})
    except OutOfRange as exc:
        assert not allowed.admits(as_float) and exc.param == field and exc.allowed == allowed
        assert allowed.text() in str(exc)
    except ParamError:  # the module's own check of its parameters together (a damping that needs another)
        assert allowed.admits(as_float)
    else:
        assert allowed.admits(as_float)


@pytest.mark.parametrize("declared, text, inside, outside", [
    (dict(at_least=0, at_most=1e6), "in [0, 1e+06]", [0, 1e6, 400], [-1e-300, 1e6 + 1, math.inf, math.nan]),
    (dict(above=0, at_most=100), "in (0, 100]", [1e-300, 100], [0, -1, 100.5]),
    (dict(above=0, below=1), "in (0, 1)", [0.5], [0, 1]),
    (dict(at_least=0), "a finite number >= 0", [0, 1e308], [-1, math.inf]),
    (dict(below=0), "a finite number < 0", [-1], [0, -math.inf]),
    (dict(above=0, at_most=math.inf), "a number > 0, or .inf for no limit", [1, math.inf], [0, -math.inf, math.nan]),
    ({}, "a finite number", [0, -1e308], [math.inf, -math.inf, math.nan]),
])
def test_a_range_reads_as_an_engineer_writes_it_and_admits_what_it_says(declared, text, inside, outside):
    allowed = param(0.0, **declared).metadata["range"]
    assert isinstance(allowed, Range) and allowed.text() == text
    assert all(allowed.admits(v) for v in inside) and not any(allowed.admits(v) for v in outside)


@pytest.mark.parametrize("declared", [dict(at_least=0, above=0), dict(at_most=1, below=1), dict(at_least=1, at_most=0)])
def test_a_range_with_two_ends_on_one_side_or_none_inside_is_a_mistake_of_the_module(declared):
    with pytest.raises(TypeError):
        param(0.0, **declared)


def test_numbers_read_as_the_operator_writes_them():
    assert [number_text(v) for v in (400.0, 1e6, 1e308, 0.001, math.nan, -math.inf, 3, 0.1 + 0.2)] == [
        "400", "1e+06", "1e+308", "0.001", ".nan", "-.inf", "3", "0.30000000000000004"]
