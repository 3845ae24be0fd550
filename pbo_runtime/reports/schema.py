"""A JSON Schema (draft 2020-12) of the subsystem file, for editors.

YAML Language Server (VS Code's YAML extension, and others) reads a first-line comment

    # yaml-language-server: $schema=pbo-subsystem.schema.json

(a path relative to the file: the schema lies beside the example configs, in the repository's
`configs/` and in the folder `pbo examples` copies them to) and then completes keys, shows their
descriptions and marks unknown keys while one types.
The schema is built from what the checker accepts: the section keys, the units of quantities,
the registered modules (each with the parameters of its `Params` dataclass) and drivers. It
helps while editing; `pbo check` stays the judge (links, shapes, writers, const order).
"""

from __future__ import annotations

import dataclasses
import json
import re
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pbo_runtime.config.model import PlantSpec
from pbo_runtime.config.units import DATA_RATE, FREQUENCY, SIZE, TIME, UNITS
from pbo_runtime.objects import registry
from pbo_runtime.objects.module import param_ranges
from pbo_runtime.objects.ranges import Range
from pbo_runtime.reports.lexicon import jsonable, param_hints, params_info, ports_depend_on_params

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_ID = "urn:pbo-runtime:subsystem-schema"
_PLANT_KEYS = ("type", "model", "timestep")  # a plant section's own keys; the others are its options
DTYPES = ("float64", "float32", "int64", "int32", "int16", "int8", "uint8", "uint16", "uint32", "uint64", "bool")

# A number (as `config.units` reads it), then a unit; a bare number in a string is SI units.
_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"

_QUANTITY_DOC = {
    TIME: ("a time: a number of seconds, or a string with a unit", "1 ms"),
    FREQUENCY: ("a frequency: a number of hertz, or a string with a unit", "1 kHz"),
    DATA_RATE: ("a data rate: a number of bytes per second, or a string with a unit", "40 MB/s"),
    SIZE: ("a size: a number of bytes, or a string with a unit", "16 B"),
}


def quantity_pattern(kind: str) -> str:
    """The regular expression of a quantity string of this kind: `1 ms`, `1.5e-3 s`, `.5kHz`."""
    units = sorted(UNITS[kind], key=lambda u: (-len(u), u))  # longest first: 'ms' before 's'
    alternatives = "|".join(re.escape(u) for u in units)
    return rf"^\s*{_NUMBER}\s*(?:{alternatives})?\s*$"


def _quantity(kind: str) -> dict[str, Any]:
    doc, example = _QUANTITY_DOC[kind]
    units = ", ".join(dict.fromkeys(u for u in UNITS[kind] if u not in ("μs", "KHz", "khz", "hz", "KB", "sec")))
    return {
        "description": f"{doc} ({units}), e.g. '{example}'",
        "oneOf": [
            {"type": "number", "exclusiveMinimum": 0} if kind != SIZE else {"type": "number", "minimum": 0},
            {"type": "string", "pattern": quantity_pattern(kind)},
        ],
    }


def _obj(properties: dict[str, Any], description: str, required: tuple[str, ...] = (), closed: bool = True) -> dict[str, Any]:
    node: dict[str, Any] = {"type": "object", "description": description, "properties": properties}
    if closed:
        node["additionalProperties"] = False
    if required:
        node["required"] = list(required)
    return node


def _map(values: dict[str, Any], description: str) -> dict[str, Any]:
    """A section that maps names (any text) to entries of one form."""
    return {"type": "object", "description": description, "additionalProperties": values}


# --- module parameters ------------------------------------------------------------------------


def hint_schema(hint: Any, allowed: Range | None = None) -> dict[str, Any]:
    """The JSON type of a `Params` field's type hint, as the checker converts YAML values; its numbers
    (each number of a list) with the minimum and maximum of the field's range."""
    bounds = allowed.schema() if allowed is not None else {}
    if hint is float:
        return {"type": "number", **bounds}
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer", **bounds}
    if hint is str:
        return {"type": "string"}
    if hint is type(None):
        return {"type": "null"}
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Literal:
        return {"enum": list(args)}
    if origin in (typing.Union, types.UnionType):
        return {"oneOf": [hint_schema(a, allowed) for a in args]}
    if origin in (tuple, list):
        items = args[0] if args and ((len(args) == 2 and args[1] is Ellipsis) or origin is list) else None
        node: dict[str, Any] = {"type": "array"}
        if items is not None:
            node["items"] = hint_schema(items, allowed)
        elif args:  # a fixed-length tuple
            node["prefixItems"] = [hint_schema(a) for a in args]
            node["minItems"] = node["maxItems"] = len(args)
        return node
    return {}  # Any, or a type the checker passes through unchecked


def params_schema(module: str, cls: type) -> dict[str, Any]:
    """The `params:` of a task of this module: the fields of its `Params` dataclass."""
    return fields_schema(getattr(cls, "Params", None), f"parameters of module '{module}'")


def fields_schema(params_type: Any, description: str) -> dict[str, Any]:
    """The fields of a dataclass as the checker converts YAML values to them (a module's Params, a plant's Options)."""
    hints = param_hints(params_type)
    ranges = param_ranges(params_type) if isinstance(params_type, type) else {}
    properties: dict[str, Any] = {}
    required: list[str] = []
    for info in params_info(params_type):
        node = hint_schema(hints[info["name"]], ranges.get(info["name"]))
        doc = info["doc"]
        node["description"] = (f"{info['name']}: {info['type']}" + (f", {info['range']}" if info["range"] else "")
                               + (f" ({doc})" if doc else ""))
        if info["required"]:
            required.append(info["name"])
        else:
            node["default"] = jsonable(info["default"])
        properties[info["name"]] = node
    return _obj(properties, description, tuple(required))


def plant_option_branches(plants: Sequence[str]) -> list[dict[str, Any]]:
    """Per registered plant that declares its `Options`: the option keys its `plant:` section may hold."""
    branches = []
    for plant in plants:
        try:
            options = getattr(registry.plant_class(plant), "Options", None)
        except Exception:  # a broken plant: its section stays open
            continue
        if not (isinstance(options, type) and dataclasses.is_dataclass(options)):
            continue
        declared = fields_schema(options, f"options of plant '{plant}'")
        condition: dict[str, Any] = {"properties": {"type": {"const": plant}}}
        if plant != PlantSpec.type:  # the default plant also answers a section without `type:`
            condition["required"] = ["type"]
        branches.append({"if": condition, "then": {
            "properties": declared["properties"],
            "propertyNames": {"enum": [*_PLANT_KEYS, *declared["properties"]]}}})
    return branches


# --- the schema -------------------------------------------------------------------------------


def json_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a subsystem file, with the registered modules and drivers."""
    modules = registry.names(registry.MODULES)
    drivers = registry.names(registry.DRIVERS)
    plants = registry.names(registry.PLANTS)
    name = {"type": "string", "minLength": 1}

    restart = _obj(
        {"max": {"type": "integer", "minimum": 0,
                 "description": "deaths restarted within `within` before the run stops (0: never)"},
         "within": {"$ref": "#/$defs/time", "description": "the window the deaths are counted in, e.g. '10 s'"}},
        "restart a dead RTPU alone: at most `max` times within `within`, e.g. {max: 3, within: 10 s}",
        required=("max",),
    )
    rtpu_entry = _obj(
        {"restart": restart,
         "cpu": {"type": "integer", "minimum": 0, "description": "the CPU core this RTPU process is pinned to"},
         "spin": {"$ref": "#/$defs/time",
                  "description": "how long before each release the RTPU stops sleeping and spins (default 200 us); "
                                 "shorter than its shortest period"}},
        "an RTPU's options",
    )
    rtpus = {
        "description": "the RTPU processes; tasks name the one that hosts them: a list of names, or a mapping {name: {cpu: N, "
                       "spin: 200 us}}",
        "oneOf": [
            {"type": "array", "items": name, "minItems": 1, "uniqueItems": True},
            {"type": "object", "minProperties": 1, "additionalProperties": {"oneOf": [rtpu_entry, {"type": "null"}]}},
        ],
    }
    bus = _obj(
        {
            "bandwidth": {"$ref": "#/$defs/data_rate", "description": "the backplane's bandwidth (TR eq. 1), e.g. '40 MB/s'"},
            "lock_overhead": {"$ref": "#/$defs/size", "description": "the lock overhead Δ of TR eq. 1, e.g. '16 B'"},
        },
        "the backplane's bandwidth and the lock overhead Δ of TR eq. 1",
    )
    plant_type: dict[str, Any] = {"type": "string", "description": "the registered plant (entry point group 'pbo.plants'), "
                                                                   "default mujoco_arm"}
    if plants:
        plant_type["enum"] = list(plants)
    plant = _obj(
        {
            "type": plant_type,
            "model": {"type": "string", "description": "the robot model the plant simulates, e.g. puma560"},
            "timestep": {"$ref": "#/$defs/time", "description": "the simulation time step, e.g. '1 ms'"},
        },
        "the simulated world the devices live in; other keys are options of the plant",
        closed=False,
    )
    option_branches = plant_option_branches(plants)
    if option_branches:
        plant["allOf"] = option_branches
    driver: dict[str, Any] = {"type": "string", "description": "the registered driver (entry point group 'pbo.drivers')"}
    if drivers:
        driver["enum"] = list(drivers)
    channels_item = {"oneOf": [{"type": "integer", "minimum": 0, "maximum": 63},
                               {"type": "string", "pattern": r"^\s*\d+\s*(-\s*\d+\s*)?$"}]}
    channels = {
        "description": "channels of a port-based I/O device: 0-5, 6, or [0-3, 6, 7] (ranges include both ends)",
        "oneOf": [channels_item, {"type": "array", "items": channels_item, "minItems": 1}],
    }
    claim = _obj(
        {
            "device": {"type": "string", "minLength": 1, "description": "a device of 'devices'"},
            "channels": channels,
        },
        "channels of an I/O device: {device: adc0, channels: 0-5} (without channels: the whole device)",
        required=("device",),
    )
    device = _obj(
        {
            "driver": driver,
            "exclusive": {"type": "boolean", "default": False,
                          "description": "true: at most one task of a configuration may use it"},
            "io": {**claim, "description": "a sensor-actuator device: the I/O device channels its cable is wired to, "
                                           "e.g. {device: adc0, channels: 0-5}"},
        },
        "a device: its driver, whether it is exclusive, and driver options (e.g. mode: torque)",
        required=("driver",),
        closed=False,
    )
    shape_item = {"oneOf": [{"type": "integer", "minimum": 1},
                            {"type": "string", "minLength": 1, "description": "a name from 'dims'"}]}
    variable = _obj(
        {
            "type": {"type": "string", "enum": list(DTYPES), "description": "the numpy dtype of the variable"},
            "shape": {
                "description": "sizes or dim names, e.g. [NDOF, 4]; leave it out for a scalar",
                "oneOf": [{"type": "array", "items": shape_item}, shape_item, {"type": "null"}],
            },
            "doc": {"type": "string", "description": "what the variable means, with its unit"},
            "object": {"type": "string", "description": "the object type a job may set this variable as (it counts as written by "
                                                        "job control)"},
            "initial": {
                "description": "the value job control writes before any task starts: a number for every element, or a nested "
                               "list of the shape",
                "type": ["number", "boolean", "array"],
            },
        },
        "a variable of the global state variable table (no type: the ports that link it give type and shape)",
    )
    task_properties = {
        "module": {"type": "string", "enum": list(modules),
                   "description": "the module's library name (`pbo lexicon` lists them)"},
        "rtpu": {"type": "string", "description": "the RTPU that hosts this task (one of 'rtpus')"},
        "period": {"$ref": "#/$defs/time", "description": "the task's period, e.g. '1 ms' (or give a rate)"},
        "rate": {"$ref": "#/$defs/frequency", "description": "the task's rate, e.g. '1 kHz' (or give a period)"},
        "priority": {"type": "integer", "description": "higher runs first among ready tasks of equal criticality"},
        "critical": {"type": "boolean", "description": "runs before ready tasks that are not critical, and is turned on first "
                                                       "(e.g. the robot interface)"},
        "params": {"type": "object", "description": "the module's parameters (`pbo lexicon` lists them)"},
        "ports": {
            "type": "object",
            "description": "port -> variable where the names differ (same name otherwise), e.g. {tau: tau_u}",
            "additionalProperties": {"type": "string", "minLength": 1},
        },
        "resources": {
            "type": "array",
            "items": {"oneOf": [name, claim]},
            "uniqueItems": True,
            "description": "the devices this task may open, e.g. [arm, {device: adc0, channels: 6-7}]",
        },
        "wcet": {"$ref": "#/$defs/time", "description": "the task's worst-case execution time per cycle, for the schedulability "
                                                        "check"},
        "aperiodic": {"type": "boolean", "description": "true: the task is released by events, not by a period"},
        "min_interarrival": {"$ref": "#/$defs/time", "description": "an aperiodic task's least time between two releases"},
        "fresh_within": {
            "type": "object",
            "description": "a critical task's in-var port -> how old its value may be before the task runs its locally "
                           "stable behaviour, e.g. {tau_u: 3 ms} (default: two periods of the port's writer)",
            "additionalProperties": {"$ref": "#/$defs/time"},
        },
    }
    task = _obj(task_properties, "a task: an instance of a module on an RTPU", required=("module", "rtpu"))
    branches = []
    for module in modules:
        try:
            cls = registry.module_class(module)
        except Exception:  # a broken library: its tasks still get the generic params
            continue
        then: dict[str, Any] = {"properties": {"params": {"$ref": f"#/$defs/params_{module}"}}}
        if not ports_depend_on_params(cls):
            then["properties"]["ports"] = {"propertyNames": {"enum": [p.name for p in cls.ports()]}}
        branches.append({"if": {"properties": {"module": {"const": module}}, "required": ["module"]}, "then": then})
    if branches:
        task["allOf"] = branches
    job = _obj(
        {
            "configuration": {"type": "string", "description": "the configuration the job runs"},
            "object": {"type": "string", "description": "the variable (marked with object:) an application step gives the job; "
                                                        "left out: inferred from the tasks that read one; none: no object"},
            "pre": {"type": "string", "description": "a pre-condition: an expression over variables that must hold before the "
                                                     "job starts"},
            "post": {"type": "string", "description": "a post-condition: the job is done when it holds, e.g. \"max(abs(q_m - "
                                                      "q_d)) < 1e-3\""},
            "timeout": {"$ref": "#/$defs/time", "description": "the job fails if its post-condition does not hold within this "
                                                               "time"},
        },
        "a job: a configuration with an object and pre/post conditions",
        required=("configuration",),
    )
    step = {
        "description": "a job or application name, {job: object name}, {job: {object variable: value}}, {application: "
                       "{object type: value}}, or a step that decides (if, try, repeat, wait)",
        "anyOf": [
            {"type": "string", "minLength": 1},
            {
                "type": "object",
                "minProperties": 1,
                "maxProperties": 1,
                "additionalProperties": {
                    "oneOf": [{"type": "string", "minLength": 1, "description": "a named object (one of 'objects')"},
                              {"type": "object", "description": "object variable (or, for an application, object type) -> value"},
                              {"type": "null"}],
                },
            },
            *_deciding_steps(),
        ],
    }
    object_type = _obj(
        {
            "type": {"type": "string", "enum": list(DTYPES), "description": "the numpy dtype of the object's values"},
            "shape": {
                "description": "sizes or dim names, e.g. [NDOF]; leave it out for a scalar",
                "oneOf": [{"type": "array", "items": shape_item}, shape_item, {"type": "null"}],
            },
            "unit": {"type": "string", "description": "the unit of its values, for the people who give them, e.g. rad"},
            "doc": {"type": "string", "description": "what an object of this type is"},
        },
        "an object type: what a job's object may be (variables marked object: <type> hold it)",
        required=("type",),
    )
    named_object = _obj(
        {
            "type": {"type": "string", "description": "its object type (one of 'object_types', or a type a variable is marked "
                                                      "with)"},
            "value": {"description": "a number for every element, or a nested list of the type's shape",
                      "type": ["number", "boolean", "array"]},
            "doc": {"type": "string", "description": "what the object is, e.g. the home pose"},
        },
        "a named object: a value of an object type, given to a job by name (- move: home)",
        required=("type", "value"),
    )
    top = {
        "subsystem": {
            "type": "string",
            "pattern": r"^[A-Za-z][A-Za-z0-9_-]*$",
            "description": "a name (letters, digits, '_', '-'): it names the run's shared memory and queues",
        },
        "include": {
            "description": "other files whose sections are merged in (paths relative to this file)",
            "oneOf": [{"type": "string"}, {"type": "array", "items": {"type": "string"}}],
        },
        "rtpus": rtpus,
        "restart": restart,
        "bus": bus,
        "plant": plant,
        "devices": _map(device, "devices: name -> driver (a registered driver), exclusive, and driver options"),
        "dims": {
            "type": "object",
            "description": "named sizes used in shapes, e.g. {NDOF: 6}",
            "additionalProperties": {"type": "integer", "minimum": 1},
        },
        "variables": _map({"$ref": "#/$defs/variable"},
                          "the global state variable table: name -> type, shape, doc, object, initial; "
                          "a variable that only connects ports needs no entry"),
        "object_types": _map({"$ref": "#/$defs/object_type"}, "object types: what a job's object may be, name -> type, shape, "
                                                              "unit, doc"),
        "objects": _map({"$ref": "#/$defs/object"}, "named objects: name -> type and value, given to jobs by name"),
        "tasks": _map({"$ref": "#/$defs/task"},
                      "every task any configuration may use: name -> module, rtpu, period or rate, ..."),
        "configurations": _map(
            {"type": "array", "items": name, "uniqueItems": True, "description": "the tasks that run together"},
            "configurations: name -> the tasks that run together",
        ),
        "jobs": _map({"$ref": "#/$defs/job"}, "jobs: a configuration with an object and pre/post conditions"),
        "applications": _map(
            {"type": "array", "items": {"$ref": "#/$defs/step"}, "description": "the steps, in order"},
            "applications: sequences of jobs",
        ),
    }
    schema = _obj(top, "A pbo-runtime subsystem file: one control subsystem (see docs/configuration.md)")
    schema = {
        "$schema": SCHEMA_DIALECT,
        "$id": SCHEMA_ID,
        "title": "pbo-runtime subsystem",
        **schema,
        # an included file may hold only some sections; a file without includes must be whole
        "if": {"not": {"required": ["include"]}},
        "then": {"required": ["subsystem", "rtpus", "tasks", "configurations"]},
        "$defs": {
            "time": _quantity(TIME),
            "frequency": _quantity(FREQUENCY),
            "data_rate": _quantity(DATA_RATE),
            "size": _quantity(SIZE),
            "variable": variable,
            "task": task,
            "job": job,
            "step": step,
            "object_type": object_type,
            "object": named_object,
            **{f"params_{m}": params_schema(m, registry.module_class(m)) for m in modules if _loads(m)},
        },
    }
    return schema


def _deciding_steps() -> list[dict[str, Any]]:
    """The steps that decide (docs/configuration.md#steps-that-decide): if, try, repeat, wait."""
    def row(what: str) -> dict[str, Any]:
        return {"type": "array", "items": {"$ref": "#/$defs/step"}, "description": what}

    def condition(what: str) -> dict[str, Any]:
        return {"type": "string", "description": f"{what}: a condition of the job language, read when the step is reached"}

    def times(what: str) -> dict[str, Any]:
        return {"type": "integer", "minimum": 1, "description": what}

    def kind(properties: dict[str, Any], required: list[str], description: str) -> dict[str, Any]:
        return {"type": "object", "properties": properties, "required": required, "additionalProperties": False,
                "description": description}

    return [
        kind({"if": condition("the steps of then: run if it holds"), "then": row("the steps run when the condition holds"),
              "else": row("the steps run when it does not")}, ["if", "then"], "if: CONDITION, then: [steps], else: [steps]"),
        kind({"try": row("steps that may fail (a pre-condition, a timeout)"),
              "fallback": row("the steps run if the try failed; the application goes on after them")},
             ["try", "fallback"], "try: [steps], fallback: [steps]"),
        kind({"repeat": row("the steps repeated"), "times": times("how many times"),
              "until": condition("it stops repeating once this holds after a turn"),
              "max": times("with until: the most turns; still false after them, the repeat fails")},
             ["repeat"], "repeat: [steps] with times: N, or until: CONDITION with max: N"),
        kind({"wait": condition("the application goes on once this holds"),
              "timeout": {"$ref": "#/$defs/time", "description": "the wait fails (as a job does) after this long"}},
             ["wait"], "wait: CONDITION, timeout: TIME"),
    ]


def _loads(module: str) -> bool:
    try:
        registry.module_class(module)
    except Exception:
        return False
    return True


def schema_text() -> str:
    """The schema as the committed file holds it: sorted keys, indent 2, a trailing newline."""
    return json.dumps(json_schema(), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def write_schema(path: str | Path) -> Path:
    """Write the schema to `path` (deterministic text: sorted keys, indent 2, trailing newline)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(schema_text(), encoding="utf-8")
    return target
