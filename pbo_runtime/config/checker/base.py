"""The checker's core: the state of one pass, how it reports a problem, the helpers that check a
value's YAML shape (a mapping, its keys, a name, text, a flag, an integer, a quantity). The pass
itself, which runs the rules the mixins of this package define, in order, is the whole checker's
(`config.checker._Checker.run`).
"""

from __future__ import annotations

import difflib
import functools
import math
import re
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from pbo_runtime.config.checker.model import Checked, DriverLookup, ModuleLookup, _Claim, _PartialVariable, _Task
from pbo_runtime.config.checker.words import describe, did_you_mean
from pbo_runtime.config.limits import MAX_DIM, MAX_NAME, MAX_PERIOD, MAX_TIME, MIN_PERIOD
from pbo_runtime.config.model import Location
from pbo_runtime.config.units import TIME, parse_quantity
from pbo_runtime.config.yaml_nodes import YList, YMap, location_of
from pbo_runtime.errors import ConfigError, Note
from pbo_runtime.objects import registry


class CheckerBase:
    """The state of one pass over one document and the helpers every rule uses."""

    def __init__(self, file: str, module_lookup: ModuleLookup, module_names: Callable[[], Iterable[str]] | None,
                 driver_lookup: DriverLookup | None = None) -> None:
        self.file = file
        self.module_lookup = module_lookup
        self.module_names = module_names
        self.driver_lookup = driver_lookup or registry.driver_class
        self._drivers: dict[str, Any] = {}
        self._driver_errors: dict[str, str] = {}  # why a driver could not be found, by name
        self._claims: dict[str, list[_Claim]] = {}
        self.out = Checked()
        self.rtpu_names: set[str] = set()
        self.bad_dims: set[str] = set()  # dims given but refused (reported at the dim)
        self.dims_node: YMap | None = None  # the file's dims: mapping, for errors about a dim
        self.var_initial: set[str] = set()
        self.var_object: dict[str, str] = {}
        self.var_locs: dict[str, Location] = {}
        self.var_ok: set[str] = set()
        self.tasks: dict[str, _Task] = {}
        self.task_names: set[str] = set()
        self.config_names: set[str] = set()
        self.config_members: dict[str, list[tuple[str, Location]]] = {}
        self.config_repeats: dict[str, set[str]] = {}  # tasks flagged E407 (a module repeated), per configuration
        self.config_locs: dict[str, Location] = {}
        self.config_list_locs: dict[str, Location] = {}  # where each configuration's list of tasks is written
        self.job_names: set[str] = set()
        self.expression_names: set[str] = set()
        self.device_names: set[str] = set()
        self.var_nodes: dict[str, YMap] = {}  # each variable's YAML entry, for the place of its type: or shape:
        self.var_links: dict[str, list[Any]] = {}  # variable -> every port linked to it (_Linked), for E301/E302
        self.plant_written = False  # the file gives plant: (right or wrong)
        self.device_nodes: dict[str, YMap] = {}  # each device's YAML entry, for the place of one of its options
        self.sources: dict[str, list[str]] = {}
        self.app_names: set[str] = set()
        self.bad_object_types: set[str] = set()  # object types refused (reported there): no follow-on errors
        self.object_locs: dict[str, Location] = {}  # every object named under objects:, right or wrong
        self._port_shapes: dict[Any, tuple[int, ...]] = {}  # a port's declared shape -> resolved with the dims
        # variables no entry (or an entry without a type) declares, which take their type and shape from their ports
        self.var_partial: dict[str, _PartialVariable] = {}  # an entry that gives no type: the rest of it
        self.var_inferred: set[str] = set()  # made from their ports alone (no entry at all)
        self.infer_failed: set[str] = set()  # their ports disagree (reported at each port)
        self.infer_failed_why: dict[str, str] = {}  # their ports cannot define them: why, for the hint
        self._robot_dims: dict[str, int] | None = None
        self._fixed_ports: dict[Any, tuple[Any, ...]] = {}  # a module class whose ports are not made from params -> its ports
        self._sized_params: dict[Any, tuple[tuple[str, tuple[Any, ...]], ...]] = {}  # a Params class -> its fields of one size

    # --- dims ---------------------------------------------------------------------------------

    def robot_dim(self, name: str) -> int | None:
        """A dim 'dims:' does not give, from the plant's robot (NDOF: the joints of its model), or None.

        Found once, it joins the subsystem's dims (modules read NDOF from them too), and the check
        says where it came from. A dim 'dims:' gives, even wrongly, is never replaced.
        """
        if name in self.bad_dims:
            return None
        if self._robot_dims is None:
            self._robot_dims = self._plant_robot_dims()
        size = self._robot_dims.get(name)
        if size is not None:
            self.out.dims[name] = size
            self.out.robot_dims[name] = size
        return size

    def _plant_robot_dims(self) -> dict[str, int]:
        """The dims of the plant's robot model (entry-point group pbo.robots); {} when there is none."""
        plant = self.out.plant
        if plant is None:
            return {}
        try:
            dims = registry.robot_dims(plant.model)
        except Exception:  # an unknown model: the dim stays undefined, reported where it is used
            return {}
        if not isinstance(dims, dict):
            return {}
        return {k: v for k, v in dims.items()
                if isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_DIM}

    # --- reporting --------------------------------------------------------------------------

    def error(self, code: str, message: str, loc: Location, hint: str = "",
              notes: Iterable[tuple[Location, str]] = ()) -> None:
        """Report at `loc`, where the fix goes; `notes` are the related places (location, what is there)."""
        self.out.errors.append(ConfigError(message, loc.file, loc.line, loc.column, hint, code=code, notes=_notes(notes)))

    def warn(self, code: str, message: str, loc: Location, hint: str = "",
             notes: Iterable[tuple[Location, str]] = ()) -> None:
        self.out.warnings.append(ConfigError(message, loc.file, loc.line, loc.column, hint, severity="warning", code=code,
                                             notes=_notes(notes)))

    # --- shape helpers ----------------------------------------------------------------------

    def mapping(self, value: Any, loc: Location, what: str, example: str = "") -> YMap | None:
        """The value if it is a mapping, else an error saying what was expected."""
        if isinstance(value, YMap):
            return value
        self.error("E113", f"{what} must be a mapping, got: {describe(value)}", location_of(value, loc), example)
        return None

    def keys(self, m: YMap, allowed: Sequence[str], required: Sequence[str], where: str, owner_loc: Location) -> None:
        # Nearly always every key is allowed and every required one is there: two C-level set
        # operations say so (this runs for every task and variable of a file); else find out which.
        if m.keys() <= (_key_set(allowed) if isinstance(allowed, tuple) else frozenset(allowed)) and all(
            key in m for key in required
        ):
            return
        missing = [key for key in required if key not in m]
        for key in m:
            if key not in allowed:
                close = difflib.get_close_matches(str(key), missing, n=1, cutoff=0.6)
                if close:  # one mistake, one error: a misspelt required key
                    missing.remove(close[0])
                    self.error(
                        "E111",
                        f"unknown key '{key}' {where}: did you mean the required key '{close[0]}'?",
                        m.key_loc(key),
                        f"rename it '{close[0]}:'",
                    )
                else:
                    self.error("E111", f"unknown key '{key}' {where}", m.key_loc(key), did_you_mean(key, allowed))
        if not missing:
            return
        subject = where[3:] if where.startswith("in ") else "the file" if where == "at the top level" else where
        for key in missing:
            self.error(
                "E112", f"{subject} has no '{key}:', which is required", owner_loc, f"add '{key}:' (keys: {', '.join(allowed)})"
            )

    def name(self, key: object, loc: Location, what: str) -> str | None:
        if isinstance(key, str) and key:
            self.name_length(key, loc, what)
            return key  # a name too long is reported, and still checked as the name it is
        self.error("E118", f"{what} names must be text, got: {describe(key)}", loc, "write the name as plain text, e.g. q_m")
        return None

    def name_length(self, name: str, loc: Location, what: str) -> bool:
        """True if `name` is at most MAX_NAME characters long; else E218 at it."""
        if len(name) <= MAX_NAME:
            return True
        shown = name if len(name) <= 60 else f"{name[:30]}...{name[-10:]}"
        self.error("E218", f"{what} name '{shown}' is {len(name):,} characters long, more than the {MAX_NAME} a name may have",
                   loc, f"shorten it to at most {MAX_NAME} characters")
        return False

    def text(self, value: Any, loc: Location, what: str) -> str | None:
        if isinstance(value, str):
            return value
        self.error("E114", f"{what} must be text, got: {describe(value)}", location_of(value, loc))
        return None

    def boolean(self, value: Any, loc: Location, what: str) -> bool | None:
        if isinstance(value, bool):
            return value
        self.error("E115", f"{what} must be true or false, got: {describe(value)}", location_of(value, loc))
        return None

    def integer(self, value: Any, loc: Location, what: str, minimum: int | None = None) -> int | None:
        if not isinstance(value, int) or isinstance(value, bool):
            self.error("E116", f"{what} must be an integer, got: {describe(value)}", location_of(value, loc))
            return None
        if minimum is not None and value < minimum:
            self.error("E117", f"{what} must be >= {minimum}, got: {value}", loc)
            return None
        return value

    def quantity(self, value: Any, loc: Location, kind: str, what: str, positive: bool = True,
                 longest: float | None = MAX_TIME) -> float | None:
        """The value in SI units, or None and an error: not a quantity of its kind (E501), not > 0 or
        >= 0 (E502), a time longer than `longest` (the caller's own bounds when None) or too large (E513)."""
        try:
            number = parse_quantity(value, kind)
        except ValueError as exc:
            hint = ""
            if kind == TIME and "that is a frequency" in str(exc):
                hint = "give a rate as 'rate: 1 kHz', or a period as 'period: 1 ms'"
            self.error("E501", f"{what}: {exc}", location_of(value, loc), hint)
            return None
        if positive and number <= 0:
            self.error("E502", f"{what} must be > 0, got: {value}", loc)
            return None
        if not positive and number < 0:
            self.error("E502", f"{what} must be >= 0, got: {value}", loc)
            return None
        if kind == TIME and longest is not None and not number <= longest:
            self.error("E513", f"{what} must be at most a day ({longest:,.0f} s), got: {value}", loc,
                       "a time longer than a day is a typo or a unit mixed up (ms, s, min, h)")
            return None
        if not math.isfinite(number):  # a finite number times its unit: 1e308 GB/s
            self.error("E513", f"{what} is too large to compute with, got: {value}", loc)
            return None
        return number

    def period_bounds(self, period: float, spec: YMap, key: str, name: str) -> bool:
        """True if a task's period (given as a period, a rate or a min_interarrival) is in
        [MIN_PERIOD, MAX_PERIOD]; else E513 at the value."""
        if MIN_PERIOD <= period <= MAX_PERIOD:
            return True
        bounds = "between one cycle an hour and 100 kHz" if key == "rate" else "between 10 us and 1 h"
        self.error("E513", f"{key} of task '{name}' must be {bounds}, got: {spec[key]}", spec.value_loc(key),
                   "a task runs at least once an hour and at most every 10 us: is the unit right?")
        return False

    def section(self, top: YMap, key: str, example: str) -> YMap | None:
        """A top-level section that maps names to entries; None (and an error) if it is not one."""
        if key not in top or top[key] is None:
            return None
        return self.mapping(top[key], top.value_loc(key), f"'{key}'", example)

    def entries(self, top: YMap, key: str, what: str, example: str) -> Iterator[tuple[str, Any, Location, Location]]:
        """Each entry of a top-level section that maps names to entries, as (name, value, where the
        name is, where the value is); an entry whose name is not text is reported and left out."""
        section = self.section(top, key, example)
        if section is None:
            return
        for raw, value in section.items():
            key_loc = section.key_loc(raw)
            name = self.name(raw, key_loc, what)
            if name is not None:
                yield name, value, key_loc, section.value_loc(raw)


@functools.lru_cache(maxsize=64)
def _key_set(allowed: Sequence[str]) -> frozenset[str]:
    """The allowed keys of a kind of entry as a set (the tuples of checker.model: a few, made once)."""
    return frozenset(allowed)


def _notes(notes: Iterable[tuple[Location, str]]) -> tuple[Note, ...]:
    return tuple(Note(message, loc.file, loc.line, loc.column) for loc, message in notes)


def _written_in(node: Any) -> Iterator[tuple[Any, Location, bool]]:
    """Everything a params tree writes, in document order: (the text, where it is, whether it is a key)."""
    if isinstance(node, YMap):
        for key, value in node.items():
            yield key, node.key_loc(key), True
            yield value, node.value_loc(key), False
            yield from _written_in(value)
    elif isinstance(node, YList):
        for index, item in enumerate(node):
            yield item, node.item_loc(index), False
            yield from _written_in(item)


def named_in(node: Any, text: str) -> Location | None:
    """Where a task's params write `text` as a value (a join's input in `inputs:`), or None."""
    return next((loc for written, loc, is_key in _written_in(node) if not is_key and written == text), None)


def key_in(node: Any, text: str) -> Location | None:
    """Where a task's params give a key named `text` (a parameter, a member's key), or None."""
    return next((loc for written, loc, is_key in _written_in(node) if is_key and written == text), None)


def named_by(node: YMap, message: str, skip: Sequence[str] = ()) -> Location | None:
    """Where in `node` (a task's params, a device's options) the thing a refusal names is written: a
    value or key it quotes ('inverse_dynamix', 'ki'), Owner.name, or the first key it names ("kd must
    be >= 0", but none of `skip`); None when it names none of them."""
    for text in [*re.findall(r"'([^']+)'", message), *re.findall(r"\b\w+\.(\w+)\b", message)]:
        found = named_in(node, text) or key_in(node, text)
        if found is not None:
            return found
    named = next((word for word in re.findall(r"\b\w+\b", message) if word in node and word not in skip), None)
    return location_of(node[named], node.value_loc(named)) if named is not None else None


def param_value_at(params: Any, name: str, index: Sequence[int] = ()) -> Location | None:
    """Where a task's params write parameter `name` (its element `index` in a list), or None."""
    if not isinstance(params, YMap) or name not in params:
        return None
    node, loc = params[name], params.value_loc(name)
    for i in index:
        if not isinstance(node, YList) or not 0 <= i < len(node):
            break
        node, loc = node[i], node.item_loc(i)
    return location_of(node, loc)
