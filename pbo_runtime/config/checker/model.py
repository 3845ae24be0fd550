"""The checker's vocabulary: the keys each section allows, what a pass returns (`Checked`), and
the records it keeps while it works (a task as far as it resolved, its port links, its device claims).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from pbo_runtime.config.model import (
    ApplicationSpec,
    BusSpec,
    ConfigurationSpec,
    DeviceSpec,
    JobSpec,
    Location,
    ObjectSpec,
    ObjectTypeSpec,
    PlantSpec,
    RtpuSpec,
    TaskSpec,
    VariableSpec,
)
from pbo_runtime.errors import ConfigError
from pbo_runtime.objects.ports import PortSpec

# what the table holds
DTYPES = ("float64", "float32", "int64", "int32", "int16", "int8", "uint64", "uint32", "uint16", "uint8", "bool")

TOP_KEYS = (
    "subsystem",
    "include",
    "rtpus",
    "restart",
    "bus",
    "plant",
    "devices",
    "dims",
    "variables",
    "object_types",
    "objects",
    "tasks",
    "configurations",
    "jobs",
    "applications",
)
TOP_REQUIRED = ("subsystem", "rtpus", "tasks", "configurations")  # variables: only those ports cannot define
VARIABLE_KEYS = ("type", "shape", "doc", "object", "initial")
TASK_KEYS = (
    "module", "rtpu", "period", "rate", "aperiodic", "min_interarrival", "wcet",
    "priority", "critical", "params", "ports", "resources", "fresh_within",
)
JOB_KEYS = ("configuration", "object", "pre", "post", "timeout")
OBJECT_TYPE_KEYS = ("type", "shape", "unit", "doc", "range")
OBJECT_KEYS = ("type", "value", "doc")
NO_OBJECT = "none"  # `object: none`: a job that takes no object, its tasks reading the variable as it is
DEVICE_KEYS = ("driver", "exclusive", "io")  # every other key of a device is a driver option
CLAIM_KEYS = ("device", "channels")  # a resource or an io: given as {device: adc0, channels: 0-5}
BUS_KEYS = ("bandwidth", "lock_overhead")
RTPU_KEYS = ("cpu", "spin", "restart")
RESTART_KEYS = ("max", "within")

ModuleLookup = Callable[[str], Any]
DriverLookup = Callable[[str], Any]


@dataclass
class Checked:
    """What the checker found: the problems, and the specs built from the parts that are right."""

    errors: list[ConfigError] = field(default_factory=list)
    warnings: list[ConfigError] = field(default_factory=list)
    name: str = ""
    rtpus: tuple[RtpuSpec, ...] = ()
    bus: BusSpec = field(default_factory=BusSpec)
    plant: PlantSpec | None = None
    devices: dict[str, DeviceSpec] = field(default_factory=dict)
    dims: dict[str, int] = field(default_factory=dict)
    variables: dict[str, VariableSpec] = field(default_factory=dict)
    initial_values: dict[str, np.ndarray] = field(default_factory=dict)
    tasks: dict[str, TaskSpec] = field(default_factory=dict)
    configurations: dict[str, ConfigurationSpec] = field(default_factory=dict)
    jobs: dict[str, JobSpec] = field(default_factory=dict)
    applications: dict[str, ApplicationSpec] = field(default_factory=dict)
    object_types: dict[str, ObjectTypeSpec] = field(default_factory=dict)
    objects: dict[str, ObjectSpec] = field(default_factory=dict)
    init_order: tuple[str, ...] = ()
    inferred: list[str] = field(default_factory=list)  # variables whose type or shape came from their ports
    robot_dims: dict[str, int] = field(default_factory=dict)  # dims 'dims:' left out, taken from the plant's robot
    robot_notes: list[str] = field(default_factory=list)  # what loading the plant's robot file changed (dropped meshes...)
    robot_limits: list[dict[str, Any]] = field(
        default_factory=list)  # each joint's limits (the robot's, tightened by plant options)


class _Link(NamedTuple):
    """A port of a task and the variable it links to, before that variable is known to exist.

    A NamedTuple: a large file has one per port of every task."""

    port: PortSpec
    variable: str
    loc: Location
    explicit: bool  # written as ports: {port: variable}; else the port's own default name


class _Linked(NamedTuple):
    """A port linked to a declared variable, as the check of dtype and shape saw it."""

    task: str
    port: PortSpec  # with the variable's dtype (and shape) where it declares any
    shape: tuple[int, ...]  # the port's shape, resolved
    loc: Location
    own_dtype: bool  # the port declares its dtype (not ANY_DTYPE): it has a say in what the variable should be
    own_shape: bool  # ... and its shape


@dataclass
class _PartialVariable:
    """A `variables:` entry that gives no type: what it does give, the rest comes from its ports."""

    loc: Location
    shape: tuple[int, ...] | None  # None: from the ports too
    doc: str
    object: str | None
    initial: Any  # the raw YAML value, checked once the type and shape are known; None: none given
    initial_loc: Location | None


@dataclass
class _Binding:
    """A port of a task linked to a variable, with where the link was written."""

    port: PortSpec
    variable: str
    shape: tuple[int, ...]
    loc: Location


@dataclass
class _Task:
    """A task as far as it could be resolved; `ok` is False when its ports are unknown."""

    name: str
    index: int
    loc: Location
    module: str = ""
    ok: bool = False
    bindings: list[_Binding] = field(default_factory=list)
    outputs: tuple[tuple[str, str], ...] = ()  # (port, variable) of each output port as linked, resolved or not (E407)
    resources: list[tuple[str, Location]] = field(default_factory=list)
    channels: dict[str, tuple[int, ...]] = field(default_factory=dict)  # device -> channels, where a subset is given
    rtpu: str = ""
    period: float = 0.0
    priority: int = 0
    critical: bool = False
    wcet: float | None = None
    aperiodic: bool = False
    min_interarrival: float | None = None
    params: dict[str, Any] = field(default_factory=dict)
    built_params: Any = None  # the module's Params instance, once the params checked out
    fresh_within: dict[str, tuple[float, Location]] = field(default_factory=dict)  # in-var port -> bound (s), where given


@dataclass(frozen=True)
class _Claim:
    """Channels of a device a task takes when it opens a resource: directly, or `via` a sensor wired to it."""

    task: str
    device: str
    channels: tuple[int, ...] | None  # None: no channel is locked (a device that is not port-based)
    loc: Location
    via: str | None = None  # the sensor-actuator device whose io: brought this claim

    def who(self) -> str:
        through = f", through device '{self.via}'" if self.via else ""
        return f"'{self.task}' (line {self.loc.line}{through})"
