"""Combined modules (TR §4.5): several modules run as one task with one local table.

    ctc: {module: combined, rtpu: rtpu0, period: 1 ms, params: {members: [
            {module: pid_joint, params: {kp: 900, kd: 60, gravity_feedforward: false}, ports: {tau: qdd_r}},
            {module: inverse_dynamics}]}}

Each member keeps its own ports and parameters; a variable that one member writes and another
reads links them inside the task (local: it never touches the global table or the bus), unless
`export` names it (an outside task reads it too). The task's own ports are the members' other
links, one per variable: a variable several members read is read from the table once. Members
run in the order given, so list producers before their consumers. This is the runtime's generic
combinator, not a module of its own: it only uses what `pbo_runtime` gives every module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from pbo_runtime import ModuleError, ParamError, PortBasedObject, PortSpec, Status, module_class

_MEMBER_KEYS = ("module", "params", "ports")


@dataclass(frozen=True)
class Member:
    """One module inside a combined task: its class, its built params, its port -> variable links."""

    name: str
    cls: Any
    params: Any
    links: tuple[tuple[PortSpec, str], ...]


@dataclass(frozen=True)
class CombinedParams:
    members: Any  # a list of {module, params, ports}
    export: tuple[str, ...] = ()  # member-to-member variables other tasks read too: also written to the table
    if TYPE_CHECKING:  # each instance's own, set by __post_init__; declared so only to stay out of the parameters
        built: ClassVar[tuple[Member, ...]]

    def __post_init__(self) -> None:
        if not isinstance(self.members, (list, tuple)) or len(self.members) < 2:
            raise ValueError(f"members must list at least two modules to combine, got: {self.members!r}")
        built = []
        for number, entry in enumerate(self.members, start=1):
            if not isinstance(entry, dict) or "module" not in entry:
                raise ValueError(f"member {number} must be a mapping with a module, got: {entry!r}")
            unknown = sorted(set(entry) - set(_MEMBER_KEYS))
            if unknown:
                raise ValueError(f"member {number} has unknown key(s) {', '.join(repr(k) for k in unknown)} "
                                 f"(valid: {', '.join(_MEMBER_KEYS)})")
            if entry["module"] == "combined":
                raise ValueError(f"member {number}: a combined module cannot contain another; list its members instead")
            try:
                cls = module_class(str(entry["module"]))
            except Exception as exc:
                raise ValueError(f"member {number}: {exc}") from None
            try:
                params = cls.build_params(dict(entry.get("params") or {}))
            except ParamError as exc:  # which member: two may share a parameter's name
                raise ValueError(f"member {number} ({entry['module']}): {exc}") from None
            relinks = dict(entry.get("ports") or {})
            declared = {p.name: p for p in cls.ports_for(params)}
            unknown_ports = sorted(set(relinks) - set(declared))
            if unknown_ports:
                raise ValueError(
                    f"member {number} ({entry['module']}) has no port(s) {', '.join(repr(p) for p in unknown_ports)} "
                    f"(ports: {', '.join(declared)})"
                )
            links = tuple((port, str(relinks.get(port.name, port.variable))) for port in declared.values())
            built.append(Member(f"{number}:{entry['module']}", cls, params, links))
        object.__setattr__(self, "built", tuple(built))
        writers: dict[str, str] = {}
        for member in built:
            for port, variable in member.links:
                if not port.kind.is_input:
                    if variable in writers:
                        raise ValueError(f"members {writers[variable]} and {member.name} both write '{variable}'")
                    writers[variable] = member.name
        internal = self.internal_variables()
        for name in self.export:
            if name not in internal:
                raise ValueError(f"export names '{name}', which is no member-to-member variable (one member writes it, "
                                 f"another reads it): internal variables: {', '.join(sorted(internal)) or 'none'}; "
                                 "a member's other links are the task's own ports, in the table already")

    def internal_variables(self) -> set[str]:
        """Variables one member writes and another reads: members read them from the writer, same cycle."""
        written = {v for m in self.built for p, v in m.links if not p.kind.is_input}
        read = {v for m in self.built for p, v in m.links if p.kind.is_input}
        return written & read

    def local_variables(self) -> set[str]:
        """Internal variables that never touch the table (all but the exported ones)."""
        return self.internal_variables() - set(self.export)


class _MemberContext:
    """A member's view of the task's context: the same services, with `written_at` asked by the
    member's port name (the task's ports are named by variable; a local link never reaches the table)."""

    def __init__(self, context: Any, variable_of: dict[str, str], exported: set[str]) -> None:
        self._context = context
        self._variable_of = variable_of
        self._exported = exported

    def __getattr__(self, name: str) -> Any:
        return getattr(self._context, name)

    @property
    def period(self) -> float:  # (what a cycle reads is a property: no __getattr__ detour per cycle)
        return self._context.period  # type: ignore[no-any-return]

    @property
    def time(self) -> float:
        return self._context.time  # type: ignore[no-any-return]

    @property
    def event(self) -> Any:
        return self._context.event

    @property
    def actuators_held(self) -> bool:
        return self._context.actuators_held  # type: ignore[no-any-return]

    def written_at(self, port: str) -> float:
        variable = self._variable_of[port]
        return self._context.written_at(variable) if variable in self._exported else -math.inf


class Combined(PortBasedObject):
    """Runs its members as one task: one local table, member-to-member links kept local (TR §4.5)."""

    Params = CombinedParams

    @classmethod
    def ports_for(cls, params: CombinedParams) -> tuple[PortSpec, ...]:
        """One port per outside variable: inputs not written inside, outputs not kept local."""
        internal, local = params.internal_variables(), params.local_variables()
        ports: dict[str, PortSpec] = {}
        for member in params.built:
            for port, variable in member.links:
                if variable in ports or (port.kind.is_input and variable in internal) or variable in local:
                    continue  # read once however many members read it; internal links never read from the table
                ports[variable] = PortSpec(variable, port.kind, variable, port.dtype, port.shape, f"{member.name}.{port.name}")
        return tuple(ports.values())

    def init(self, params: CombinedParams) -> None:
        external = {spec.variable: array for spec, array in zip(type(self).ports_for(params), self.bound_arrays, strict=True)}
        dims = self._pbo_context.dims
        local: dict[str, np.ndarray] = {}
        for variable in params.local_variables():
            port = next(p for m in params.built for p, v in m.links if v == variable and not p.kind.is_input)
            if port.shape is None or port.dtype == "any":
                raise ModuleError(f"local variable '{variable}' needs a port of fixed dtype and shape to be kept local")
            local[variable] = np.zeros(port.resolved_shape(dims), dtype=port.dtype)
        self._members: list[PortBasedObject] = []
        for member in params.built:
            instance = member.cls.__new__(member.cls)
            arrays = []
            for _port, variable in member.links:
                # a local link is a private array; an exported one is the writer's output, read in place
                arrays.append(local[variable] if variable in local else external[variable])
            instance._pbo_ports = arrays
            instance._pbo_context = _MemberContext(self._pbo_context, {p.name: v for p, v in member.links},
                                                   set(external))
            instance.init(member.params)
            self._members.append(instance)
        self._params = [member.params for member in params.built]
        self._cycles = tuple(m.cycle for m in self._members)
        self._stable = tuple(m.stable_cycle for m in self._members)

    def on(self) -> None:
        for member in self._members:
            member.on()

    def cycle(self) -> Status:
        for cycle in self._cycles:
            result = cycle()
            if result != Status.CONTINUE:
                return result
        return Status.CONTINUE

    def stable_cycle(self) -> Status:
        for cycle in self._stable:
            result = cycle()
            if result != Status.CONTINUE:
                return result
        return Status.CONTINUE

    def tune(self, params: CombinedParams) -> None:
        """`pbo set TASK N.kp`: each member whose parameters changed takes its new ones."""
        for index, (member, new) in enumerate(zip(self._members, params.built, strict=True)):
            if new.params != self._params[index]:
                member.tune(new.params)
                self._params[index] = new.params

    def off(self) -> None:
        for member in self._members:
            member.off()

    def kill(self) -> None:
        for member in reversed(getattr(self, "_members", [])):
            member.kill()

    def error(self, exc: BaseException | None) -> Status:
        verdicts = [member.error(exc) for member in self._members]
        return max(verdicts)

    def clear(self) -> bool:
        return all(member.clear() for member in self._members)
