"""The operator's verbs on a running subsystem: what the supervisor does for each.

The verbs are declared in `supervisor.command_table` (name, arguments, help, reply), each naming
its handler here; the supervisor serves the control queue's requests with `dispatch`
(`ipc.control`). How the operator's terminal prints each reply is `cli.operator`'s.

A handler decides; it reaches the run only through `CommandHost`, which the Supervisor
implements (a fake host in the unit tests, with a manual clock). A handler that says no raises
PboError (or ValueError/KeyError), whose message the operator reads as the refusal; BadRequest
when what was asked is wrong (a name, a value, an argument), not the run's state. Every request
is checked here, whatever sent it: the CLI, or anything else that writes to the control queue.

The status reply (times in seconds, rates in Hz; keys marked ? may be absent or None; a task's
entry is `status_reply.TaskStatusEntry`):

    {"subsystem": str, "run_id": str, "file": str (the subsystem's YAML file, absolute), "configuration": str,
     "job": str?, "application": str?,
     "elapsed": float (since the configuration went on),
     "tasks": [{"task": str, "index": int (its status block in the table), "rtpu": str,
                "state": "NOT_CREATED"|"CREATED"|"OFF"|"ON"|"ERROR"|"KILLED",
                "cycles": int, "rate": float (measured Hz), "overruns": int,
                "jitter_p50": float?, "jitter_p99": float?, "jitter_max": float, "exec_last": float,
                "exec_p50": float?, "exec_p99": float?, "missed": int, "error": str?}, ...]
       (in table index order: tasks[i] is status block i when "index" is absent;
        percentiles are over each task's last 1,024 cycles, 0 until it has run that many),
     "flags": [str] (the table's flags that are set, e.g. "ILLEGAL_CONFIGURATION"),
     "realtime": {rtpu: {what it runs under}}, "stalled": {task: seconds without a cycle}}
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from pbo_runtime.config.checker.loops import GAINS_NOTE
from pbo_runtime.config.decisions import decides
from pbo_runtime.config.values import as_value, describe, element_problem, range_problem
from pbo_runtime.edit.live import LiveChangeRefused, LiveDescription, TaskChange, parse_assignments
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import operator_input
from pbo_runtime.ipc.control import BadRequest
from pbo_runtime.objects import registry
from pbo_runtime.objects.ranges import Range, number_text

# the table, for whoever serves or tests the verbs from here
from pbo_runtime.supervisor.command_table import COMMAND_TIMEOUT as COMMAND_TIMEOUT
from pbo_runtime.supervisor.command_table import COMMANDS as COMMANDS
from pbo_runtime.supervisor.command_table import LIVE_TIMEOUT as LIVE_TIMEOUT
from pbo_runtime.supervisor.command_table import SERVED as SERVED
from pbo_runtime.supervisor.command_table import STATUS_TIMEOUT as STATUS_TIMEOUT
from pbo_runtime.supervisor.command_table import VERBS as VERBS
from pbo_runtime.supervisor.command_table import WHICH_RUN as WHICH_RUN
from pbo_runtime.supervisor.command_table import Argument as Argument
from pbo_runtime.supervisor.command_table import Verb as Verb
from pbo_runtime.supervisor.command_table import parse_job_object as parse_job_object
from pbo_runtime.supervisor.command_table import parse_object_values as parse_object_values
from pbo_runtime.supervisor.command_table import verb_table as verb_table
from pbo_runtime.supervisor.job_control import application_steps
from pbo_runtime.supervisor.status_reply import TaskRow, TaskStatusEntry

if TYPE_CHECKING:
    from pbo_runtime.config.model import Subsystem
    from pbo_runtime.supervisor.job_control import JobControl

MAX_EVENT_VALUES = 256  # an event carries a goal or a setpoint, never bulk data (a request is at most 4 KiB)


class CommandHost(Protocol):
    """What the operator's verbs need of the running subsystem (the Supervisor; a fake in tests)."""

    @property
    def subsystem(self) -> Subsystem: ...
    @property
    def run_id(self) -> str: ...
    @property
    def configuration(self) -> str: ...
    @property
    def application(self) -> str | None: ...
    @property
    def started_at(self) -> float | None: ...
    @property
    def task_states(self) -> Mapping[str, str]: ...
    @property
    def task_errors(self) -> Mapping[str, str]: ...
    @property
    def job_control(self) -> JobControl: ...
    @property
    def realtime(self) -> Mapping[str, Mapping[str, str]]: ...

    def now(self) -> float:
        """The run's time."""
    def status_rows(self) -> list[TaskRow]:
        """Per task, in table index order: its status block's figures."""
    def table_flags(self) -> list[str]:
        """The names of the table's flags that are set."""
    def stalled_since(self) -> Mapping[str, float]:
        """Tasks ON whose cycle has not returned, and since when (run time)."""
    def restarts(self) -> list[dict[str, Any]]:
        """Each RTPU restart so far (supervisor.restarts.Restart.to_json), in the order they died."""
    def signal_task(self, task: str, op: str, states: set[str]) -> str:
        """Send `op` (on, off, clear) to a task and wait until it is in one of `states`; that state."""
    def send_event(self, task: str, values: Any) -> None:
        """Send an event with `values` to an aperiodic task."""
    def request_stop(self, reason: str) -> None:
        """Stop the run cleanly, as soon as the command is answered."""
    @property
    def live(self) -> LiveDescription | None:
        """The description the run lives by (None: live changes are off for this run)."""
    def start_application(self, name: str) -> None:
        """Run application `name` on the live subsystem, as soon as the command is answered."""


Handler = Callable[[CommandHost, dict[str, Any]], dict[str, Any]]


def _numbers(values: Any, what: str) -> list[int | float]:
    """An event's values as the control queue brought them: a flat list of finite numbers."""
    if not isinstance(values, list):
        raise BadRequest(f"{what} must be a list of numbers, got: {describe(values)}")
    if len(values) > MAX_EVENT_VALUES:
        raise BadRequest(f"{what} must be at most {MAX_EVENT_VALUES} numbers, got: {len(values)}")
    for position, value in enumerate(values, 1):
        problem = element_problem(value, "float64")
        if problem:
            raise BadRequest(f"{what}: {problem.replace('float64 elements', 'values')} (value {position})")
    return values


def _name(arguments: dict[str, Any], key: str, what: str, known: Collection[str]) -> str:
    """A name argument that must be text and one of `known` (tasks, jobs, configurations)."""
    value = arguments.get(key)
    listing = ", ".join(known) or "none"
    if not isinstance(value, str):
        raise BadRequest(f"{what} must be named by text, got: {describe(value)} ({what}s: {listing})")
    if value not in known:
        raise BadRequest(f"no {what} '{value}' ({what}s: {listing})")
    return value


# --- the handlers: what the supervisor does for each verb -------------------------------------


def status(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    now = host.now()
    elapsed = now - host.started_at if host.started_at is not None else 0.0
    rows = []
    for row, spec in zip(host.status_rows(), host.subsystem.tasks.values(), strict=True):
        state = host.task_states.get(spec.name, row.state)
        rows.append(TaskStatusEntry(dataclasses.replace(row, state=state), spec.index,
                                    row.cycles / elapsed if elapsed > 0 else 0.0,
                                    host.task_errors.get(spec.name) if host.task_states.get(spec.name) == "ERROR"
                                    else None).to_json())
    return {"subsystem": host.subsystem.name, "run_id": host.run_id, "file": os.path.abspath(host.subsystem.file),
            "configuration": host.configuration,
            "job": host.job_control.job, "application": host.application, "elapsed": elapsed,
            "path": " > ".join(host.job_control.path), "place": list(host.job_control.place),
            "tasks": rows, "flags": host.table_flags(), "realtime": dict(host.realtime),
            "stalled": {name: now - since for name, since in host.stalled_since().items()},
            "restarts": host.restarts(), "gains": gain_notes(host.subsystem.robot_notes)}


def gain_notes(notes: Sequence[str]) -> list[str]:
    """The gains each controller given a bandwidth made from the arm's inertia (the check's notes)."""
    return [note for note in notes if note.startswith(GAINS_NOTE)]


def _task(host: CommandHost, arguments: dict[str, Any]) -> str:
    return _name(arguments, "task", "task", host.subsystem.tasks)


# on: OFF too, when its error component turned it off
_EXPECTED = {"on": {"ON", "ERROR", "OFF"}, "off": {"OFF", "ERROR"}, "clear": {"OFF", "ERROR"}}


def task_signal(command: str) -> Handler:
    """The handler of on, off or clear: checked against the task's state, then sent and awaited."""

    def handle(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
        task = _task(host, arguments)
        before = host.task_states.get(task)
        members = host.subsystem.configurations[host.configuration].tasks
        if command == "on" and task not in members:
            raise PboError(f"task '{task}' is not in the running configuration '{host.configuration}' "
                           f"({', '.join(members)}): turning it on would give its outputs two writers; "
                           f"use pbo switch to a configuration that has it")
        if command == "clear" and before != "ERROR":
            raise PboError(f"task '{task}' is {before}, not in ERROR: there is nothing to clear")
        if command == "on" and before != "OFF":
            raise PboError(f"task '{task}' is {before}: only an OFF task can be turned on")
        if command == "off" and before != "ON":
            raise PboError(f"task '{task}' is {before}: only an ON task can be turned off")
        state = host.signal_task(task, command, _EXPECTED[command])
        note = ""
        if command == "clear":
            note = "cleared: the task is OFF; turn it on with pbo on" if state == "OFF" else \
                f"still in ERROR: its clear component found the fault not fixed ({host.task_errors.get(task, '')})"
        if command == "on" and state == "OFF":
            note = f"its on failed and its error component turned it off ({host.task_errors.get(task, '')})"
        return {"task": task, "state": state, "message": f"task '{task}' is {state}" + (f"; {note}" if note else "")}

    handle.__name__ = command
    return handle


def event(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    task = _task(host, arguments)
    values = arguments.get("values")
    if values is not None:
        values = _numbers(values, f"the values of an event for '{task}'")
    if not host.subsystem.tasks[task].aperiodic:
        aperiodic = [name for name, spec in host.subsystem.tasks.items() if spec.aperiodic]
        raise BadRequest(f"task '{task}' is periodic: it runs on its own timer and takes no events; send events to an "
                         f"aperiodic task ({', '.join(aperiodic) if aperiodic else 'this subsystem has none'})")
    expected = _event_size(host, task)
    if expected is not None and len(values or ()) != expected:
        raise BadRequest(f"task '{task}' takes events of {expected} values "
                         f"({host.subsystem.tasks[task].module}'s EVENT_SHAPE), got {len(values or ())}")
    bounds = _event_range(host, task)
    outside = (next(((position, v) for position, v in enumerate(values or (), 1) if not bounds.admits(v)), None)
               if bounds else None)
    if bounds is not None and outside is not None:
        raise BadRequest(f"the values of an event for '{task}' must be {bounds.text()} "
                         f"({host.subsystem.tasks[task].module}'s EVENT_RANGE), got: {number_text(outside[1])} "
                         f"(value {outside[0]})")
    state = host.task_states.get(task)
    if state != "ON":
        raise PboError(f"task '{task}' is {state}, not ON: an event would not run it; turn it on with pbo on {task}")
    host.send_event(task, values)
    return {"task": task, "message": f"event sent to '{task}'"}


def play(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    devices = host.subsystem.devices
    device = _name(arguments, "device", "device", devices)
    values = _numbers(arguments.get("values") or [], f"the values played into device '{device}'")
    writes = operator_input.play(host.subsystem.name, host.run_id, device, [float(v) for v in values])
    return {"device": device, "writes": writes, "message": f"device '{device}' plays {values}"}


def _event_size(host: CommandHost, task: str) -> int | None:
    """How many values the task's module says an event carries (its EVENT_SHAPE), None if any."""
    spec = host.subsystem.tasks[task]
    try:
        shape = getattr(registry.module_class(spec.module), "EVENT_SHAPE", None)
    except Exception:  # the run found the module at start; a fake host's may not exist
        return None
    if shape is None:
        return None
    dims = host.subsystem.dims
    if any(isinstance(size, str) and size not in dims for size in shape):
        return None  # a dim the subsystem does not define: the module's own cycle judges the count
    return math.prod(dims[size] if isinstance(size, str) else int(size) for size in shape)


def _event_range(host: CommandHost, task: str) -> Range | None:
    """The closed range each value of the task's events must be in (its module's EVENT_RANGE), None if any."""
    try:
        bounds = getattr(registry.module_class(host.subsystem.tasks[task].module), "EVENT_RANGE", None)
    except Exception:  # the run found the module at start; a fake host's may not exist
        return None
    if bounds is None:
        return None
    return Range(float(bounds[0]), float(bounds[1]), low_open=False, high_open=False)


def _no_application(host: CommandHost) -> None:
    if host.application:
        raise PboError(f"application '{host.application}' is running its jobs; switch, job, app and live changes "
                       "are refused until it ends")


def switch(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    _no_application(host)
    record = host.job_control.switch(_name(arguments, "configuration", "configuration", host.subsystem.configurations))
    return {"configuration": record.after, "entered": record.on, "left": record.off, "took": record.latency,
            "message": f"switched '{record.before}' -> '{record.after}' in {record.latency * 1e3:.2f} ms: "
                       f"off {', '.join(record.off) or 'nothing'}; on {', '.join(record.on) or 'nothing'}"}


def job(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    _no_application(host)
    name = _name(arguments, "job", "job", host.subsystem.jobs)
    spec = host.subsystem.jobs[name]
    values: dict[str, Any] = {}
    if arguments.get("object") is not None:
        if not spec.object:
            raise BadRequest(f"job '{name}' takes no object")
        variable = host.subsystem.variables[spec.object]
        given = arguments["object"]
        if isinstance(given, str):  # a named object of the file (`objects:`), as an application's step gives one
            given = _named_object(host, name, spec.object_type, given)
        try:  # the checker's rule for a job's object in a file: numbers of the dtype, finite, all elements
            values[spec.object] = as_value(given, variable.dtype, variable.shape, f"job '{name}': object '{spec.object}'")
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        kind = host.subsystem.object_types.get(spec.object_type or "")
        problem = range_problem(values[spec.object], kind.name, kind.range) if kind is not None else ""
        if problem:
            raise BadRequest(f"job '{name}': object '{spec.object}': {problem}")
    elif spec.object:
        raise BadRequest(f"job '{name}' needs its object '{spec.object}': pbo job {name} VALUE ...")
    host.job_control.start_job(name, values)
    return {"job": name, "configuration": spec.configuration,
            "message": f"job '{name}' runs in '{spec.configuration}'" + (f"; done when {spec.post}" if spec.post else "")}


def _named_object(host: CommandHost, job: str, object_type: str | None, name: str) -> list[Any]:
    """The value of the file's object `name`, if it is of the job's object type."""
    objects = host.subsystem.objects
    fitting = sorted(o.name for o in objects.values() if o.type == object_type)
    found = objects.get(name)
    if found is None:
        raise BadRequest(f"no object '{name}' in the file (objects of type {object_type}: {', '.join(fitting) or 'none'}); "
                         f"give it by name or as numbers: pbo job {job} VALUE ...")
    if found.type != object_type:
        raise BadRequest(f"object '{name}' is of type {found.type}, but job '{job}' takes one of type {object_type} "
                         f"({', '.join(fitting) or 'the file names none'})")
    values: list[Any] = found.value.tolist()
    return values


def stop(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    host.request_stop("pbo stop")
    return {"message": f"stopping '{host.subsystem.name}'"}


# --- live changes (edit.live checks them, job control applies them at a cycle boundary) ------


def _text(arguments: dict[str, Any], key: str, what: str, optional: bool = False) -> str | None:
    value = arguments.get(key)
    if value is None and optional:
        return None
    if not isinstance(value, str) or not value:
        raise BadRequest(f"{what} must be given as text, got: {describe(value)}")
    return value


def _texts(arguments: dict[str, Any], key: str, what: str) -> list[str]:
    values = arguments.get(key) or []
    if not isinstance(values, list) or not all(isinstance(v, str) for v in values):
        raise BadRequest(f"{what} must be a list of texts, got: {describe(values)}")
    return values


def _task_change(arguments: dict[str, Any]) -> TaskChange:
    """What `pbo spawn` and `pbo replace` say of the new task; values stay YAML text, the checker reads them."""
    fields = {key: str(arguments[key]) for key in ("period", "priority", "min_interarrival") if arguments.get(key) is not None}
    for flag in ("critical", "aperiodic"):
        if arguments.get(flag):
            fields[flag] = "true"
    resources = _texts(arguments, "resources", "--resources")
    if resources:
        fields["resources"] = f"[{', '.join(resources)}]"
    try:
        return TaskChange(_text(arguments, "module", "--module", optional=True),
                          _text(arguments, "rtpu", "--rtpu", optional=True), fields,
                          parse_assignments(_texts(arguments, "params", "--param"), "--param"),
                          parse_assignments(_texts(arguments, "ports", "--port"), "--port"))
    except LiveChangeRefused as exc:
        raise BadRequest(str(exc)) from None


def _live(host: CommandHost) -> LiveDescription:
    _no_application(host)
    live = host.live
    if live is None:
        raise PboError(f"live changes are off for this run: {host.subsystem.file} could not be read again when it started")
    return live


def _checked(change: Callable[[], LiveDescription]) -> LiveDescription:
    """The changed description, or the refusal (a BadRequest: the change asked for is wrong), located."""
    try:
        return change()
    except LiveChangeRefused as exc:
        raise BadRequest(str(exc)) from None


def _applied(host: CommandHost, live: LiveDescription, change: str, task: str) -> dict[str, Any]:
    record = host.job_control.apply_live(live, change)
    spec = host.subsystem.tasks.get(task)
    state = host.task_states.get(task, "KILLED")
    where = f" on {spec.rtpu} (status block {spec.index})" if spec is not None else ""
    return {"task": task, "state": state, "configuration": host.configuration,
            "entered": record.on, "left": record.off, "at": record.activation,
            "message": f"{change}: done at the cycle boundary at {record.activation:.3f} s; task '{task}'{where} is {state}"}


def spawn(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    live = _live(host)
    name = _text(arguments, "task", "the task's name")
    assert name is not None
    new = _checked(lambda: live.spawn(name, _task_change(arguments), [host.configuration]))
    return _applied(host, new, f"spawn '{name}'", name)


def kill(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    live = _live(host)
    name = _task(host, arguments)
    new = _checked(lambda: live.kill(name))
    reply = _applied(host, new, f"kill '{name}'", name)
    return {**reply, "message": f"kill '{name}': off at the cycle boundary at {reply['at']:.3f} s, then killed"}


def replace(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    live = _live(host)
    old = _task(host, arguments)
    new_name = _text(arguments, "new", "the new task's name")
    assert new_name is not None
    new = _checked(lambda: live.replace(old, new_name, _task_change(arguments)))
    reply = _applied(host, new, f"replace '{old}' by '{new_name}'", new_name)
    return {**reply, "replaced": old}


def set_parameter(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    live = _live(host)
    name = _task(host, arguments)
    param = _text(arguments, "param", "the parameter's name")
    assert param is not None
    texts = _texts(arguments, "values", "the values")
    new = _checked(lambda: live.set_param(name, param, texts))
    reply = _applied(host, new, f"set '{param}' of '{name}'", name)
    edit = new.edits[-1]
    params = host.subsystem.tasks[name].params
    if edit.member:  # a member's parameter, in the combined task's members
        params = (params["members"][edit.member - 1] or {}).get("params") or {}
    value = params.get(edit.param)
    return {**reply, "param": param, "value": value,
            "message": f"'{param}' of task '{name}' is {value} from the cycle boundary at {reply['at']:.3f} s"}


def app(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    _no_application(host)
    steps = arguments.get("steps")
    if steps is not None:  # an application given with its steps: checked with the whole file, then adopted
        live = _live(host)
        given = _text(arguments, "application", "the application's name")
        assert given is not None
        if not isinstance(steps, (str, list)):
            raise BadRequest(f"the steps must be a list, or YAML text of one, got: {describe(steps)}")
        listed: str | list[Any] = steps
        new = _checked(lambda: live.with_application(given, listed))
        host.job_control.apply_live(new, f"application '{given}'")
    name = _name(arguments, "application", "application", host.subsystem.applications)
    if not host.subsystem.applications[name].complete:
        raise BadRequest(f"application '{name}' is incomplete (a step lacks its object) and cannot run; "
                         f"pbo check {host.subsystem.file} shows which step")
    host.start_application(name)
    steps = [job for job, _ in application_steps(host.subsystem, name)]
    if decides(host.subsystem, name):
        return {"application": name, "jobs": [],
                "message": f"application '{name}' runs its steps, deciding as it goes; pbo status shows where it is"}
    return {"application": name, "jobs": steps,
            "message": f"application '{name}' runs its jobs ({', '.join(steps)}); pbo status shows the current one"}


def save(host: CommandHost, arguments: dict[str, Any]) -> dict[str, Any]:
    live = host.live
    if live is None:
        raise PboError(f"live changes are off for this run: {host.subsystem.file} could not be read again when it started")
    path = _text(arguments, "file", "the file to write")
    assert path is not None
    if not os.path.isabs(path):
        raise BadRequest(f"the file to write must be an absolute path (the supervisor writes it), got: {path!r}")
    if os.path.exists(path) and not arguments.get("force"):
        raise BadRequest(f"{path} exists: give --force to overwrite it")
    from pbo_runtime.edit.live_save import save_live  # (ruamel.yaml: imported by the save, not by every run's start)

    try:
        same = save_live(live, path)
    except LiveChangeRefused as exc:
        raise PboError(str(exc)) from None
    return {"file": path, "edits": len(live.edits),
            "message": f"wrote {path}: the file with {len(live.edits)} live change(s) replayed, comments kept" +
                       ("" if same else "; WARNING: pbo check on it does not give the live subsystem back")}


# --- the handlers by verb ------------------------------------------------------------------

on, off, clear = task_signal("on"), task_signal("off"), task_signal("clear")

# each served verb's handler, by the name the table gives it
HANDLERS: dict[str, Handler] = {verb.name: globals()[verb.handler] for verb in VERBS if verb.handler is not None}


def dispatch(host: CommandHost, command: str, arguments: dict[str, Any]) -> dict[str, Any]:
    """One operator request, as the supervisor serves it from the control queue."""
    verb = COMMANDS.get(command)
    if verb is None or verb.name not in HANDLERS:
        raise BadRequest(f"unknown command '{command}' (commands: {', '.join(SERVED)})")
    takes = [argument.key for argument in verb.arguments if argument.key is not None]
    unknown = [key for key in arguments if key not in takes]
    if unknown:
        raise BadRequest(f"'{command}' takes no argument {', '.join(repr(key) for key in unknown)} "
                         f"(its arguments: {', '.join(takes) or 'none'})")
    return HANDLERS[command](host, arguments)
