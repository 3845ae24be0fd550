"""Object types and named objects (Onika §4.4.1): what a job's object may be, and values given by name.

`object_types:` is Onika's "preference file": each type an object may have, with its dtype and
shape (and a unit and a doc for the people who fill it in). A variable marked `object: <type>` is
where a job writes an object of that type. Without an `object_types:` section (in the file or an
included one) each type a variable is marked with is implied by the variable itself, as before
the section existed. `objects:` names values of a type, so an application step can say
`- reach: home` and an HMI can show `home` as an icon of the job dictionary.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.model import DTYPES, OBJECT_KEYS, OBJECT_TYPE_KEYS
from pbo_runtime.config.checker.words import _show_shape, did_you_mean
from pbo_runtime.config.model import Location, ObjectSpec, ObjectTypeSpec
from pbo_runtime.config.values import range_problem
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of, plain
from pbo_runtime.objects.ranges import Range

_TYPE_EXAMPLE = "e.g. object_types: {joint_position: {type: float64, shape: [NDOF], unit: rad}}"
_OBJECT_EXAMPLE = "e.g. objects: {home: {type: joint_position, value: [0, 0, 0, 0, 0, 0]}}"


class ObjectChecks(CheckerBase):
    """Rules for `object_types:`, the variables marked `object:`, and `objects:`."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def resolve_shape(self, value: Any, loc: Location, owner: str) -> tuple[int, ...] | None: ...
        def check_value(self, value: Any, loc: Location, dtype: str, shape: tuple[int, ...], what: str,
                        owner: str = "the variable's shape", kind: ObjectTypeSpec | None = None) -> np.ndarray | None: ...

    def check_object_types(self, top: YMap) -> None:
        """The declared types, then each variable's marking against them (or the types it implies)."""
        declared = "object_types" in top and top["object_types"] is not None
        broken: set[str] = set()  # declared but wrong (reported there): no follow-on "not declared"
        for name, value, key_loc, value_loc in self.entries(top, "object_types", "object type", _TYPE_EXAMPLE):
            spec = self.mapping(
                value, value_loc, f"object type '{name}'", f"e.g. {name}: {{type: float64, shape: [NDOF], unit: rad}}"
            )
            if spec is None:
                broken.add(name)
                continue
            self.keys(spec, OBJECT_TYPE_KEYS, ("type",), f"in object type '{name}'", key_loc)
            dtype = None
            if "type" in spec:
                raw = self.text(spec["type"], spec.value_loc("type"), f"type of object type '{name}'")
                if raw is not None and raw not in DTYPES:
                    self.error(
                        "E303",
                        f"object type '{name}' has unknown type '{raw}'",
                        spec.value_loc("type"),
                        did_you_mean(raw, DTYPES),
                    )
                elif raw is not None:
                    dtype = str(np.dtype(raw))
            shape: tuple[int, ...] | None = ()
            if "shape" in spec and spec["shape"] is not None:
                shape = self.resolve_shape(spec["shape"], spec.value_loc("shape"), f"object type '{name}'")
            unit = doc = ""
            for key in ("unit", "doc"):
                if key in spec and spec[key] is not None:
                    text = self.text(spec[key], spec.value_loc(key), f"{key} of object type '{name}'")
                    if key == "unit":
                        unit = text or ""
                    else:
                        doc = text or ""
            ranged = "range" in spec and spec["range"] is not None
            allowed = self.object_range(spec, name) if ranged else None
            if dtype is None or shape is None or (ranged and allowed is None):
                broken.add(name)
                continue
            self.out.object_types[name] = ObjectTypeSpec(name, dtype, shape, unit, doc, key_loc, range=allowed)
        self.bad_object_types = broken
        self.check_markings(top, declared)

    def object_range(self, spec: YMap, name: str) -> Range | None:
        """An object type's `range: [low, high]`: two finite numbers, low < high; else E321 and None."""
        value, loc = spec["range"], spec.value_loc("range")
        if (
            isinstance(value, YList)
            and len(value) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            and all(map(math.isfinite, value))
            and value[0] < value[1]
        ):
            return Range(float(value[0]), float(value[1]), low_open=False, high_open=False)
        self.error(
            "E321",
            f"range of object type '{name}' must be [low, high], two finite numbers with low < high, got: {plain(value)!r}",
            location_of(value, loc),
            "e.g. range: [-3.2, 3.2]: every element of an object of the type",
        )
        return None

    def check_markings(self, top: YMap, declared: bool) -> None:
        """Each variable marked `object: <type>` holds values of that type: declared, or implied by it."""
        implied: dict[str, str] = {}  # type -> the variable that implies it
        for variable, type_name in self.var_object.items():
            spec = self.out.variables.get(variable)
            where = _marking_loc(top, variable, self.var_locs[variable])
            if declared:
                if type_name in self.bad_object_types:
                    continue
                kind = self.out.object_types.get(type_name)
                if kind is None:
                    self.error(
                        "E711",
                        f"variable '{variable}' is marked object: '{type_name}', which 'object_types' does not declare",
                        where,
                        did_you_mean(type_name, self.out.object_types, "declared"),
                    )
                    self.bad_object_types.add(type_name)
                    continue
                if spec is not None and (spec.dtype, spec.shape) != (kind.dtype, kind.shape):
                    self.error(
                        "E712",
                        f"variable '{variable}' ({spec.dtype} {_show_shape(spec.shape)}) is marked object: '{type_name}', "
                        f"but objects of type '{type_name}' are {kind.dtype} {_show_shape(kind.shape)}",
                        where,
                        "give the variable the type's dtype and shape, or mark it with another object type",
                    )
                    continue
                initial = self.out.initial_values.get(variable)
                problem = range_problem(initial, type_name, kind.range) if initial is not None else ""
                if problem:  # the first object the run starts with
                    entry = self.var_nodes.get(variable)
                    self.error("E322", f"initial value of variable '{variable}': {problem}",
                               entry.value_loc("initial") if entry is not None and "initial" in entry else where,
                               f"object type '{type_name}' declares this range (at {kind.loc.line}:{kind.loc.column})")
                continue
            if spec is None:
                self.bad_object_types.add(type_name)  # the variable is wrong, and was reported there
                continue
            first = implied.get(type_name)
            if first is None:
                implied[type_name] = variable
                self.out.object_types[type_name] = ObjectTypeSpec(type_name, spec.dtype, spec.shape, doc=spec.doc,
                                                                  loc=spec.loc, declared=False)
                continue
            kind = self.out.object_types[type_name]
            if (spec.dtype, spec.shape) != (kind.dtype, kind.shape):
                self.error("E712", f"variables '{first}' ({kind.dtype} {_show_shape(kind.shape)}) and '{variable}' "
                                   f"({spec.dtype} {_show_shape(spec.shape)}) are both marked object: '{type_name}'",
                           where, f"an object type has one dtype and shape: mark '{variable}' with another type, or declare "
                                  f"the types under object_types:")

    def check_objects(self, top: YMap) -> None:
        for name, value, key_loc, value_loc in self.entries(top, "objects", "object", _OBJECT_EXAMPLE):
            self.object_locs[name] = key_loc
            spec = self.mapping(
                value, value_loc, f"object '{name}'", f"e.g. {name}: {{type: joint_position, value: [0, 0, 0, 0, 0, 0]}}"
            )
            if spec is None:
                continue
            self.keys(spec, OBJECT_KEYS, ("type", "value"), f"in object '{name}'", key_loc)
            type_name = self.text(spec["type"], spec.value_loc("type"), f"type of object '{name}'") if "type" in spec else None
            doc = ""
            if "doc" in spec and spec["doc"] is not None:
                doc = self.text(spec["doc"], spec.value_loc("doc"), f"doc of object '{name}'") or ""
            if type_name is None or type_name in self.bad_object_types:
                continue
            kind = self.out.object_types.get(type_name)
            if kind is None:
                self.error(
                    "E711",
                    f"object '{name}' has type '{type_name}', which no object type declares",
                    spec.value_loc("type"),
                    did_you_mean(type_name, self.out.object_types, "object types")
                    if self.out.object_types
                    else "declare it under object_types:, or mark a variable object: " + type_name,
                )
                continue
            if "value" not in spec:
                continue
            array = self.check_value(spec["value"], spec.value_loc("value"), kind.dtype, kind.shape,
                                     f"value of object '{name}'", f"the shape of object type '{type_name}'", kind)
            if array is None:
                continue
            array.setflags(write=False)
            self.out.objects[name] = ObjectSpec(name, type_name, array, doc, key_loc)

    def check_object_names(self) -> None:
        """An object is an icon of the job dictionary beside jobs and applications: their names differ."""
        for name, loc in self.object_locs.items():
            for what, names in (("job", self.job_names), ("application", self.app_names)):
                if name in names:
                    self.error("E717", f"'{name}' names both an object and a{'n' if what == 'application' else ''} {what}", loc,
                               "the job dictionary shows jobs, applications and objects by name; rename one")

    def objects_of_type(self, type_name: str | None) -> str:
        """The named objects of a type, for a hint."""
        names = [o.name for o in self.out.objects.values() if o.type == type_name]
        return ", ".join(names) if names else "none yet"


def _marking_loc(top: YMap, variable: str, fallback: Location) -> Location:
    """Where a variable's `object:` value is written, if its entry is a mapping (it is, once marked)."""
    section = top.get("variables")
    entry = section.get(variable) if isinstance(section, YMap) else None
    if isinstance(entry, YMap) and "object" in entry:
        return entry.value_loc("object")
    return fallback
