"""The live description of a running subsystem: its file as changed by `pbo spawn/kill/replace/set`.

A run starts from its YAML file. A live change is first made on a copy of the description the
run is living by (the file's document, includes merged, with every change so far), and that copy
goes through the same checker as `pbo check`, every configuration of it: a change that would
break a rule is refused (`LiveChangeRefused`) with the checker's located messages, exactly as
`pbo check` prints them, before anything of the run is touched. Only a description that checks
clean is handed to job control, which applies it at a cycle boundary (`supervisor.job_control`).

Decisions this module makes, and why:

- Where a change's own text is located: each value the operator gives (`--module`, `--param
  kp=300`, `pbo set pid kp 300`) is loaded by the project's own safe loader as a YAML snippet
  named after what gave it, `<pbo spawn logger --param path>:1:1`; a mistake in it is reported
  there, and a mistake a change reveals elsewhere (a reader left without its writer) at the
  file's own line, where the fix goes.
- Status blocks: the table's layout is fixed when the run starts, with `slots` status blocks
  (the file's tasks and some spares, `table.SPARE_TASK_SLOTS`). A task keeps its block for life;
  a new task takes the lowest block no task of the run uses (a killed task's is free again), and
  a spawn past them is refused.
- State variables: the layout is fixed, so a change that would add or reshape a variable is
  refused, with a message that says to add it to the file and restart.
- How RTPUs learn it: `to_wire` is the description an RTPU needs (task specs and configuration
  members, no YAML), written by the supervisor to a file of the run and read back by each RTPU
  with `edit.wire.from_wire`, outside any cycle; nothing of the per-cycle path changes.
- `edits` records each change in order, for `pbo save` (`edit.live_save`).
- An application given with its steps (`pbo app NAME --steps`, the HMI's workspace) is a change
  too: it is put in the description's `applications:` and checked with the whole file, so a step
  that does not interlock, or an object of the wrong type, is refused before any job runs.
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from pbo_runtime.config.checker import ModuleLookup
from pbo_runtime.config.limits import MAX_NAME
from pbo_runtime.config.loader import check_loaded, load_document, with_application
from pbo_runtime.config.model import Location, Subsystem, TaskSpec
from pbo_runtime.config.yaml_nodes import YList, YMap, load_text, plain
from pbo_runtime.errors import ConfigError, PboError, closest_name
from pbo_runtime.objects import registry

# A live task's name: a plain identifier, at most MAX_NAME characters (the checker's bound for every name)
NAME = re.compile(rf"^[A-Za-z_][A-Za-z0-9_]{{0,{MAX_NAME - 1}}}$")
SPAWN_KEYS = ("module", "rtpu", "period", "priority", "critical", "aperiodic", "min_interarrival", "wcet", "resources")


class LiveChangeRefused(PboError):
    """A live change refused before anything was touched: what was asked is wrong, or it breaks a rule."""


@dataclass(frozen=True)
class Edit:
    """One live change as `pbo save` replays it on the original file."""

    kind: str  # spawn, kill, replace, set, application
    task: str  # application: the application's name
    entry: Any = None  # spawn, replace: the new task's entry (plain); set: the parameter's value; application: its steps
    new: str = ""  # replace: the new task's name
    param: str = ""  # set: the parameter
    member: int = 0  # set: the number of the member of a combined task whose parameter it is; 0: the task's own
    configurations: tuple[str, ...] = ()  # spawn: the configurations it joined


@dataclass(frozen=True)
class TaskChange:
    """What a spawn or a replace says of the new task; a value is the operator's YAML text."""

    module: str | None = None
    rtpu: str | None = None
    fields: Mapping[str, str] = dataclasses.field(default_factory=dict)  # period, priority, critical, ...
    params: Mapping[str, str] = dataclasses.field(default_factory=dict)
    ports: Mapping[str, str] = dataclasses.field(default_factory=dict)


@dataclass(frozen=True)
class LiveDescription:
    """The running subsystem's description: its document (never mutated: a change copies what it edits)."""

    file: str
    doc: YMap
    subsystem: Subsystem
    slots: int  # status blocks in the run's table
    edits: tuple[Edit, ...] = ()
    module_lookup: ModuleLookup = registry.module_class

    @classmethod
    def start(cls, subsystem: Subsystem, slots: int, module_lookup: ModuleLookup = registry.module_class) -> LiveDescription:
        """The description of a run that has just started from `subsystem`'s file."""
        doc, errors = load_document(subsystem.file)
        if errors or not isinstance(doc, YMap):
            shown = "; ".join(e.format() for e in errors) or "not a mapping"
            raise LiveChangeRefused(f"{subsystem.file} cannot be read again for live changes ({shown}): "
                                    "was it changed or removed after the run started?")
        return cls(subsystem.file, doc, subsystem, slots, (), module_lookup)

    # --- the changes --------------------------------------------------------------------------

    def spawn(self, name: str, change: TaskChange, configurations: Iterable[str]) -> LiveDescription:
        """A new task, member of `configurations` (the running one, as `pbo spawn` asks)."""
        self._new_name(name, "spawn")
        if not change.module or not change.rtpu:
            raise LiveChangeRefused(f"a spawned task needs --module and --rtpu (pbo spawn {name} --module M --rtpu R)")
        entry = _entry(YMap(Location(f"<pbo spawn {name}>", 1, 1)), change, f"pbo spawn {name}")
        doc = self.doc.shallow_copy()
        tasks = doc["tasks"].shallow_copy()
        tasks.put(name, entry, entry.loc, entry.loc)
        doc.put("tasks", tasks, self.doc.key_loc("tasks"), self.doc.value_loc("tasks"))
        joined = tuple(configurations)
        configs = doc["configurations"].shallow_copy()
        for configuration in joined:
            members = _copy_list(configs[configuration])
            members.add(name, entry.loc)
            configs.put(configuration, members, configs.key_loc(configuration), configs.value_loc(configuration))
        doc.put("configurations", configs, self.doc.key_loc("configurations"), self.doc.value_loc("configurations"))
        return self._checked(doc, f"spawning task '{name}'", Edit("spawn", name, plain(entry), configurations=joined))

    def kill(self, name: str) -> LiveDescription:
        """The task gone from the description and from every configuration that has it."""
        self._task(name)
        doc = self.doc.shallow_copy()
        tasks = doc["tasks"].shallow_copy()
        _remove(tasks, name)
        doc.put("tasks", tasks, self.doc.key_loc("tasks"), self.doc.value_loc("tasks"))
        configs = doc["configurations"].shallow_copy()
        for configuration, members in list(configs.items()):
            if isinstance(members, YList) and name in members:
                configs.put(configuration, _copy_list(members, without=name), configs.key_loc(configuration),
                            configs.value_loc(configuration))
        doc.put("configurations", configs, self.doc.key_loc("configurations"), self.doc.value_loc("configurations"))
        return self._checked(doc, f"killing task '{name}'", Edit("kill", name))

    def replace(self, old: str, new: str, change: TaskChange) -> LiveDescription:
        """`new` takes `old`'s place: its entry (`old`'s, with what `change` says) where `old`'s was, in
        every configuration that has `old`, in one switch."""
        self._task(old)
        self._new_name(new, "replace")
        original = self.doc["tasks"][old]
        base = original.shallow_copy() if isinstance(original, YMap) else YMap(Location(f"<pbo replace {old} {new}>", 1, 1))
        entry = _entry(base, change, f"pbo replace {old} {new}")
        doc = self.doc.shallow_copy()
        tasks_before = doc["tasks"]
        tasks = YMap(tasks_before.loc)
        for key, value in tasks_before.items():  # the new entry where the old one was: the file's order kept
            if key == old:
                tasks.put(new, entry, tasks_before.key_loc(old), tasks_before.value_loc(old))
            else:
                tasks.put(key, value, tasks_before.key_loc(key), tasks_before.value_loc(key))
        doc.put("tasks", tasks, self.doc.key_loc("tasks"), self.doc.value_loc("tasks"))
        configs = doc["configurations"].shallow_copy()
        for configuration, members in list(configs.items()):
            if isinstance(members, YList) and old in members:
                configs.put(configuration, _copy_list(members, swap=(old, new)), configs.key_loc(configuration),
                            configs.value_loc(configuration))
        doc.put("configurations", configs, self.doc.key_loc("configurations"), self.doc.value_loc("configurations"))
        return self._checked(doc, f"replacing task '{old}' by '{new}'", Edit("replace", old, plain(entry), new=new))

    def set_param(self, task: str, param: str, texts: list[str]) -> LiveDescription:
        """A live-tunable parameter of a task set to the value the operator wrote (one value, or a list).
        In a combined task, a member's: `kp` when one member has it, else `N.kp` or `MODULE.kp`."""
        spec = self._task(task)
        module_class = self.module_lookup(spec.module)
        owner, reader, member = f"module '{spec.module}' of task '{task}'", f"module '{spec.module}'", 0
        members = _members(module_class, spec)
        if members:
            member, param = _member_param(task, members, param, _fields(module_class.Params))
            if member:
                module_class = members[member - 1].cls
                reader = f"module '{members[member - 1].name.split(':', 1)[1]}' of member {member}"
                owner = f"{reader} of task '{task}'"
        fields = _fields(module_class.Params)
        tunable = tuple(getattr(module_class, "TUNABLE", ()))
        if param not in fields:
            close = closest_name(param, fields)
            raise LiveChangeRefused(f"{owner} has no parameter '{param}'"
                                    + (f": did you mean '{close}'?" if close else "") + " "
                                    f"(parameters: {', '.join(fields) or 'none'}; live-tunable: {', '.join(tunable) or 'none'})")
        address = f"{member}.{param}" if member else param
        if param not in tunable:
            raise LiveChangeRefused(
                f"parameter '{address}' of task '{task}' is not live-tunable: {reader} reads it in init only "
                f"(live-tunable: {', '.join(tunable) or 'none'}); to change it, replace the task: pbo replace {task} NEW --param "
                + (f"{param}=..." if not member else "members=[...]"))
        if not texts:
            raise LiveChangeRefused(f"pbo set {task} {address} needs a value")
        where = f"pbo set {task} {address}"
        if len(texts) == 1:
            value, _ = _snippet(texts[0], where)
        else:
            value = YList(Location(f"<{where}>", 1, 1))
            for position, text in enumerate(texts, 1):
                item, loc = _snippet(text, f"{where} (value {position})")
                value.add(item, loc)
        here = Location(f"<{where}>", 1, 1)
        doc = self.doc.shallow_copy()
        tasks = doc["tasks"].shallow_copy()
        entry = tasks[task].shallow_copy()
        params = entry["params"].shallow_copy() if isinstance(entry.get("params"), YMap) else YMap(here)
        if member:
            params.put("members", _with_member_param(params["members"], member - 1, param, value, here),
                       params.key_loc("members"), params.value_loc("members"))
        else:
            params.put(param, value, here, here)
        entry.put("params", params, tasks[task].key_loc("params") if "params" in tasks[task] else params.loc,
                  tasks[task].value_loc("params") if "params" in tasks[task] else params.loc)
        tasks.put(task, entry, self.doc["tasks"].key_loc(task), self.doc["tasks"].value_loc(task))
        doc.put("tasks", tasks, self.doc.key_loc("tasks"), self.doc.value_loc("tasks"))
        return self._checked(doc, f"setting '{address}' of task '{task}'",
                             Edit("set", task, plain(value), param=param, member=member))

    def with_application(self, name: str, steps: str | list[Any]) -> LiveDescription:
        """The description with application `name` (replaced if it has one) of `steps`: a list as a file
        writes it, or that list as one line of YAML text (`pbo app NAME --steps "[reach: ready, hold]"`)."""
        if not NAME.match(name):
            raise LiveChangeRefused(f"an application's name is a letter or '_' then letters, digits or '_', at most "
                                    f"{MAX_NAME} characters, got: {name!r}")
        # JSON is YAML on one line: the safe loader reads either, each step located in it
        node, loc = _snippet(steps if isinstance(steps, str) else json.dumps(steps), f"pbo app {name} --steps")
        if not isinstance(node, YList) or not node:
            raise LiveChangeRefused(f"application '{name}': its steps are a non-empty list, e.g. [reach: ready, hold], "
                                    f"got: {plain(node)!r}")
        return self._checked(with_application(self.doc, name, node, loc), f"application '{name}'",
                             Edit("application", name, plain(node)))

    # --- checking -----------------------------------------------------------------------------

    def _task(self, name: str) -> TaskSpec:
        if name not in self.subsystem.tasks:
            raise LiveChangeRefused(f"no task '{name}' in the live subsystem (tasks: {', '.join(self.subsystem.tasks)})")
        if name not in self.doc.get("tasks", {}):
            raise LiveChangeRefused(f"task '{name}' is declared in an included file: change it there, and restart")
        return self.subsystem.tasks[name]

    def _new_name(self, name: str, verb: str) -> None:
        if not NAME.match(name):
            raise LiveChangeRefused(f"a task's name is a letter or '_' then letters, digits or '_', at most {MAX_NAME} "
                                    f"characters, got: {name!r}")
        if name in self.subsystem.tasks:
            raise LiveChangeRefused(f"task '{name}' exists already (module '{self.subsystem.tasks[name].module}' on "
                                    f"{self.subsystem.tasks[name].rtpu}): choose another name, or kill it first")

    def _checked(self, doc: YMap, what: str, edit: Edit) -> LiveDescription:
        """The description with `doc`, if the checker finds no error in it; else the refusal, located."""
        result = check_loaded(doc, self.file, self.module_lookup)
        errors, subsystem = result.errors, result.subsystem
        if errors or subsystem is None:
            if any(error.code == "E206" for error in errors):  # a variable no file declares: the layout cannot grow
                what += " (a live change cannot add a state variable: add it to the file's variables: and restart)"
            raise LiveChangeRefused(refusal(what, errors))
        self._same_variables(subsystem, what)
        subsystem = self._reindexed(subsystem, what)
        return dataclasses.replace(self, doc=doc, subsystem=subsystem, edits=(*self.edits, edit))

    def _same_variables(self, subsystem: Subsystem, what: str) -> None:
        live = self.subsystem.variables
        for name, variable in subsystem.variables.items():
            known = live.get(name)
            if known is None or (known.dtype, known.shape) != (variable.dtype, variable.shape):
                change = "add state variable" if known is None else "change the type or shape of state variable"
                raise LiveChangeRefused(
                    f"{what} would {change} '{name}': the state variable table's layout is fixed when the run starts; "
                    f"add '{name}' to the file's variables: and restart the run")

    def _reindexed(self, subsystem: Subsystem, what: str) -> Subsystem:
        """Each task's status block: the one it has; a new task, the lowest no task of the run uses."""
        used = {task.index for task in self.subsystem.tasks.values()}  # a leaving task keeps its block until it is killed
        free = iter(index for index in range(self.slots) if index not in used)
        tasks: dict[str, TaskSpec] = {}
        for name, spec in subsystem.tasks.items():
            if name in self.subsystem.tasks:
                index = self.subsystem.tasks[name].index
            else:
                index = next(free, -1)
                if index < 0:
                    raise LiveChangeRefused(
                        f"{what} needs a status block in the table, but all {self.slots} are in use (the file's tasks and "
                        f"the spares reserved at start): kill a task first, or add the task to the file and restart")
            tasks[name] = dataclasses.replace(spec, index=index)
        return dataclasses.replace(subsystem, tasks=tasks)


def refusal(what: str, errors: list[ConfigError]) -> str:
    """The refusal's text: the checker's messages as `pbo check` prints them, then its count line."""
    count = f"{len(errors)} error" + ("" if len(errors) == 1 else "s")
    return f"{what} would break the live configuration:\n" + "\n".join(e.format() for e in errors) + f"\n{count}, 0 warnings"


# --- building the new YAML nodes ------------------------------------------------------------------


def _snippet(text: str, where: str) -> tuple[Any, Location]:
    """One value the operator wrote, loaded by the safe loader as YAML, located at `<where>`."""
    if not isinstance(text, str) or "\n" in text or "\r" in text:
        raise LiveChangeRefused(f"{where}: a value is one line of YAML, got: {text!r}")
    file = f"<{where}>"
    try:
        loaded = load_text(f"value: {text}\n", file)
    except ConfigError as exc:
        raise LiveChangeRefused(f"{where}: not a YAML value: {text!r} ({exc})") from None
    if not isinstance(loaded, YMap) or set(loaded) != {"value"}:
        raise LiveChangeRefused(f"{where}: not one YAML value: {text!r}")
    return loaded["value"], Location(file, 1, 1)


def _entry(base: YMap, change: TaskChange, where: str) -> YMap:
    """`base` (a task's entry) with what `change` says put in it; each value located where it came from."""
    entry = base
    for key, text in (("module", change.module), ("rtpu", change.rtpu), *change.fields.items()):
        if text is None:
            continue
        if key not in SPAWN_KEYS:
            raise LiveChangeRefused(f"{where}: '{key}' cannot be given here (given: {', '.join(SPAWN_KEYS)}, --param, --port)")
        value, loc = _snippet(str(text), f"{where} --{key}")
        entry.put(key, value, loc, loc)
    for section, given in (("params", change.params), ("ports", change.ports)):
        if not given:
            continue
        existing = entry.get(section)
        mapping = existing.shallow_copy() if isinstance(existing, YMap) else YMap(Location(f"<{where} --{section[:-1]}>", 1, 1))
        for key, text in given.items():
            value, loc = _snippet(text, f"{where} --{section[:-1]} {key}")
            mapping.put(key, value, loc, loc)
        entry.put(section, mapping, mapping.loc, mapping.loc)
    return entry



def _remove(node: YMap, key: str) -> None:
    del node[key]


def _fields(params_type: Any) -> list[str]:
    return [f.name for f in dataclasses.fields(params_type)] if dataclasses.is_dataclass(params_type) else []


def _members(module_class: Any, spec: TaskSpec) -> tuple[Any, ...]:
    """The members of a combined task (each with its name 'N:module', class and params), else ()."""
    if "members" not in _fields(module_class.Params):
        return ()
    try:
        return tuple(getattr(module_class.build_params(dict(spec.params)), "built", ()))
    except Exception:  # the live description checked clean: its members build
        return ()


def _member_param(task: str, members: tuple[Any, ...], address: str, own: list[str]) -> tuple[int, str]:
    """(member number, parameter) that `address` names in a combined task: `N.param`, `module.param`, or
    `param` alone when one member has it (the one member with it live-tunable, when several have it);
    (0, address) for the task's own parameters."""
    listed = ", ".join(f"{m.name.split(':', 1)[0]} ({m.name.split(':', 1)[1]})" for m in members)
    prefix, dot, param = address.rpartition(".")
    if dot:
        named = [n for n, m in enumerate(members, 1) if prefix in (str(n), m.name, m.name.split(":", 1)[1])]
        if len(named) == 1:
            return named[0], param
        if not named:
            raise LiveChangeRefused(f"task '{task}' has no member '{prefix}' (members: {listed}): name one by its number "
                                    f"or its module: pbo set {task} 1.{param or 'PARAM'} VALUE")
        raise LiveChangeRefused(f"members {' and '.join(map(str, named))} of task '{task}' are both module '{prefix}': "
                                f"name one by its number: {' or '.join(f'{n}.{param}' for n in named)}")
    if address in own:
        return 0, address
    having = [n for n, m in enumerate(members, 1) if address in _fields(m.cls.Params)]
    tunable = [n for n in having if address in getattr(members[n - 1].cls, "TUNABLE", ())]
    if len(having) == 1 or len(tunable) == 1:
        return (having if len(having) == 1 else tunable)[0], address
    if not having:
        offered = [f"{n}.{name}" for n, m in enumerate(members, 1) for name in getattr(m.cls, "TUNABLE", ())]
        raise LiveChangeRefused(f"no member of combined task '{task}' has a parameter '{address}' (members: {listed}; "
                                f"live-tunable: {', '.join(offered) or 'none'})")
    raise LiveChangeRefused(f"members {' and '.join(map(str, having))} of task '{task}' both have a parameter '{address}': "
                            f"name one by its number: {' or '.join(f'{n}.{address}' for n in having)}")


def _with_member_param(members: Any, index: int, param: str, value: Any, here: Location) -> YList:
    """A copy of a combined task's `members:` list with `param` of member `index` set to `value`."""
    copy = YList(members.loc)
    for position, item in enumerate(members):
        if position == index:
            item = item.shallow_copy()
            params = item["params"].shallow_copy() if isinstance(item.get("params"), YMap) else YMap(here)
            params.put(param, value, here, here)
            item.put("params", params, item.key_loc("params") if "params" in item else here,
                     item.value_loc("params") if "params" in item else here)
        copy.add(item, members.item_loc(position))
    return copy


def _copy_list(node: YList, without: str | None = None, swap: tuple[str, str] | None = None) -> YList:
    copy = YList(node.loc)
    for index, item in enumerate(node):
        if item == without:
            continue
        copy.add(swap[1] if swap is not None and item == swap[0] else item, node.item_loc(index))
    return copy


def parse_assignments(texts: Iterable[str] | None, what: str) -> dict[str, str]:
    """`k=v` arguments (`--param kp=300`, `--port tau=tau_u`) as {k: v}; v stays YAML text."""
    result: dict[str, str] = {}
    for text in texts or ():
        key, equals, value = str(text).partition("=")
        if not equals or not key.strip():
            raise LiveChangeRefused(f"{what} is given as NAME=VALUE, got: {text!r}")
        result[key.strip()] = value.strip()
    return result


# --- what an RTPU needs of it -----------------------------------------------------------------------


def to_wire(subsystem: Subsystem) -> dict[str, Any]:
    """The tasks and configurations of a live subsystem as plain data (JSON), for its RTPUs."""
    return {
        "configurations": {name: list(c.tasks) for name, c in subsystem.configurations.items()},
        "init_order": list(subsystem.init_order),
        "tasks": {name: {"module": t.module, "rtpu": t.rtpu, "period": t.period, "priority": t.priority,
                         "critical": t.critical, "params": plain(dict(t.params)),
                         "bindings": [[b.port.name, b.variable, list(b.shape)] for b in t.bindings],
                         "writes": [b.variable for b in t.bindings if not b.port.kind.is_input and b.port.kind.every_cycle],
                         "resources": list(t.resources), "index": t.index, "wcet": t.wcet, "aperiodic": t.aperiodic,
                         "min_interarrival": t.min_interarrival,
                         "resource_channels": {d: list(c) for d, c in t.resource_channels.items()},
                         "fresh_within": dict(t.fresh_within)}
                  for name, t in subsystem.tasks.items()},
    }
