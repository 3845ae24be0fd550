"""The parsed, checked description of a subsystem: immutable data, no run-time state.

The YAML loader (`config.loader`) builds these after the checker (`config.checker`) found no error.
Every spec keeps the `Location` of its YAML node so later errors can still point at the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, NamedTuple

from pbo_runtime.objects.ports import PortSpec


class Location(NamedTuple):
    """Where a YAML node is (1-based). A NamedTuple: a file has hundreds of thousands of them."""

    file: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


NOWHERE = Location("<none>", 0, 0)


# The executive sleeps in the kernel until this long before a release, then spins the rest: long
# enough to hide a late wake-up, short enough to leave CPU for the other RTPUs; how this figure was
# chosen, measured: docs/performance.md, "The wait before a release" (`python -m bench.wait`).
DEFAULT_SPIN = 0.0002


@dataclass(frozen=True)
class RtpuSpec:
    name: str
    index: int
    cpu: int | None = None
    loc: Location = NOWHERE
    spin: float = DEFAULT_SPIN  # seconds spun before each release after the kernel's wait (bench/wait.py)
    spin_loc: Location = NOWHERE


@dataclass(frozen=True)
class BusSpec:
    bandwidth: float = 40e6  # bytes per second
    lock_overhead: float = 16.0  # bytes: Δ of TR eq. 1
    loc: Location = NOWHERE


@dataclass(frozen=True)
class PlantSpec:
    type: str = "mujoco_arm"  # entry point in group pbo.plants
    model: str = "puma560"
    timestep: float = 0.001  # seconds
    options: Mapping[str, Any] = field(default_factory=dict)
    loc: Location = NOWHERE


@dataclass(frozen=True)
class PortClaim:
    """Channels of an I/O device (TR §4.6.1): a task's `{device: adc0, channels: 0-5}`, or a device's `io:`.

    `channels` None: the whole device (every channel of a port-based device).
    """

    device: str
    channels: tuple[int, ...] | None = None
    loc: Location = NOWHERE


@dataclass(frozen=True)
class DeviceSpec:
    name: str
    driver: str  # entry point in group pbo.drivers
    exclusive: bool = False
    options: Mapping[str, Any] = field(default_factory=dict)  # every other key, e.g. mode
    loc: Location = NOWHERE
    io: PortClaim | None = None  # a sensor-actuator device wired to channels of an I/O device (TR §4.6.2)


@dataclass(frozen=True)
class VariableSpec:
    name: str
    index: int
    dtype: str
    shape: tuple[int, ...]
    doc: str = ""
    object: str | None = None  # the object type a job may set it as
    loc: Location = NOWHERE
    initial: Any = field(default=None, compare=False)  # read-only numpy array job control writes at start

    @property
    def size(self) -> int:
        n = 1
        for d in self.shape:
            n *= d
        return n


@dataclass(frozen=True)
class PortBinding:
    """One port of a task linked to one variable of the table."""

    port: PortSpec
    variable: str
    shape: tuple[int, ...]


@dataclass(frozen=True)
class TaskSpec:
    name: str
    module: str  # library name (entry point in group pbo.modules)
    rtpu: str
    period: float  # seconds; for an aperiodic task its min_interarrival (the worst case analysis assumes)
    priority: int = 0  # higher runs first among ready tasks of equal criticality
    critical: bool = False
    params: Mapping[str, Any] = field(default_factory=dict)
    bindings: tuple[PortBinding, ...] = ()
    resources: tuple[str, ...] = ()  # the devices the task may open, by name
    index: int = 0
    loc: Location = NOWHERE
    wcet: float | None = None  # seconds: the declared worst-case execution time of one cycle
    aperiodic: bool = False  # released by events, at most once per min_interarrival (TR §4.3)
    min_interarrival: float | None = None  # seconds, for an aperiodic task
    # device -> the channels the task opens, for resources given as {device: adc0, channels: 0-5};
    # a device not listed here is opened whole
    resource_channels: Mapping[str, tuple[int, ...]] = field(default_factory=dict)
    # in-var port -> seconds: how old a critical task's input may be before it runs its locally
    # stable behaviour instead of its cycle (a port not listed: two periods of its writer)
    fresh_within: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ConfigurationSpec:
    name: str
    tasks: tuple[str, ...]
    loc: Location = NOWHERE


@dataclass(frozen=True)
class JobSpec:
    name: str
    configuration: str
    object: str | None = None
    pre: str | None = None
    post: str | None = None
    timeout: float | None = None
    loc: Location = NOWHERE


@dataclass(frozen=True)
class ApplicationStep:
    job: str  # a job's name, or an application's when `is_application`
    arguments: Mapping[str, Any] = field(default_factory=dict)
    loc: Location = NOWHERE
    is_application: bool = False  # the step runs another application (Onika §4.4.2)


@dataclass(frozen=True)
class ApplicationSpec:
    name: str
    steps: tuple[ApplicationStep, ...]
    loc: Location = NOWHERE
    complete: bool = True  # False when a step lacks its object: it may be kept but not run (Onika §4.4.2)


@dataclass(frozen=True)
class Subsystem:
    """Everything one YAML file (and its includes) says, checked and resolved."""

    name: str
    file: str
    rtpus: tuple[RtpuSpec, ...]
    bus: BusSpec
    plant: PlantSpec | None
    devices: Mapping[str, DeviceSpec]
    dims: Mapping[str, int]
    variables: Mapping[str, VariableSpec]  # in table order
    tasks: Mapping[str, TaskSpec]  # in file order; TaskSpec.index is the task's id in the table
    configurations: Mapping[str, ConfigurationSpec]
    jobs: Mapping[str, JobSpec]
    applications: Mapping[str, ApplicationSpec]
    init_order: tuple[str, ...]  # every task, producers of consts before their consumers

    def rtpu(self, name: str) -> RtpuSpec:
        return next(r for r in self.rtpus if r.name == name)

    def tasks_on(self, rtpu: str) -> tuple[TaskSpec, ...]:
        return tuple(t for t in self.tasks.values() if t.rtpu == rtpu)
