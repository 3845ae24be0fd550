"""Port declarations of port-based objects (TR §4.1, §4.3; Onika §4.3.2).

A module declares its ports on the class, so the checker and `pbo lexicon` know every module
without running it. At run time each port is bound to a slot of the task's local state
variable table; reading the attribute gives the local numpy array, assigning to it copies into
that array (so an output keeps its binding whatever the module assigns).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np


class PortKind(enum.Enum):
    """The six kinds of port. `both` ports transfer at init and on every cycle."""

    IN_CONST = "in-const"
    OUT_CONST = "out-const"
    IN_VAR = "in-var"
    OUT_VAR = "out-var"
    IN_BOTH = "in-both"
    OUT_BOTH = "out-both"

    # The kinds each property names are tuples made once, below the class: looking members up
    # on the class at every call made these properties the checker's most frequent cost.

    @property
    def is_input(self) -> bool:
        return self in _INPUTS

    @property
    def at_init(self) -> bool:
        """Transferred once around `init` (in before, out after)."""
        return self in _AT_INIT

    @property
    def every_cycle(self) -> bool:
        """Transferred around `on` and every `cycle`."""
        return self in _EVERY_CYCLE

    @property
    def needs_initial_value(self) -> bool:
        """An input read before `init` needs a producer that writes at init."""
        return self in _NEEDS_INITIAL_VALUE

    @property
    def supplies_initial_value(self) -> bool:
        return self in _SUPPLIES_INITIAL_VALUE


_INPUTS = (PortKind.IN_CONST, PortKind.IN_VAR, PortKind.IN_BOTH)
_AT_INIT = (PortKind.IN_CONST, PortKind.OUT_CONST, PortKind.IN_BOTH, PortKind.OUT_BOTH)
_EVERY_CYCLE = (PortKind.IN_VAR, PortKind.OUT_VAR, PortKind.IN_BOTH, PortKind.OUT_BOTH)
_NEEDS_INITIAL_VALUE = (PortKind.IN_CONST, PortKind.IN_BOTH)
_SUPPLIES_INITIAL_VALUE = (PortKind.OUT_CONST, PortKind.OUT_BOTH)


Shape = tuple[int | str, ...]
ANY_DTYPE = "any"  # a port that takes its variable's dtype (and, with shape None, its shape)


@dataclass(frozen=True)
class PortSpec:
    """What a module declares about one port: the checker's and the lexicon's view of it."""

    name: str
    kind: PortKind
    variable: str
    dtype: str  # a numpy dtype name, or ANY_DTYPE
    shape: Shape | None  # None: whatever shape the variable has
    doc: str = ""

    def resolved_shape(self, dims: dict[str, int], variable_shape: tuple[int, ...] = ()) -> tuple[int, ...]:
        """The shape with named dims replaced by their values (KeyError names a missing dim)."""
        if self.shape is None:
            return tuple(variable_shape)
        return tuple(dims[d] if isinstance(d, str) else int(d) for d in self.shape)


class Port:
    """A class-level port declaration; a data descriptor bound to the task's local table."""

    kind: PortKind

    def __init__(self, variable: str, dtype: str = "float64", shape: Shape | int | str | None = (), doc: str = "") -> None:
        if isinstance(shape, (int, str)):
            shape = (shape,)
        self.variable = variable
        # an unknown dtype fails where the module is written, not at run time
        self.dtype = dtype if dtype == ANY_DTYPE else str(np.dtype(dtype))
        self.shape: Shape | None = None if shape is None else tuple(shape)
        self.doc = doc
        self.name = variable
        self.slot = -1

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @property
    def spec(self) -> PortSpec:
        """The declaration as data (made once: ports do not change after class creation)."""
        spec = self.__dict__.get("_spec")
        if spec is None or spec.name != self.name:
            spec = self._spec = PortSpec(self.name, self.kind, self.variable, self.dtype, self.shape, self.doc)
        return spec

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        try:
            return obj._pbo_ports[self.slot]
        except (AttributeError, IndexError):
            raise AttributeError(
                f"port '{self.name}' of {type(obj).__name__} is not bound: ports exist only in a spawned task"
            ) from None

    def __set__(self, obj: Any, value: Any) -> None:
        np.copyto(self.__get__(obj), value)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.variable!r}, dtype={self.dtype!r}, shape={self.shape!r})"


class InConst(Port):
    """Read from the global table once, before `init`."""

    kind = PortKind.IN_CONST


class OutConst(Port):
    """Written to the global table once, after `init`."""

    kind = PortKind.OUT_CONST


class InVar(Port):
    """Read before `on` and before every `cycle`."""

    kind = PortKind.IN_VAR


class OutVar(Port):
    """Read before `on` (to take over the current value), written after `on` and every `cycle`."""

    kind = PortKind.OUT_VAR


class InBoth(Port):
    """An in-const that is also read before every cycle."""

    kind = PortKind.IN_BOTH


class OutBoth(Port):
    """An out-const that is also written after every cycle."""

    kind = PortKind.OUT_BOTH
