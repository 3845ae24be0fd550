"""Placement queries: which lexicon modules can be dropped into a configuration, and why not the rest.

Onika's canvas dims the tasks of the lexicon that cannot be placed legally (§4.3.2). A module
dropped on the canvas becomes a new task whose ports join the variables of their own names; it
is legal where the configuration's rules (the checker's, docs/configuration.md) still hold with
it. The first rule it would break is the answer, worded and coded as `pbo check` would:

- E407: the configuration runs the module already writing the variables its outputs would write
  (an instance of a module is the module with its outputs' variables: a second join, or a second
  combined module, writing variables of its own is a second instance);
- E208, E601, E609, E610: the device it opens (its `device` parameter) is not declared, is exclusive and
  held by a task of the configuration, lacks a driver option the module needs (its `DEVICES`:
  robot_torque on an arm in position mode), or is of another kind (a camera for fk_jacobian_spp);
- E301, E302, E304, E206: a port and its variable disagree on dtype or shape, a port's shape names
  an undefined dim, or a port of any dtype names a variable nothing defines;
- E401: an output port would be a second writer of a variable;
- E404: an output port would write, only after each cycle, a const another task reads before its init;
- E403, E404, E405: a const input (read at init, as the task is spawned) nobody writes, whose
  writer writes it only after each cycle, or that only a job's object sets.

An in-var nobody writes yet is no refusal: the canvas is being built; such inputs are listed as
open, the way a configuration is only required to be complete when it is saved as a job (§4.3.3).

`Placement` indexes one configuration once (writers by variable, const readers, modules and
exclusive devices in use) and each module's ports once, so a query is a few dictionary lookups
per port; `add_task`/`remove_task` keep the index current as tasks are placed or removed.
`placement_report` is the plain-data entry (JSON-able dict out) for the CLI and the API.

No rule above depends on the RTPU the task would run on (timing is judged by warnings, W501-W503,
once wcets are given): the RTPU is checked to exist and reported back.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from pbo_runtime.config.model import Subsystem, TaskSpec
from pbo_runtime.objects import registry
from pbo_runtime.objects.ports import ANY_DTYPE, PortKind

_JOIN_HINT = "an output has one writer; join them with a join connector (TR Figure 6)"


@dataclass(frozen=True)
class Verdict:
    """Whether a module can be placed; if not, the first rule it would break, as the checker words it."""

    module: str
    legal: bool
    code: str = ""
    reason: str = ""
    hint: str = ""
    links: dict[str, str] = field(default_factory=dict)  # port -> variable it would join
    new_variables: tuple[str, ...] = ()  # variables the placed task's ports would define
    open_inputs: tuple[str, ...] = ()  # in-vars no task of the configuration writes yet

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"module": self.module, "legal": self.legal}
        if not self.legal:
            out.update(code=self.code, reason=self.reason, hint=self.hint)
        out.update(links=dict(self.links), new_variables=list(self.new_variables), open_inputs=list(self.open_inputs))
        return out


@dataclass(frozen=True)
class _Port:
    """A module's port as placement needs it: resolved once per subsystem."""

    name: str
    kind: PortKind
    kind_text: str
    variable: str
    dtype: str  # ANY_DTYPE when the port takes its variable's
    shape: tuple[int, ...] | None  # None: takes its variable's
    is_input: bool
    needs_init: bool  # in-const, in-both
    supplies_init: bool  # out-const, out-both
    problem: tuple[str, str, str] | None = None  # (code, reason, hint) when its declared shape does not resolve


@dataclass(frozen=True)
class _Module:
    name: str
    ports: tuple[_Port, ...]
    device: str | None  # the device its default params open
    problem: tuple[str, str, str] | None = None  # the module cannot be imported or list its ports
    needs: tuple[tuple[str, Any], ...] = ()  # the driver options it needs of that device (its DEVICES)


class Placement:
    """One configuration (a list of tasks of a checked subsystem), indexed for placement queries."""

    def __init__(self, subsystem: Subsystem, tasks: Iterable[str], configuration: str = "",
                 module_lookup: Callable[[str], Any] = registry.module_class) -> None:
        self.subsystem = subsystem
        self.configuration = configuration
        self.where = f"in configuration '{configuration}'" if configuration else "on the canvas"
        self._lookup = module_lookup
        self._modules: dict[str, _Module] = {}
        self.variables: dict[str, tuple[str, tuple[int, ...]]] = {
            name: (v.dtype, v.shape) for name, v in subsystem.variables.items()}
        # job control writes a variable with an initial value before tasks start, and a job's object
        self.initial = {name for name, v in subsystem.variables.items() if v.initial is not None}
        self.job_written = self.initial | {name for name, v in subsystem.variables.items() if v.object}
        self.members: dict[str, TaskSpec] = {}
        self.instances: dict[tuple[str, frozenset[str]], str] = {}  # (module, variables it writes) -> its task
        self.writers: dict[str, list[tuple[str, str, bool]]] = {}  # variable -> (task, port, supplies init)
        self.const_readers: dict[str, list[tuple[str, str]]] = {}  # variable -> (task, port) reading it before init
        self.device_users: dict[str, str] = {}  # exclusive device -> the task that holds it
        for name in tasks:
            self.add_task(subsystem.tasks[name])

    # --- the index, kept current --------------------------------------------------------------

    def add_task(self, task: TaskSpec) -> None:
        """Index a task that joins the configuration (placed, or there from the start)."""
        self.members[task.name] = task
        instance = _instance(task)
        if instance[1]:
            self.instances.setdefault(instance, task.name)
        for b in task.bindings:
            kind = b.port.kind
            if kind.is_input:
                if kind.needs_initial_value:
                    self.const_readers.setdefault(b.variable, []).append((task.name, b.port.name))
            else:
                self.writers.setdefault(b.variable, []).append((task.name, b.port.name, kind.supplies_initial_value))
            if b.variable not in self.variables:
                self.variables[b.variable] = (b.port.dtype, b.shape)
        for device in task.resources:
            spec = self.subsystem.devices.get(device)
            if spec is not None and spec.exclusive:
                self.device_users.setdefault(device, task.name)

    def remove_task(self, name: str) -> None:
        """Forget a task that leaves the configuration."""
        task = self.members.pop(name)
        instance = _instance(task)
        if self.instances.get(instance) == name:
            del self.instances[instance]
            other = next((t.name for t in self.members.values() if _instance(t) == instance), None)
            if other is not None:
                self.instances[instance] = other
        for variable in {b.variable for b in task.bindings}:
            writers = [w for w in self.writers.get(variable, []) if w[0] != name]
            readers = [r for r in self.const_readers.get(variable, []) if r[0] != name]
            _store(self.writers, variable, writers)
            _store(self.const_readers, variable, readers)
        for device, user in list(self.device_users.items()):
            if user == name:
                del self.device_users[device]
                other = next((t.name for t in self.members.values() if device in t.resources), None)
                if other is not None:
                    self.device_users[device] = other

    # --- modules, resolved once ---------------------------------------------------------------

    def module(self, name: str) -> _Module:
        found = self._modules.get(name)
        if found is None:
            found = self._modules[name] = self._resolve(name)
        return found

    def _resolve(self, name: str) -> _Module:
        try:
            cls = self._lookup(name)
        except Exception as exc:  # a broken library is a reason, not a crash of the canvas
            return _Module(name, (), None, ("E207", f"module '{name}' cannot be loaded: {exc}", "see pbo lexicon"))
        try:
            params = cls.build_params({})
        except Exception:
            params = None  # required parameters: the class's own ports, until the task's modifiers are set
        try:
            specs = tuple(cls.ports_for(params) if params is not None else cls.ports())
        except Exception as exc:
            return _Module(name, (), None, ("E307", f"module '{name}' cannot list its ports: {exc!r}", ""))
        device = getattr(params, "device", None) if params is not None else _default_device(cls)
        dims = self.subsystem.dims
        ports = []
        for p in specs:
            shape: tuple[int, ...] | None = None
            problem = None
            if p.shape is not None:
                try:
                    shape = p.resolved_shape(dict(dims))
                except KeyError as exc:
                    problem = ("E304", f"port '{p.name}' of module '{name}' has shape {_show(p.shape)} with dim {exc}, "
                                       "which 'dims' does not define", "add it under dims:")
                except (TypeError, ValueError) as exc:
                    problem = ("E306", f"port '{p.name}' of module '{name}' has a bad shape {p.shape!r}: {exc}", "")
            kind = p.kind
            ports.append(_Port(p.name, kind, kind.value, p.variable, p.dtype, shape, kind.is_input,
                               kind.needs_initial_value, kind.supplies_initial_value, problem))
        uses = getattr(cls, "DEVICES", None)
        needs = uses.get("device") if isinstance(uses, dict) else None
        return _Module(name, tuple(ports), device if isinstance(device, str) else None,
                       needs=tuple(needs.items()) if isinstance(needs, dict) else ())

    # --- the query ----------------------------------------------------------------------------

    def query(self, name: str) -> Verdict:
        """Whether module `name` can be placed in this configuration, with its default links."""
        module = self.module(name)
        if module.problem is not None:
            return Verdict(name, False, *module.problem)
        where = self.where
        user = self.instances.get((name, frozenset(p.variable for p in module.ports if not p.is_input)))
        if user is not None:
            return Verdict(name, False, "E407", f"module '{name}' runs already {where}, as task '{user}' writing the "
                                                "same variables",
                           f"one set of output ports has one writer: link the outputs of task '{user}' to variables of "
                           "their own (ports:), then place it and join the two with a join connector (TR Figure 6)")
        device = module.device
        if device is not None:
            spec = self.subsystem.devices.get(device)
            if spec is None:
                return Verdict(name, False, "E208", f"module '{name}' opens device '{device}', which 'devices' does not declare",
                               "declare the device, or set the task's device parameter to a declared one")
            holder = self.device_users.get(device)
            if holder is not None:
                return Verdict(name, False, "E601", f"module '{name}' opens device '{device}', which is exclusive, and task "
                                                    f"'{holder}' holds it {where}",
                               "an exclusive device has one user per configuration; remove that task first")
            for option, wanted in module.needs:
                if option == "kind":
                    kind = _driver_kind(spec.driver)
                    if kind is not None and kind != wanted:
                        return Verdict(name, False, "E610", f"module '{name}' needs a device of kind {wanted}, but device "
                                                            f"'{device}' is of kind {kind or 'none'} (driver {spec.driver})",
                                       f"set the task's device parameter to a device of kind {wanted}")
                    continue
                has = spec.options.get(option, _driver_default(spec.driver, option))
                if has is not None and has != wanted:
                    return Verdict(name, False, "E609", f"module '{name}' needs device '{device}' with {option}: {wanted}, "
                                                        f"but the device has {option}: {has}",
                                   f"choose a module for a device with {option}: {has}")
        variables, writers = self.variables, self.writers
        links: dict[str, str] = {}
        new: list[str] = []
        open_inputs: list[str] = []
        for port in module.ports:
            var = port.variable
            links[port.name] = var
            if port.problem is not None:
                return Verdict(name, False, *port.problem, links=links)
            known = variables.get(var)
            if known is None:
                if port.dtype == ANY_DTYPE or port.shape is None:
                    return Verdict(name, False, "E206", f"port '{port.name}' of module '{name}' links by default to variable "
                                                        f"'{var}', which nothing declares and the port cannot define",
                                   f"declare '{var}' under variables:, or link the port to a variable with ports: "
                                   f"{{{port.name}: <variable>}}", links=links)
                new.append(var)
            else:
                dtype, shape = known
                if port.dtype != ANY_DTYPE and port.dtype != dtype:
                    return Verdict(
                        name,
                        False,
                        "E301",
                        f"port '{port.name}' ({port.kind_text}) of module '{name}' is "
                        f"{port.dtype}, but variable '{var}' is {dtype}",
                        f"link the port to a {port.dtype} variable with ports: {{{port.name}: <variable>}}",
                        links=links,
                    )
                if port.shape is not None and port.shape != shape:
                    return Verdict(
                        name,
                        False,
                        "E302",
                        f"port '{port.name}' ({port.kind_text}) of module '{name}' has shape "
                        f"{_show(port.shape)}, but variable '{var}' has shape {_show(shape)}",
                        f"link the port to a variable of shape {_show(port.shape)} with ports: {{{port.name}: <variable>}}",
                        links=links,
                    )
            written = writers.get(var)
            if not port.is_input:
                if written:
                    return Verdict(name, False, "E401", f"variable '{var}' would have two writers {where}: "
                                                        f"'{written[0][0]}' and port '{port.name}' of module '{name}'",
                                   _JOIN_HINT, links=links)
                readers = self.const_readers.get(var)
                if readers and not port.supplies_init and var not in self.initial:
                    reader, reader_port = readers[0]
                    return Verdict(name, False, "E404", f"task '{reader}' reads '{var}' (port '{reader_port}') before its init, "
                                                        f"but port '{port.name}' of module '{name}' would write it as "
                                                        f"{port.kind_text} (only after each cycle)",
                                   f"give variable '{var}' an initial: value, or place a module that writes it out-const",
                                   links=links)
                continue
            if not port.needs_init:
                if not written and var not in self.job_written:
                    open_inputs.append(var)
                continue
            if var in self.initial:
                continue
            if not written:
                if var in self.job_written:
                    return Verdict(name, False, "E405", f"port '{port.name}' of module '{name}' reads {port.kind_text} '{var}' "
                                                        f"before its init, but {where} only job control "
                                                        "sets it, as a job's object, after tasks are spawned",
                                   f"give variable '{var}' an initial: value", links=links)
                return Verdict(name, False, "E403", f"port '{port.name}' of module '{name}' reads {port.kind_text} '{var}', "
                                                    f"but no task {where} writes it",
                               f"place a task that writes '{var}' first, or give it an initial: value", links=links)
            if not any(supplies for _, _, supplies in written):
                writer, writer_port, _ = written[0]
                return Verdict(name, False, "E404", f"port '{port.name}' of module '{name}' reads {port.kind_text} '{var}' "
                                                    f"before its init, but its writer '{writer}' {where} "
                                                    "writes it only after each cycle",
                               f"make port '{writer_port}' write it out-const, or give variable '{var}' an initial: value",
                               links=links)
        return Verdict(name, True, links=links, new_variables=tuple(new), open_inputs=tuple(open_inputs))

    def query_all(self, names: Iterable[str] | None = None) -> list[Verdict]:
        """A verdict for each module (every registered one by default), sorted by name."""
        return [self.query(name) for name in (sorted(names) if names is not None else registry.names(registry.MODULES))]


def placement_report(subsystem: Subsystem, configuration: str | None = None, *, tasks: Sequence[str] | None = None,
                     rtpu: str | None = None, modules: Sequence[str] | None = None) -> dict[str, Any]:
    """Plain data in, a JSON-able dict out: which modules can be placed in a configuration on an RTPU.

    `configuration` names one of the subsystem's (its first by default); `tasks` gives the task
    list instead (a live or edited configuration). ValueError names what is unknown.
    """
    if tasks is None:
        if not subsystem.configurations:
            raise ValueError(f"subsystem '{subsystem.name}' has no configuration")
        configuration = configuration or next(iter(subsystem.configurations))
        if configuration not in subsystem.configurations:
            raise ValueError(f"no configuration '{configuration}' (configurations: {', '.join(subsystem.configurations)})")
        tasks = subsystem.configurations[configuration].tasks
    unknown = [t for t in tasks if t not in subsystem.tasks]
    if unknown:
        raise ValueError(f"no task {', '.join(repr(t) for t in unknown)} in subsystem '{subsystem.name}' "
                         f"(tasks: {', '.join(subsystem.tasks)})")
    rtpus = [r.name for r in subsystem.rtpus]
    rtpu = rtpu or rtpus[0]
    if rtpu not in rtpus:
        raise ValueError(f"no RTPU '{rtpu}' (rtpus: {', '.join(rtpus)})")
    placement = Placement(subsystem, tasks, configuration or "")
    verdicts = placement.query_all(modules)
    return {
        "subsystem": subsystem.name,
        "configuration": configuration,
        "tasks": list(tasks),
        "rtpu": rtpu,
        "legal": sum(v.legal for v in verdicts),
        "modules": [v.as_json() for v in verdicts],
    }


def _instance(task: TaskSpec) -> tuple[str, frozenset[str]]:
    """A module's instance: the module with the variables its output ports write (E407)."""
    return task.module, frozenset(b.variable for b in task.bindings if not b.port.kind.is_input)


def _store(index: dict[str, list[Any]], key: str, entries: list[Any]) -> None:
    if entries:
        index[key] = entries
    else:
        index.pop(key, None)


def _driver_default(driver: str, option: str) -> Any:
    """What a device's option is when its YAML leaves it out (its driver's OPTION_DEFAULTS), or None."""
    try:
        defaults = getattr(registry.driver_class(driver), "OPTION_DEFAULTS", None) or {}
    except Exception:  # an unknown driver: the checker reported it
        return None
    return defaults.get(option)


def _driver_kind(driver: str) -> str | None:
    """The kind of device a driver drives (its KIND), or None for an unknown driver."""
    try:
        return str(getattr(registry.driver_class(driver), "KIND", "") or "")
    except Exception:  # an unknown driver: the checker reported it
        return None


def _default_device(cls: Any) -> str | None:
    """The default of a `device` field of the module's Params, when its params cannot be built whole."""
    params = getattr(cls, "Params", None)
    if params is None or not dataclasses.is_dataclass(params):
        return None
    for f in dataclasses.fields(params):
        if f.name == "device" and isinstance(f.default, str):
            return f.default
    return None


def _show(shape: Sequence[object]) -> str:
    if not shape:
        return "() (a scalar)"
    return "(" + ", ".join(str(d) for d in shape) + ("," if len(shape) == 1 else "") + ")"
