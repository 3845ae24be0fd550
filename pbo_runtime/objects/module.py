"""The port-based object: the base class of every control module (TR §4.3, Figure 11).

A module declares its ports on the class and overrides the components it needs. The framework
owns the loop: it transfers the ports and calls the components (see `task.lifecycle.Task`).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import re
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from pbo_runtime.errors import ParamError, closest_name
from pbo_runtime.objects.ports import Port, PortSpec
from pbo_runtime.objects.ranges import OutOfRange, Range, check_number


class Status(enum.IntEnum):
    """What `cycle` (and `error`) return: go on, turn this task off, or report an error.

    STABLE: go on, but this cycle ran the locally stable behaviour because the module's own
    inputs stopped being fresh (a device that stopped updating): the runtime reports the episode
    as it reports stale in-vars, and the task is back to normal with its next CONTINUE.
    """

    CONTINUE = 0
    OFF = 1
    ERROR = 2
    STABLE = 3


@dataclasses.dataclass(frozen=True)
class NoParams:
    """The parameters of a module that takes none."""


@typing.runtime_checkable
class TaskContext(typing.Protocol):
    """What a running task may ask of the runtime, besides its ports: what a module sees through
    `PortBasedObject`'s properties and methods. The runtime's own is `task.lifecycle.RuntimeTaskContext`."""

    task_name: str
    period: float  # seconds
    dims: dict[str, int]  # the subsystem's named dimensions
    resources: tuple[str, ...]  # the devices the task may open
    time: float  # the current cycle's release time, seconds on the run's clock
    event: Any  # an aperiodic task's event this cycle (None if none)
    out_dir: str  # the run's output directory (`pbo run --out DIR`, or its default), or "" when paths stay as given
    outputs: list[str]  # the files the task's `output_path` gave out, for the run to say where they went
    run_metadata: Mapping[str, str]  # the run: subsystem, configuration, clock, versions, the YAML file (reports.log_notes)
    variable_notes: Mapping[str, tuple[str, str]]  # each variable's (doc, unit) from the YAML
    restarted: bool  # its RTPU was restarted after a death (restart policy): continue the run's files

    @property
    def actuators_held(self) -> bool: ...  # a critical task holds, or a task is in ERROR (job control's flag)

    def open_device(self, name: str) -> Any: ...

    def written_at(self, port: str) -> float: ...

    def open_link(self, name: str, like: np.ndarray, role: str) -> Any: ...

    def hand_off(self, work: Callable[[], None], what: str) -> None: ...


class PortBasedObject:
    """Base class of control modules.

    Override the components you need; each does nothing by default. `init`, `on`, `off`,
    `kill`, `error` and `clear` run outside the real-time loop; `cycle` runs every period and
    must be real-time safe: no allocation, no I/O, no blocking.
    """

    Params: ClassVar[type] = NoParams
    # For an aperiodic task: the shape (sizes or dim names) of the values an operator's event must
    # carry, which the supervisor checks before sending it (`pbo event TASK values...`); None: any
    # list of finite numbers. A wrong event is refused to the operator, never a task in ERROR.
    EVENT_SHAPE: ClassVar[tuple[int | str, ...] | None] = None
    # For an aperiodic task: the closed range [low, high] each value of an event must be in, which
    # the supervisor checks with the shape; None: any finite number.
    EVENT_RANGE: ClassVar[tuple[float, float] | None] = None
    # The parameters an operator may change while the task runs (`pbo set TASK PARAM VALUE`): `tune`
    # gets the whole new Params between two cycles. Every other parameter is read in `init` only.
    TUNABLE: ClassVar[tuple[str, ...]] = ()
    # The Params fields that name a YAML device the module opens in `init` (an empty name: none),
    # each with the kind of device it needs (its driver's KIND) and the driver options it needs the
    # device to have: {"device": {"kind": "arm", "mode": "torque"}}. `pbo check` refuses a device
    # that is not among the task's resources (E608), lacks those options (E609) or is of another
    # kind (E610).
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {}
    # For inverse dynamics: the in-var port of the joint acceleration it turns into torque through the
    # arm's model (tau = M(q) qdd + ...). A joint controller writing that acceleration is analysed by
    # `pbo check` as a computed-torque loop: each joint a unit inertia. Empty: the module is none.
    ACCELERATION_INPUT: ClassVar[str] = ""
    _pbo_port_decls: ClassVar[tuple[Port, ...]] = ()

    _pbo_ports: list[np.ndarray]
    _pbo_context: TaskContext

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        seen: dict[str, Port] = {}
        for klass in reversed(cls.__mro__):
            for name, value in vars(klass).items():
                if isinstance(value, Port):
                    seen.pop(name, None)
                    seen[name] = value
        for slot, port in enumerate(seen.values()):
            port.slot = slot
        cls._pbo_port_decls = tuple(seen.values())

    # --- what the checker, the lexicon and the task see ---------------------------------------

    @classmethod
    def ports(cls) -> tuple[PortSpec, ...]:
        """The declared ports, in declaration order."""
        return tuple(port.spec for port in cls._pbo_port_decls)

    @classmethod
    def ports_for(cls, params: Any) -> tuple[PortSpec, ...]:
        """The ports of a task built with these params: the class's, then any the params add.

        Most modules have fixed ports; a data logger adds one input per logged variable.
        """
        return cls.ports()

    @classmethod
    def check_links(cls, params: Any, shapes: Mapping[str, tuple[int, ...]], dims: Mapping[str, int],
                    channels: Mapping[str, int], options: Mapping[str, Mapping[str, Any]]) -> None:
        """Raise ValueError for what `init` would refuse that the file already shows: `shapes` of the
        variables its ports link (by port name), the subsystem's `dims`, how many `channels` of each
        device the task opens and each device's `options` as written. `pbo check` calls it (E323);
        by default all is well."""

    @classmethod
    def same_shape(cls, params: Any) -> tuple[tuple[str, ...], ...]:
        """Groups of port names whose variables must all have one shape (a join's output and
        inputs): ports that take their shape from their variable, but must agree with each other.
        `pbo check` reports a variable of another shape; by default there are none."""
        return ()

    @classmethod
    def build_params(cls, values: dict[str, Any] | None) -> Any:
        """Turn a YAML `params:` mapping into the module's `Params`, or raise ParamError saying why."""
        return build_params(cls.Params, values or {}, cls.__name__)

    # --- the runtime's services -------------------------------------------------------------

    @property
    def task_name(self) -> str:
        return self._pbo_context.task_name

    @property
    def period(self) -> float:
        """The task's period in seconds."""
        return self._pbo_context.period

    @property
    def restarted(self) -> bool:
        """True in a task whose RTPU was restarted after its process died (a restart policy):
        a file it writes for the run should be continued, not replaced (the data logger does)."""
        return self._pbo_context.restarted

    @property
    def actuators_held(self) -> bool:
        """True while the run's critical tasks hold the plant (a robot interface's brakes): one of them
        runs its locally stable behaviour (a stale input, a stopped plant, the table lock held past
        its wait), or a task is in ERROR. This task's outputs then reach no actuator and measurements
        may stand still: a controller does not integrate meanwhile, and a reference generator
        starts again from the measured state once it is over. Cheap enough for `cycle` (one word
        of the table's header); job control sets it once it hears of the hold."""
        return self._pbo_context.actuators_held

    @property
    def bound_arrays(self) -> list[np.ndarray]:
        """The local arrays of every port, in `ports_for` order (class ports first)."""
        return self._pbo_ports

    @property
    def time(self) -> float:
        """The current cycle's release time, seconds on the run's clock."""
        return self._pbo_context.time

    @property
    def event(self) -> Any:
        """For an aperiodic task: the payload of the event this cycle serves (None if none)."""
        return self._pbo_context.event

    @property
    def resources(self) -> tuple[str, ...]:
        """The device names this task may open (its YAML `resources`)."""
        return self._pbo_context.resources

    def output_path(self, path: str) -> Path:
        """Where to write a file named `path`: a relative path under the run's output directory, an absolute one as given.

        Every run has an output directory (`pbo run --out DIR`, or runs/<subsystem>-<time>/), beside
        its report, so one run's files never overwrite another's and never land wherever the shell
        happened to be. Outside a run (a task made by hand) the path stays as given. The run lists
        the file among its outputs.
        """
        out_dir = self._pbo_context.out_dir
        given = Path(path)
        where = Path(out_dir) / given if out_dir and not given.is_absolute() else given
        self._pbo_context.outputs.append(str(where))
        return where

    @property
    def run_metadata(self) -> Mapping[str, str]:
        """What the run is, for a file a task writes: subsystem, configuration, clock, versions, the YAML file and text."""
        return self._pbo_context.run_metadata

    def variable_note(self, name: str) -> tuple[str, str]:
        """A variable's (doc, unit) as its YAML gives them (unit "" when it names none)."""
        return self._pbo_context.variable_notes.get(name, ("", ""))

    def written_at(self, port: str) -> float:
        """When the value now in `port`'s variable was written: its writer's release time, seconds on
        the run's clock (-inf if nothing wrote it). For `on`, to judge whether the value it takes
        over is what drives the plant now; not for `cycle` (it reads the table)."""
        return self._pbo_context.written_at(port)

    def open_link(self, name: str, like: np.ndarray, role: str) -> Any:
        """Open one end of the application's link `name` (call it in `init`).

        A periodic link's ends are 'sender' and 'reader'; a message link's 'sender' and 'server'
        (an aperiodic task: each message then releases it, with `[body, sent_ns]` in `event`).
        Items are shaped like `like` (a bound port array); the link closes when the task is killed.
        """
        return self._pbo_context.open_link(name, like, role)

    def hand_off(self, work: Callable[[], None], what: str) -> None:
        """Have `work` done by the RTPU's background thread, after what was handed off before, and
        return at once: what is slow in `off` or `kill` (a log's last chunk and footer, a helper
        process joined, a file closed) must not hold the cycles of the RTPU's other tasks.

        The thread runs at a lower priority than the RTPU's tasks; the RTPU waits for all it was
        handed before it exits, so nothing is lost. `work` must not touch the task's ports (the
        next cycle may be writing them) and should spend its time waiting (a system call, a join),
        not computing in Python. If it raises, the error is reported as the task's, naming
        `what` ("finishing log x.mcap"); an OutputError fails the run's output, as in a component.
        Outside an RTPU (a task made by hand) the process's own background thread does it."""
        self._pbo_context.hand_off(work, what)

    def fault(self, message: str) -> Status:
        """Return this from `cycle` to report an error with its reason: `return self.fault("...")`."""
        self._pbo_fault = message
        return Status.ERROR

    def open_device(self, name: str) -> Any:
        """Open a device driver object by the device's YAML name (call it in `init`)."""
        return self._pbo_context.open_device(name)

    # --- components (TR §4.3) ---------------------------------------------------------------

    def init(self, params: Any) -> None:
        """On `spawn`, after in-consts are read; allocate here. An exception kills the task."""

    def on(self) -> None:
        """On `on`, after in-vars and out-vars are read: take over the current state."""

    def cycle(self) -> Status:
        """Every period while ON, between the in-var read and the out-var write. Real-time safe."""
        return Status.CONTINUE

    def stable_cycle(self) -> Status:
        """Instead of `cycle`, for a critical task while the configuration is illegal (a switch
        that overran a cycle, a task in ERROR), while an in-var is older than its freshness
        bound (its writer stalled), or when the table lock stayed held past the cycle's wait (its
        in-vars are then the last ones read): keep the plant locally stable (TR 4.4), e.g. a
        robot interface holds position. Real-time safe. By default, the ordinary cycle."""
        return self.cycle()

    def off(self) -> None:
        """On `off`: place final values on the out-vars (written to the table when it returns), flush logs."""

    def kill(self) -> None:
        """On `kill`, or after `init` failed: free what `init` took."""

    def error(self, exc: BaseException | None) -> Status:
        """After an error in any component once init succeeded (on, cycle, off, clear, kill; `exc` None
        for a returned ERROR or outputs not finite). Return CONTINUE if recovered, OFF to stop, ERROR
        to wait for the operator (docs/modules.md: where each verdict leaves the task)."""
        return Status.ERROR

    def tune(self, params: Any) -> None:
        """A TUNABLE parameter changed (`pbo set`): take the new `params`. Runs between two cycles, at
        the cycle boundary the change is applied at; keep it short (copy into preallocated arrays)."""

    def clear(self) -> bool:
        """On the operator's `clear`: True if the fault is gone (task goes OFF), False to stay in ERROR."""
        return True


def build_params(params_type: type, values: dict[str, Any], owner: str) -> Any:
    """Build a frozen dataclass of parameters from YAML values, checking names and types."""
    if not isinstance(values, dict):
        raise ParamError(f"params of {owner} must be a mapping, got: {type(values).__name__}")
    if isinstance(params_type, type):
        fields, required = _fields(params_type), _required(params_type)
    else:
        fields = {f.name: f for f in dataclasses.fields(params_type)}
        required = tuple(
            name for name, f in fields.items() if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        )
    unknown = sorted(set(values) - fields.keys())
    if unknown:
        valid = ", ".join(sorted(fields)) or "none"
        meant = [f"'{close}'" + (f" for '{u}'" if len(unknown) > 1 else "") for u in unknown
                 for close in [closest_name(u, fields)] if close]
        hint = f"; did you mean {', '.join(meant)}?" if meant else ""
        raise ParamError(f"unknown parameter(s) {', '.join(repr(u) for u in unknown)} for {owner}{hint} (valid: {valid})")
    converted: dict[str, Any] = {}
    for name, value in values.items():
        converted[name] = convert_param(params_type, name, value, f"{owner}.{name}")
    missing = [name for name in required if name not in converted]
    if missing:
        raise ParamError(f"missing parameter(s) {', '.join(repr(m) for m in missing)} for {owner}")
    try:
        return params_type(**converted)
    except (TypeError, ValueError) as exc:
        raise ParamError(f"bad parameters for {owner}: {exc}") from None
    except OutOfRange as exc:  # a parameter of something the Params builds (a combined module's member): not one of these
        raise ParamError(f"bad parameters for {owner}: {exc}") from None


def convert_param(params_type: type, name: str, value: Any, where: str) -> Any:
    """One YAML value as field `name` of a Params class takes it, or ParamError saying what it accepts.

    The checker uses it to report each wrong parameter (a plant's option) at its own place; a number
    out of range says which parameter and which element of a list (`OutOfRange.param`, `.index`)."""
    try:
        return _convert(value, _type_hints(params_type).get(name, Any), where, param_ranges(params_type).get(name))
    except OutOfRange as exc:
        exc.param = name
        exc.index = tuple(int(i) for i in re.findall(r"\[(\d+)\]", exc.where[len(where):]))
        raise


def param_fields(params_type: type) -> dict[str, dataclasses.Field[Any]]:
    """The fields of a Params class by name; a field's `metadata["shape"]` (sizes or dim names, as a
    port's) says how long a list it takes: `q0: tuple[float, ...] | None = field(default=None,
    metadata={"shape": ("NDOF",)})`; its `metadata["range"]` (an `objects.ranges.Range`, which
    `objects.ranges.param` writes) which numbers it takes."""
    return dict(_fields(params_type))


@functools.cache
def param_ranges(params_type: type) -> dict[str, Range]:
    """The declared range of each field of a Params class that declares one (`param(..., at_least=0)`)."""
    if not dataclasses.is_dataclass(params_type):
        return {}
    return {name: f.metadata["range"] for name, f in _fields(params_type).items() if isinstance(f.metadata.get("range"), Range)}


@functools.cache
def _fields(params_type: type) -> dict[str, dataclasses.Field[Any]]:
    """The fields of a Params class by name (the same for every task built with it: read, never changed)."""
    return {f.name: f for f in dataclasses.fields(params_type)}


@functools.cache
def _required(params_type: type) -> tuple[str, ...]:
    """The fields of a Params class without a default, in declaration order (found once per class)."""
    return tuple(name for name, f in _fields(params_type).items()
                 if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING)


@functools.cache
def _type_hints(params_type: type) -> dict[str, Any]:
    """The resolved annotations of a Params class (string annotations compile: do it once)."""
    return typing.get_type_hints(params_type)


@functools.cache
def _origin_and_args(hint: Any) -> tuple[Any, tuple[Any, ...]]:
    return typing.get_origin(hint), typing.get_args(hint)


def _convert(value: Any, hint: Any, where: str, allowed: Range | None = None) -> Any:
    """Coerce a YAML scalar or list to the declared type, each number in `allowed` (a float: finite
    at least); say what was expected and found."""
    origin, args = _origin_and_args(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        errors: dict[Any, str] = {}
        for option in args:
            if option is type(None):
                if value is None:
                    return None
                continue
            try:
                return _convert(value, option, where, allowed)
            except OutOfRange:
                raise  # the value is of this kind, only out of range: say so, not every kind the union takes
            except ParamError as exc:
                errors[option] = str(exc)
        # A list whose items are wrong is best told about its items, if only one option takes a list;
        # otherwise say every kind of value the parameter accepts.
        lists = [option for option in errors if _origin_and_args(option)[0] in (tuple, list)]
        if isinstance(value, (list, tuple)) and len(lists) == 1:
            raise ParamError(errors[lists[0]])
        raise ParamError(f"{where} must be {' or '.join(_accepted(option) for option in args)}, got: {value!r}")
    if origin is typing.Literal:
        if value in args:
            return value
        raise ParamError(f"{where} must be one of {', '.join(repr(a) for a in args)}, got: {value!r}")
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ParamError(f"{where} must be true or false, got: {value!r}")
    if hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:  # an integer beyond any float
                number = math.inf if value > 0 else -math.inf
            check_number(number, allowed, where)
            return number
        raise ParamError(f"{where} must be a number, got: {value!r}")
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            if allowed is not None:
                check_number(value, allowed, where)
            return value
        raise ParamError(f"{where} must be an integer, got: {value!r}")
    if hint is str:
        if isinstance(value, str):
            return value
        raise ParamError(f"{where} must be a string, got: {value!r}")
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ParamError(f"{where} must be a list, got: {value!r}")
        item = args[0] if args else Any
        return tuple(_convert(v, item, f"{where}[{i}]", allowed) for i, v in enumerate(value))
    return value


def _accepted(hint: Any) -> str:
    """What a YAML value of type `hint` is, in words: 'a number', 'a list of numbers', 'null'."""
    origin, args = _origin_and_args(hint)
    if hint is type(None):
        return "null"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_accepted(a) for a in args)
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (tuple, list):
        item = _accepted(args[0]) if args and args[0] is not Ellipsis else "value"
        return "a list of " + _PLURAL.get(item, item)
    return _WORDS.get(hint, f"a {getattr(hint, '__name__', hint)}")


_WORDS: dict[Any, str] = {float: "a number", int: "an integer", str: "a string", bool: "true or false", Any: "any value"}
_PLURAL = {
    "a number": "numbers",
    "an integer": "integers",
    "a string": "strings",
    "true or false": "flags",
    "any value": "values",
}
