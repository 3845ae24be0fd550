"""The job canvas (Onika §4.3) checked like a file: the canvas's tasks composed onto a subsystem file's base.

The engineer's canvas holds tasks not yet written anywhere. To check them the way `pbo check`
checks a file, they are composed onto the file's *base* (everything but its `tasks:`,
`configurations:`, `jobs:` and `applications:`: rtpus, plant, devices, dims, variables, object
types, objects, includes merged) as the file's only tasks, and the tasks that are on as its one
configuration. The composed document goes through the project's checker (`loader.check_loaded`).

Where each diagnostic came from: every value of a canvas task is loaded by the project's own safe
loader as a YAML snippet of its own, named after its origin: `<canvas pid>` for the task itself
(and its place in the configuration), `<canvas pid params.kp>` for a modifier value,
`<canvas pid ports.tau>` for a port's link, `<canvas pid period>` for a field. A diagnostic
located in such a snippet belongs to that task (`origin_of`); its pin is the port the snippet
links, or else the task's port that the message names, or whose variable it names (`pin_of`).
A diagnostic located anywhere else is the base file's own, at its line.

Placement (which lexicon modules could still be dropped, and why not the rest) needs a checked
subsystem. When the canvas has errors, the tasks whose own entries are sound are checked again in
no configuration (a configuration's rules, such as one writer per variable, then hold vacuously)
and the placement query (`analysis.placement`) indexes them as the canvas's configuration.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from pbo_runtime.analysis.placement import placement_report
from pbo_runtime.config.checker import ModuleLookup
from pbo_runtime.config.loader import CheckResult, check_loaded, load_document
from pbo_runtime.config.model import Location, Subsystem
from pbo_runtime.config.yaml_nodes import YList, YMap, load_text, plain
from pbo_runtime.edit.live import NAME
from pbo_runtime.errors import ConfigError, Note
from pbo_runtime.objects import registry

CANVAS_CONFIGURATION = "canvas"  # the configuration's name when the canvas did not start from one of the file's
BASE_EXCLUDED = ("tasks", "configurations", "jobs", "applications")  # what the canvas stands in for
MAX_TASKS = 64  # a canvas is a configuration, not a data set
MAX_VALUE = 2000  # characters of one value's YAML text
_CANVAS_FILE = re.compile(r"^<canvas ([A-Za-z_][A-Za-z0-9_]*)(?: ([a-z_]+)(?:\.(.+))?)?>$")
_QUOTED = re.compile(r"'([^']+)'")
_PORT_NAMED = re.compile(r"port '([^']+)'")
_RETRY_ROUNDS = 3  # rounds of dropping broken tasks to find a subsystem the placement query can index


class CanvasError(ValueError):
    """The canvas sent is malformed (not the checker's business: a name, a value of the wrong kind)."""


@dataclass(frozen=True)
class CanvasTask:
    """A task on the canvas: values are YAML text, as the engineer types them (and `pbo spawn --param` takes them)."""

    name: str
    module: str
    fields: Mapping[str, str] = field(default_factory=dict)  # rtpu, period, resources, ...: key -> YAML text
    params: Mapping[str, str] = field(default_factory=dict)  # modifier -> YAML text ("" or absent: the default)
    ports: Mapping[str, str] = field(default_factory=dict)  # port -> the variable it links (absent: its own default)
    on: bool = True  # off: kept on the canvas, left out of the configuration


def tasks_from_json(data: Any) -> list[CanvasTask]:
    """The canvas's tasks from a request's JSON list; CanvasError saying what is wrong and where."""
    if not isinstance(data, list):
        raise CanvasError(f"tasks must be a list of tasks, got: {type(data).__name__}")
    if len(data) > MAX_TASKS:
        raise CanvasError(f"a canvas holds at most {MAX_TASKS} tasks, got {len(data)}")
    tasks: list[CanvasTask] = []
    seen: set[str] = set()
    for number, item in enumerate(data, 1):
        if not isinstance(item, dict):
            raise CanvasError(f"task {number} must be an object with name and module, got: {type(item).__name__}")
        name, module = item.get("name"), item.get("module")
        if not isinstance(name, str) or not NAME.match(name):
            raise CanvasError(f"task {number}: its name must be an identifier of at most 40 characters, got: {name!r}")
        if name in seen:
            raise CanvasError(f"two tasks on the canvas are named '{name}': rename one")
        seen.add(name)
        if not isinstance(module, str) or not NAME.match(module):
            raise CanvasError(f"task '{name}': its module must be a module's name (pbo lexicon lists them), got: {module!r}")
        sections = {key: _texts(item.get(key), f"{key} of task '{name}'") for key in ("fields", "params", "ports")}
        bad = [key for key in sections["fields"] if key in ("module", "params", "ports")]
        if bad:
            raise CanvasError(f"task '{name}': '{bad[0]}' is not one of its fields (given apart)")
        tasks.append(CanvasTask(name, module, sections["fields"], sections["params"], sections["ports"],
                                bool(item.get("on", True))))
    return tasks


def _texts(value: Any, what: str) -> dict[str, str]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise CanvasError(f"{what} must be an object of names to YAML text, got: {type(value).__name__}")
    out: dict[str, str] = {}
    for key, text in value.items():
        if not isinstance(key, str) or not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", key):
            raise CanvasError(f"{what}: {key!r} is not a name")
        if not isinstance(text, str):
            raise CanvasError(f"{what}: the value of '{key}' must be YAML text, got: {type(text).__name__}")
        if "\n" in text or "\r" in text or len(text) > MAX_VALUE:
            raise CanvasError(f"{what}: the value of '{key}' must be one line of YAML of at most {MAX_VALUE} characters")
        out[key] = text
    return out


# --- where a diagnostic came from -----------------------------------------------------------------


def origin_file(task: str, section: str | None = None, key: str | None = None) -> str:
    """The name of the snippet a canvas task's value is loaded as: `<canvas pid>`, `<canvas pid params.kp>`."""
    if section is None:
        return f"<canvas {task}>"
    return f"<canvas {task} {section}{'.' + key if key else ''}>"


@dataclass(frozen=True)
class Origin:
    task: str
    section: str | None = None  # params, ports, or a field's name (rtpu, period, ...); None: the task itself
    key: str | None = None  # the modifier or port, in params and ports


def origin_of(file: str) -> Origin | None:
    """The canvas task (and its field) a diagnostic's file names; None for the base file's own."""
    match = _CANVAS_FILE.match(file)
    if match is None:
        return None
    return Origin(match.group(1), match.group(2), match.group(3))


@dataclass(frozen=True)
class Pin:
    """A task's port as the canvas draws it: which side, and the variable it joins."""

    port: str
    kind: str  # in-var, out-const, ...
    variable: str
    dtype: str
    shape: str

    def as_json(self) -> dict[str, Any]:
        return {"port": self.port, "kind": self.kind, "variable": self.variable, "dtype": self.dtype, "shape": self.shape}


def pin_of(origin: Origin, message: str, pins: Sequence[Pin]) -> str | None:
    """The port a diagnostic of the task is about: the port its snippet links, the one it names, or the
    one linked to a variable it names (the first such in the message); None when it is about none."""
    by_port = {p.port: p for p in pins}
    if origin.section == "ports":
        return origin.key
    if origin.section is not None:
        return None  # a modifier's or a field's value: the block's, not a pin's
    name: str
    for name in _PORT_NAMED.findall(message):
        if name in by_port:
            return name
    by_variable: dict[str, str] = {}
    for p in pins:
        by_variable.setdefault(p.variable, p.port)
    for name in _QUOTED.findall(message):
        if name in by_variable and name != origin.task:
            return by_variable[name]
    return None


def note_on_canvas(note: Note) -> dict[str, Any]:
    """A related place of a diagnostic: the canvas task it is in, or the base file's line."""
    origin = origin_of(note.file)
    if origin is not None:
        return {"message": note.message, "task": origin.task, "file": None, "line": None}
    return {"message": note.message, "task": None, "file": note.file, "line": note.line}


def diagnostic(error: ConfigError, pins: Mapping[str, Sequence[Pin]],
               params: Mapping[str, Sequence[str]] | None = None, names: Sequence[str] = ()) -> dict[str, Any]:
    """A diagnostic as the canvas shows it: E-code, message, hint, and the task, modifier and pin it belongs to.

    A module's own check of its params is located at the task's `params:` as a whole; the modifier it
    is about is the one of the task's (`params`: task -> its modifiers) that the message names."""
    origin = origin_of(error.file)
    about = error.message
    if origin is None:  # the canvas's own configuration list (E408): shown at the first task its notes name
        noted = next(((o, n.message) for n in error.notes if (o := origin_of(n.file)) is not None), None)
        if noted is not None:
            origin, about = noted
    if origin is not None and origin.section == "params" and origin.key is None:
        named = [key for key in (params or {}).get(origin.task, ()) if re.search(rf"\b{re.escape(key)}\b", error.message)]
        if named:
            origin = Origin(origin.task, "params", named[0])
    out: dict[str, Any] = {"code": error.code, "severity": error.severity, "message": error.message, "hint": error.hint,
                           "task": None, "section": None, "key": None, "port": None,
                           "notes": [note_on_canvas(note) for note in error.notes]}
    if origin is None:
        out.update(file=error.file, line=error.line, column=error.column)
        return out
    if names:  # "'pid' (line 1)": a canvas task has no line of a file to point to
        out["message"] = re.sub(rf"'({'|'.join(map(re.escape, names))})' \(line \d+\)", r"'\1'", error.message)
    out.update(task=origin.task, section=origin.section, key=origin.key,
               port=pin_of(origin, about, pins.get(origin.task, ())), file=None, line=None, column=None)
    return out


# --- composing the canvas onto the file's base ----------------------------------------------------


def base_document(file: str) -> tuple[YMap | None, list[ConfigError]]:
    """The file's document, includes merged, without what the canvas stands in for."""
    doc, errors = load_document(file)
    if not isinstance(doc, YMap):
        if doc is not None:
            errors.append(ConfigError("the file must be a mapping of sections (subsystem, rtpus, variables, ...)", file, 1, 1))
        return None, errors
    base = YMap(doc.loc)
    for key, value in doc.items():
        if key not in BASE_EXCLUDED:
            base.put(key, value, doc.key_loc(key), doc.value_loc(key))
    return base, errors


def _value(text: str, file: str, errors: list[ConfigError]) -> tuple[bool, Any, Location]:
    """One value's YAML text loaded as its own snippet named `file`; (False, ...) when it is empty or broken."""
    loc = Location(file, 1, 1)
    if not text.strip():
        return False, None, loc
    try:
        loaded = load_text(f"value: {text}\n", file)
    except ConfigError as exc:
        errors.append(exc)
        return False, None, loc
    if not isinstance(loaded, YMap) or set(loaded) != {"value"}:
        errors.append(ConfigError(f"invalid YAML: not one value: {text!r}", file, 1, 1, code="E101",
                                  hint="write one value: 400, [1, 2], \"text\""))
        return False, None, loc
    return True, loaded["value"], loaded.value_loc("value")


def task_entry(task: CanvasTask, errors: list[ConfigError]) -> YMap:
    """The task's YAML entry as the checker reads a file's, each value located in its own snippet."""
    here = Location(origin_file(task.name), 1, 1)
    entry = YMap(here)
    module_loc = Location(origin_file(task.name, "module"), 1, 1)
    entry.put("module", task.module, module_loc, module_loc)
    for key, text in task.fields.items():
        ok, value, loc = _value(text, origin_file(task.name, key), errors)
        if ok:
            entry.put(key, value, Location(origin_file(task.name, key), 1, 1), loc)
    for section, given in (("params", task.params), ("ports", task.ports)):
        mapping = YMap(Location(origin_file(task.name, section), 1, 1))
        for key, text in given.items():
            file = origin_file(task.name, section, key)
            if section == "ports":
                if text.strip():
                    mapping.put(key, text.strip(), Location(file, 1, 1), Location(file, 1, 1))
                continue
            ok, value, loc = _value(text, file, errors)
            if ok:
                mapping.put(key, value, Location(file, 1, 1), loc)
        if mapping:
            entry.put(section, mapping, mapping.loc, mapping.loc)
    return entry


def compose(base: YMap, tasks: Sequence[CanvasTask], configuration: str | None,
            errors: list[ConfigError]) -> YMap:
    """The base with the canvas's tasks as its tasks and those on as `configuration` (None: no configuration)."""
    doc = YMap(base.loc)
    for key, value in base.items():
        doc.put(key, value, base.key_loc(key), base.value_loc(key))
    here = Location("<canvas>", 1, 1)
    entries = YMap(here)
    for task in tasks:
        entry = task_entry(task, errors)
        entries.put(task.name, entry, entry.loc, entry.loc)
    doc.put("tasks", entries, here, here)
    configurations = YMap(here)
    if configuration is not None:
        members = YList(here)
        for task in tasks:
            if task.on:
                members.add(task.name, Location(origin_file(task.name), 1, 1))
        configurations.put(configuration, members, here, here)
    doc.put("configurations", configurations, here, here)
    return doc


# --- the check ------------------------------------------------------------------------------------


def task_pins(subsystem: Subsystem | None, tasks: Sequence[CanvasTask],
              module_lookup: ModuleLookup = registry.module_class) -> dict[str, list[Pin]]:
    """Each task's pins: its bindings in the checked subsystem, or its module's declared ports as linked."""
    pins: dict[str, list[Pin]] = {}
    for task in tasks:
        spec = subsystem.tasks.get(task.name) if subsystem is not None else None
        if spec is not None:
            pins[task.name] = [Pin(b.port.name, b.port.kind.value, b.variable, b.port.dtype, _shape(b.shape))
                               for b in spec.bindings]
            continue
        try:
            declared = module_lookup(task.module).ports()
        except Exception:  # an unknown module is the checker's error (E207), shown on the block
            declared = []
        pins[task.name] = [Pin(p.name, p.kind.value, task.ports.get(p.name, "").strip() or p.variable, p.dtype,
                               "as variable" if p.shape is None else _shape(p.shape)) for p in declared]
    return pins


def _shape(shape: Sequence[Any]) -> str:
    return "[" + ", ".join(str(d) for d in shape) + "]"


def check_canvas(file: str, tasks: Sequence[CanvasTask], configuration: str = CANVAS_CONFIGURATION,
                 module_lookup: ModuleLookup = registry.module_class) -> dict[str, Any]:
    """The checker's verdict on the canvas composed onto `file`'s base, with each diagnostic's task and pin,
    each task's pins, and which lexicon modules could be placed next (JSON-able)."""
    base, load_errors = base_document(file)
    if base is None:
        diagnostics = [diagnostic(e, {}) for e in load_errors]
        return {"valid": False, "configuration": configuration, "diagnostics": diagnostics, "pins": {},
                "job_written": [], "placement": {"error": _first(load_errors, file)}}
    value_errors: list[ConfigError] = []
    result = check_loaded(compose(base, tasks, configuration, value_errors), file, module_lookup)
    errors = [*load_errors, *value_errors, *result.errors]
    subsystem = result.subsystem if not errors else None
    placed = subsystem if subsystem is not None else _placeable(base, tasks, errors, module_lookup)
    pins = task_pins(subsystem or placed, tasks, module_lookup)
    modifiers = {t.name: list(t.params) for t in tasks}
    diagnostics = [diagnostic(e, pins, modifiers, list(modifiers)) for e in [*errors, *result.warnings]]
    placement: dict[str, Any]
    if placed is None:
        placement = {"error": f"the file's base has errors: nothing can be placed until they are fixed "
                              f"({_first([e for e in errors if origin_of(e.file) is None], file)})"}
    else:
        members = [t.name for t in tasks if t.on and t.name in placed.tasks]
        placement = placement_report(placed, None, tasks=members)
    source = subsystem or placed
    job_written = sorted(name for name, v in source.variables.items() if v.initial is not None or v.object) if source else []
    return {"valid": not errors, "configuration": configuration, "diagnostics": diagnostics,
            "pins": {name: [p.as_json() for p in found] for name, found in pins.items()},
            "job_written": job_written, "placement": placement}


def _placeable(base: YMap, tasks: Sequence[CanvasTask], errors: Sequence[ConfigError],
               module_lookup: ModuleLookup) -> Subsystem | None:
    """A subsystem of the base and the tasks whose own entries check clean, in no configuration; None if the base is broken."""
    broken = {o.task for e in errors if (o := origin_of(e.file)) is not None and o.section is not None}
    for _ in range(_RETRY_ROUNDS):
        kept = [t for t in tasks if t.name not in broken]
        result: CheckResult = check_loaded(compose(base, kept, None, []), base.loc.file, module_lookup)
        if result.subsystem is not None:
            return result.subsystem
        more = {o.task for e in result.errors if (o := origin_of(e.file)) is not None}
        if not more or any(origin_of(e.file) is None for e in result.errors):
            return None
        broken |= more
    return None


def _first(errors: Sequence[ConfigError], file: str) -> str:
    return errors[0].format().splitlines()[0] if errors else f"{file} cannot be read"


# --- the file's own tasks, as the canvas holds them -------------------------------------------------


def yaml_text(value: Any) -> str:
    """A plain value as one line of YAML text that loads back to it (what the modifier panel shows)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        if math.isnan(value):
            return ".nan"
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        try:
            loaded = load_text(f"value: {value}\n", "<text>") if value and "\n" not in value else None
        except ConfigError:
            loaded = None
        return value if isinstance(loaded, dict) and loaded.get("value") == value else json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(yaml_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {yaml_text(v)}" for k, v in value.items()) + "}"
    return json.dumps(str(value))


def canvas_task_json(name: str, entry: Any) -> dict[str, Any]:
    """A file's task entry as the canvas holds it (values as YAML text)."""
    entry = plain(entry) if isinstance(entry, dict) else {}
    params = entry.get("params") if isinstance(entry.get("params"), dict) else {}
    ports = entry.get("ports") if isinstance(entry.get("ports"), dict) else {}
    return {"name": name, "module": str(entry.get("module", "")),
            "fields": {k: yaml_text(v) for k, v in entry.items() if k not in ("module", "params", "ports")},
            "params": {str(k): yaml_text(v) for k, v in params.items()},
            "ports": {str(k): str(v) for k, v in ports.items()}, "on": True}


def file_canvas(file: str) -> dict[str, Any]:
    """What a canvas may start from: the file's RTPUs, devices, configurations and their tasks (JSON-able)."""
    doc, errors = load_document(file)
    if not isinstance(doc, YMap):
        raise CanvasError(f"cannot read {file}: {_first(errors, file)}")
    tasks: dict[Any, Any] = _section(doc, "tasks", dict)
    configurations: dict[Any, Any] = _section(doc, "configurations", dict)
    rtpus: list[Any] = _section(doc, "rtpus", list)
    devices: dict[Any, Any] = _section(doc, "devices", dict)
    return {"file": file, "subsystem": str(doc.get("subsystem", "")), "rtpus": [str(r) for r in rtpus],
            "devices": [str(d) for d in devices],
            "configurations": {str(name): [str(t) for t in members] for name, members in configurations.items()
                               if isinstance(members, list)},
            "tasks": {str(name): canvas_task_json(str(name), entry) for name, entry in tasks.items()},
            "jobs": [str(j) for j in _section(doc, "jobs", dict)]}


def _section(doc: YMap, key: str, kind: type) -> Any:
    """The document's section `key` when it is of `kind`, else an empty one (the checker reports what is wrong)."""
    value = doc.get(key)
    return value if isinstance(value, kind) else kind()
