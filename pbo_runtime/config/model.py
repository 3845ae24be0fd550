"""The parsed, checked description of a subsystem: immutable data, no run-time state.

The YAML loader (`config.loader`) builds these after the checker (`config.checker`) found no error.
Every spec keeps the `Location` of its YAML node so later errors can still point at the file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from pbo_runtime.objects.ports import PortSpec
from pbo_runtime.objects.ranges import Range


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
class RestartPolicy:
    """How often a dead RTPU is restarted before the run stops: at most `max` deaths within `within` s
    (`restart: {max: 3, within: 10 s}`, per RTPU or for the whole subsystem). None: the run stops."""

    max: int
    within: float
    loc: Location = NOWHERE


@dataclass(frozen=True)
class RtpuSpec:
    name: str
    index: int
    cpu: int | None = None
    loc: Location = NOWHERE
    spin: float = DEFAULT_SPIN  # seconds spun before each release after the kernel's wait (bench/wait.py)
    spin_loc: Location = NOWHERE
    restart: RestartPolicy | None = None  # its own, or the subsystem's; None: its death stops the run


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
class ObjectTypeSpec:
    """A kind of object a job may take (Onika's "preference file"): what its values are."""

    name: str
    dtype: str
    shape: tuple[int, ...]
    unit: str = ""
    doc: str = ""
    loc: Location = NOWHERE
    declared: bool = True  # False: implied by the variables marked `object: <name>` (no object_types: entry)
    range: Range | None = None  # `range: [low, high]`: every element of an object of this type (pbo job, objects:, steps)


@dataclass(frozen=True)
class ObjectSpec:
    """A named object: a value of an object type, given to a job or an application by name."""

    name: str
    type: str
    value: Any = field(default=None, compare=False)  # read-only numpy array of the type's dtype and shape
    doc: str = ""
    loc: Location = NOWHERE


ACTION = "action"
ACTION_REQUIRING_OBJECT = "action_requiring_object"
INCOMPLETE = "incomplete"  # an application with gaps of several object types: no one object fills it


@dataclass(frozen=True)
class JobSpec:
    name: str
    configuration: str
    object: str | None = None  # the variable its object is written to: `object:`, or inferred from the tasks
    pre: str | None = None
    post: str | None = None
    timeout: float | None = None
    loc: Location = NOWHERE
    object_type: str | None = None  # the type of its object (Onika §4.3.3)

    @property
    def kind(self) -> str:
        """An action, or an action requiring an object (Onika §4.4.1)."""
        return ACTION if self.object is None else ACTION_REQUIRING_OBJECT


@dataclass(frozen=True)
class ApplicationStep:
    job: str  # a job's name, or an application's when `is_application`
    arguments: Mapping[str, Any] = field(default_factory=dict)  # a job's object variable -> the value written
    loc: Location = NOWHERE
    is_application: bool = False  # the step runs another application (Onika §4.4.2)
    object: str | None = None  # a named object given to the step (its value is read when the step runs)
    fill: Any = field(default=None, compare=False)  # an application's object written out: fills each of its gaps
    decision: Decision | None = None  # a step that decides (if, try, repeat, wait): `job` is then its kind


DECISIONS = ("if", "try", "repeat", "wait")  # the step kinds that decide (DESIGN §16), by their first key


@dataclass(frozen=True)
class Decision:
    """A step that decides at a cycle boundary, on the table's values (config.decisions)."""

    kind: str  # one of DECISIONS
    rows: tuple[tuple[ApplicationStep, ...], ...] = ()  # if: (then, else); try: (try, fallback); repeat: (body,)
    condition: str | None = None  # if; repeat's until; wait
    times: int | None = None  # repeat: how many times
    most: int | None = None  # repeat until: how many times at most
    timeout: float | None = None  # wait: it fails after this long


@dataclass(frozen=True)
class Gap:
    """A step of an application that lacks its object (Onika §4.4.2, Figure 4)."""

    step: int  # 1-based, in the application's own steps
    job: str  # the job, or the incomplete application, of that step
    object_type: str | None  # None: an incomplete application with gaps of several types (fill them inside it)


@dataclass(frozen=True)
class ApplicationSpec:
    name: str
    steps: tuple[ApplicationStep, ...]
    loc: Location = NOWHERE
    complete: bool = True  # False when a step lacks its object: it may be kept but not run (Onika §4.4.2)
    gaps: tuple[Gap, ...] = ()

    @property
    def object_type(self) -> str | None:
        """The one object type of all its gaps, if it has gaps and they agree: one object fills them all."""
        types = {gap.object_type for gap in self.gaps}
        return next(iter(types)) if len(types) == 1 else None

    @property
    def kind(self) -> str:
        """As a step of another application: an action, an action requiring an object, or neither."""
        if not self.gaps:
            return ACTION
        return ACTION_REQUIRING_OBJECT if self.object_type is not None else INCOMPLETE


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
    object_types: Mapping[str, ObjectTypeSpec] = field(default_factory=dict)  # declared, then implied
    objects: Mapping[str, ObjectSpec] = field(default_factory=dict)
    robot_notes: tuple[str, ...] = field(default=(), compare=False)  # what loading the plant's robot file changed

    def rtpu(self, name: str) -> RtpuSpec:
        return next(r for r in self.rtpus if r.name == name)

    def tasks_on(self, rtpu: str) -> tuple[TaskSpec, ...]:
        return tuple(t for t in self.tasks.values() if t.rtpu == rtpu)
