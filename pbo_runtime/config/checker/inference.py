"""Variables made from their ports: pins joined by name (Onika §4.3.1), without a `variables:` entry.

A variable that only connects ports needs no entry: the ports that link it say its dtype and
shape (dim names resolved with `dims:`, or with the plant's robot). An entry is needed only for
what ports cannot say: an initial value, a doc, an object type; an entry that gives no `type:`
takes the type (and the shape, if it gives none) from its ports too. A declared type or shape
always wins, and every port is checked against it as usual.

What inference will not do: make a variable from one explicit `ports: {p: name}` link alone (a
typo would quietly become a new variable: E205 says so), or from ports that declare no dtype or
no shape (`any`, a shape of None: E206 says to declare it), or from ports that disagree (E317 at
each of them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.model import _Link, _PartialVariable, _Task
from pbo_runtime.config.checker.words import _and_list, _show_shape
from pbo_runtime.config.model import Location, VariableSpec
from pbo_runtime.objects.ports import ANY_DTYPE, PortSpec

_Use = tuple[_Task, _Link]


class InferenceChecks(CheckerBase):
    """Rules for variables that take their dtype and shape from the ports that link them."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def port_shape(self, port: PortSpec, variable_shape: tuple[int, ...]) -> tuple[int, ...]: ...
        def check_variable_size(self, name: str, dtype: str, shape: tuple[int, ...], loc: Location) -> bool: ...
        def check_value(self, value: Any, loc: Location, dtype: str, shape: tuple[int, ...], what: str) -> np.ndarray | None: ...

    def infer_variables(self, linked: list[tuple[_Task, list[_Link]]]) -> None:
        """Make a `VariableSpec` for each variable no entry types, from the ports that link it."""
        uses: dict[str, list[_Use]] = {}
        declared, partial = self.var_locs, self.var_partial
        for task, links in linked:
            for link in links:
                if link.variable not in declared or link.variable in partial:
                    uses.setdefault(link.variable, []).append((task, link))
        for name, unlinked in partial.items():
            if name not in uses:
                self.error("E112", f"variable '{name}' has no 'type:', and no task's port links it to give it one", unlinked.loc,
                           "add 'type:' (e.g. type: float64), or link a port to it")
        for var, var_uses in uses.items():
            entry = partial.get(var)
            if entry is None and len(var_uses) == 1 and var_uses[0][1].explicit:
                continue  # a name only one ports: entry uses is more likely a typo than a new variable: E205
            self._infer(var, var_uses, entry)

    def _infer(self, var: str, uses: list[_Use], entry: _PartialVariable | None) -> None:
        typed = [(task, link) for task, link in uses if link.port.dtype != ANY_DTYPE]
        shaped: list[tuple[_Task, _Link, tuple[int, ...]]] = []
        for task, link in uses:
            if link.port.shape is None:
                continue
            try:
                shaped.append((task, link, self.port_shape(link.port, ())))
            except (KeyError, TypeError, ValueError):
                continue  # reported at that port when it is bound (E304, E306)
        if not typed or ((entry is None or entry.shape is None) and not shaped):
            missing = "a dtype" if not typed else "a shape"
            ports = _and_list(
                [f"port '{link.port.name}' of task '{task.name}' is {_declared(link.port)}" for task, link in uses[:3]]
            )
            why = f"no port that links '{var}' declares {missing} ({ports})"
            if entry is not None:
                self.error("E112", f"variable '{var}' has no 'type:', and its ports cannot give one", entry.loc,
                           f"{why}; add 'type:' and 'shape:' to it")
            else:
                self.infer_failed_why[var] = why
            return
        dtype = typed[0][1].port.dtype
        if any(link.port.dtype != dtype for _, link in typed):
            self._disagree(var, [(task, link, link.port.dtype) for task, link in typed], "dtype", lambda d: str(d))
            return
        if entry is not None and entry.shape is not None:
            shape = entry.shape  # declared: the ports are checked against it when they are bound (E302)
        else:
            shape = shaped[0][2]
            if any(found != shape for _, _, found in shaped):
                self._disagree(var, [(task, link, found) for task, link, found in shaped], "shape", _show_shape)
                return
        loc = entry.loc if entry is not None else uses[0][1].loc
        if not self.check_variable_size(var, dtype, shape, loc):
            self.infer_failed.add(var)
            return
        initial = None
        if entry is not None and entry.initial_loc is not None:
            initial = self.check_value(entry.initial, entry.initial_loc, dtype, shape, f"initial value of variable '{var}'")
            if initial is None:
                self.infer_failed.add(var)
                return
            self.out.initial_values[var] = initial
            initial = initial.copy()
            initial.setflags(write=False)
        doc, obj = (entry.doc, entry.object) if entry is not None else ("", None)
        self.out.variables[var] = VariableSpec(var, len(self.out.variables), dtype, shape, doc, obj, loc, initial)
        self.out.inferred.append(var)
        self.var_ok.add(var)
        if entry is None:
            self.var_locs[var] = loc
            self.var_inferred.add(var)

    def _disagree(self, var: str, found: list[tuple[_Task, _Link, Any]], what: str, show: Any) -> None:
        """E317 at each port: the variable is undeclared and its ports give it different dtypes or shapes."""
        self.infer_failed.add(var)
        for task, link, value in found:
            other_task, other_link, other = next((t, lk, v) for t, lk, v in found if v != value)
            self.error(
                "E317",
                f"task '{task.name}' port '{link.port.name}' ({link.port.kind.value}) gives undeclared variable '{var}' {what} "
                f"{show(value)}, but task '{other_task.name}' port '{other_link.port.name}' gives it {what} {show(other)}",
                link.loc,
                f"ports that share a variable agree on its {what}: declare '{var}' under variables: with the {what} "
                "you mean (each port is then checked against it), or link one of the ports to another variable",
            )


def _declared(port: PortSpec) -> str:
    dtype = "any dtype" if port.dtype == ANY_DTYPE else port.dtype
    shape = "any shape" if port.shape is None else f"shape {_show_shape(port.shape)}"
    return f"{dtype}, {shape}"
