"""Variables: their type and shape (with dims), an initial value or a job's argument as an array."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.model import DTYPES, VARIABLE_KEYS, _PartialVariable
from pbo_runtime.config.checker.words import _show_shape, describe, did_you_mean
from pbo_runtime.config.limits import MAX_DIM, MAX_TABLE_BYTES, show_bytes
from pbo_runtime.config.model import Location, ObjectTypeSpec, VariableSpec
from pbo_runtime.config.values import element_problem, non_finite, outside_range
from pbo_runtime.config.values import leaves as _leaves
from pbo_runtime.config.values import nested_shape as _nested_shape
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of


class VariableChecks(CheckerBase):
    """Rules for `variables:`, and the value check an application step reuses."""

    def resolve_shape(self, value: Any, loc: Location, owner: str) -> tuple[int, ...] | None:
        if isinstance(value, YList):
            items: list[Any] = value
            where: Callable[[int], Location] = value.item_loc  # locations are worked out only for an error
        elif (isinstance(value, int) and not isinstance(value, bool)) or isinstance(value, str):
            items = [value]  # 'shape: 6' and 'shape: NDOF' mean one dimension
            where = lambda _index: loc  # noqa: E731
        else:
            self.error(
                "E113",
                f"shape of {owner} must be a list of sizes or dim names, got: {describe(value)}",
                location_of(value, loc),
                "e.g. shape: [NDOF, 4]; leave shape out for a scalar",
            )
            return None
        shape: list[int] = []
        ok = True
        dims = self.out.dims
        for index, item in enumerate(items):
            if isinstance(item, str):
                if item in dims:
                    shape.append(dims[item])
                elif item in self.bad_dims:
                    ok = False  # the dim itself is wrong, and was reported there
                elif (size := self.robot_dim(item)) is not None:
                    shape.append(size)
                else:
                    self.error(
                        "E204",
                        f"shape of {owner} uses dim '{item}', which 'dims' does not define",
                        where(index),
                        did_you_mean(item, dims, "defined"),
                    )
                    ok = False
            elif isinstance(item, int) and not isinstance(item, bool) and 1 <= item <= MAX_DIM:
                shape.append(item)
            elif isinstance(item, int) and not isinstance(item, bool) and item > MAX_DIM:
                self.error("E315", f"shape of {owner}: each size must be at most {MAX_DIM:,}, got: {item:,}", where(index),
                           "a size counts joints, channels or pixels; is a digit too many?")
                ok = False
            else:
                self.error("E305", f"shape of {owner}: each size must be an integer >= 1 or a dim name, got: {describe(item)}",
                           where(index))
                ok = False
        return tuple(shape) if ok else None

    def check_variable_size(self, name: str, dtype: str, shape: tuple[int, ...], loc: Location) -> bool:
        """A variable that fits in the table by itself (E315 at its shape); before any value of it is built."""
        nbytes = math.prod(shape) * _itemsize(dtype)
        if nbytes <= MAX_TABLE_BYTES:
            return True
        self.error("E315", f"variable '{name}' ({dtype}, shape {_show_shape(shape)}) would take {show_bytes(nbytes)}, "
                           f"more than the whole state variable table may hold, {show_bytes(MAX_TABLE_BYTES)}", loc,
                   "the table is copied to and from every task each cycle; check the dims and sizes of the shape")
        return False

    def check_table_size(self, top: YMap) -> None:
        """The variables' data together fit in the table's limit (E316), reported at `variables:`."""
        total = sum(-(-math.prod(v.shape) * _itemsize(v.dtype) // 8) * 8 for v in self.out.variables.values())
        if total > MAX_TABLE_BYTES:
            biggest = sorted(self.out.variables.values(), key=lambda v: math.prod(v.shape) * _itemsize(v.dtype))[-3:]
            self.error("E316", f"the variables take {show_bytes(total)} of state variable table, more than its limit of "
                               f"{show_bytes(MAX_TABLE_BYTES)}",
                       top.key_loc("variables") if "variables" in top else top.loc,
                       "the largest: " + ", ".join(f"'{v.name}' {_show_shape(v.shape)} {v.dtype}" for v in reversed(biggest)))

    def check_value(self, value: Any, loc: Location, dtype: str, shape: tuple[int, ...], what: str,
                    owner: str = "the variable's shape", kind: ObjectTypeSpec | None = None) -> np.ndarray | None:
        """A value for a variable (initial or a job's argument), or of an object type (`owner`), as an array, or an error.
        An object of a `kind` that declares a range has every element in it (E322, at the element)."""
        if isinstance(value, dict):
            self.error("E310", f"{what} must be a number or a list, got: a mapping", location_of(value, loc))
            return None
        found = _nested_shape(value)
        if found is None:
            self.error(
                "E311",
                f"{what} is a ragged list; rows must have equal lengths",
                location_of(value, loc),
                f"give a nested list of shape {_show_shape(shape)}",
            )
            return None
        if isinstance(value, list) and found != shape:
            self.error(
                "E312",
                f"{what} has shape {_show_shape(found)}, but {owner} is {_show_shape(shape)}",
                location_of(value, loc),
                f"give a nested list of shape {_show_shape(shape)}, or one number for every element",
            )
            return None
        leaves = list(_leaves(value))
        if any(map(non_finite, leaves)):  # reported at the value itself: it is the one to fix
            leaf, leaf_loc = next((leaf, where) for leaf, where in _located_leaves(value, loc) if non_finite(leaf))
            self.error("E314", f"{what}: {element_problem(leaf, dtype)}", leaf_loc,
                       "write a finite number; NaN and Inf would travel on to the actuators")
            return None
        for leaf in leaves:
            problem = element_problem(leaf, dtype)
            if problem:
                self.error("E313", f"{what}: {problem}", location_of(value, loc))
                return None
        if kind is not None and kind.range is not None and not all(map(kind.range.admits, leaves)):
            position, (leaf, leaf_loc) = next((i, found) for i, found in enumerate(_located_leaves(value, loc), 1)
                                              if not kind.range.admits(found[0]))
            self.error("E322", f"{what}: {outside_range(kind.name, kind.range, leaf, position if len(leaves) > 1 else 0)}",
                       leaf_loc, f"object type '{kind.name}' declares this range (at {kind.loc.line}:{kind.loc.column})")
            return None
        try:
            array = np.asarray(leaves if not isinstance(value, list) else value, dtype=dtype).reshape(found)
        except (ValueError, TypeError, OverflowError) as exc:
            self.error("E313", f"{what} cannot be stored as {dtype}: {exc}", location_of(value, loc))
            return None
        # One number fills every element (a list has the shape already, checked above). An
        # empty array filled by broadcasting is what np.broadcast_to(...).copy() makes, faster.
        filled = np.empty(shape, dtype=array.dtype)
        filled[...] = array
        return filled

    def check_variables(self, top: YMap) -> None:
        for name, value, key_loc, value_loc in self.entries(
            top, "variables", "variable", "e.g. variables: {q_m: {type: float64, shape: [NDOF]}}"
        ):
            self.var_locs[name] = key_loc
            # (a mapping, as nearly always, needs no location and no message: they are made for the error only)
            spec = value if isinstance(value, YMap) else self.mapping(
                value, value_loc, f"variable '{name}'", "e.g. q_m: {type: float64, shape: [NDOF]}")
            if spec is None:
                continue
            self.var_nodes[name] = spec
            where = f"in variable '{name}'"
            self.keys(spec, VARIABLE_KEYS, (), where, key_loc)  # no type: its ports give it (InferenceChecks)
            dtype: str | None = None
            if "type" in spec:
                raw = spec["type"]  # (its location is looked up only to report it)
                if not isinstance(raw, str):
                    self.text(raw, spec.value_loc("type"), f"type of variable '{name}'")
                elif raw not in DTYPES:
                    self.error(
                        "E303", f"variable '{name}' has unknown type '{raw}'", spec.value_loc("type"), did_you_mean(raw, DTYPES)
                    )
                else:
                    dtype = _dtype_name(raw)
            shape: tuple[int, ...] | None = ()
            if "shape" in spec and spec["shape"] is not None:
                shape_loc = spec.value_loc("shape")
                shape = self.resolve_shape(spec["shape"], shape_loc, f"variable '{name}'")
                if shape is not None and dtype is not None and not self.check_variable_size(name, dtype, shape, shape_loc):
                    shape = None
            doc = ""
            if "doc" in spec and spec["doc"] is not None:
                doc = self.text(spec["doc"], spec.value_loc("doc"), f"doc of variable '{name}'") or ""
            obj: str | None = None
            if "object" in spec:
                obj = spec["object"]
                if not isinstance(obj, str):
                    obj = self.text(obj, spec.value_loc("object"), f"object type of variable '{name}'")
                if obj is not None:
                    self.var_object[name] = obj
            if "initial" in spec:
                self.var_initial.add(name)
                if dtype is not None and shape is not None:
                    initial = self.check_value(
                        spec["initial"], spec.value_loc("initial"), dtype, shape, f"initial value of variable '{name}'"
                    )
                    if initial is not None:
                        self.out.initial_values[name] = initial
            if "type" not in spec and (shape is not None or "shape" not in spec):
                given = shape if "shape" in spec and spec["shape"] is not None else None
                self.var_partial[name] = _PartialVariable(key_loc, given, doc, obj, spec.get("initial"),
                                                          spec.value_loc("initial") if "initial" in spec else None)
                continue
            if dtype is None or shape is None:
                continue
            self.var_ok.add(name)
            initial = self.out.initial_values.get(name)
            if initial is not None:
                initial = initial.copy()
                initial.setflags(write=False)
            self.out.variables[name] = VariableSpec(name, len(self.out.variables), dtype, shape, doc, obj, key_loc, initial)


@functools.cache
def _dtype_name(raw: str) -> str:
    """numpy's canonical name of a dtype (working it out costs microseconds: once per name)."""
    return str(np.dtype(raw))


@functools.cache
def _itemsize(dtype: str) -> int:
    return np.dtype(dtype).itemsize


def _located_leaves(value: Any, loc: Location) -> Iterable[tuple[Any, Location]]:
    """Each number of a value with where it was written (a scalar: the value's own place)."""
    if isinstance(value, YList):
        for index, item in enumerate(value):
            yield from _located_leaves(item, value.item_loc(index))
    elif isinstance(value, list):
        for item in value:
            yield from _located_leaves(item, loc)
    else:
        yield value, loc
