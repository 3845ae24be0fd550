"""A task: one spawned instance of a port-based object, and its state machine (TR Figure 11).

    spawn:  in-consts -> init -> out-consts             CREATED -> OFF   (init raises: kill, no task)
    on:     in-vars + out-vars -> on -> out-vars        OFF -> ON
    cycle:  in-vars -> cycle -> out-vars                ON (OFF returned: off)
    off:    off -> out-vars                             ON -> OFF   (its final values reach the table)
    kill:   kill                                        OFF/ERROR -> KILLED
    clear:  clear                                       ERROR -> OFF (True) or ERROR (False)

An error after init (a component raised, returned ERROR, or left an output NaN or Inf) goes to
the `error` component, whichever component it was (TR §4.3); its verdict says where the task
goes. CONTINUE: on as if the component had succeeded (a failed `on` turns the task on, a failed
`cycle` stays on, a failed `off` or `clear` ends OFF); OFF: the task turns off (`off` runs if
the task was on); ERROR, or `error` raising: the task waits in ERROR for the operator's clear.
Outputs that are not finite are never written, whatever the verdict. A `kill` that raises goes
to `error` as well, but the task is killed all the same: kill is not refusable. Only a failed
init keeps the report's other path: kill, and no task.

The executive (rtpu) decides *when*; this class decides *what happens*, so every transition
can be unit-tested with a manual clock and no process.
"""

from __future__ import annotations

import math
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pbo_runtime.config.model import DeviceSpec, TaskSpec
from pbo_runtime.errors import LifecycleError, ModuleError, OutputError
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.objects.module import PortBasedObject, Status
from pbo_runtime.objects.waits import sleep_while_cycling
from pbo_runtime.table.table import Flag, Header, StateTable, StatusWord, TaskState
from pbo_runtime.task.transfer import LocalTable

_FLAGS, _HELD = int(Header.FLAGS), int(Flag.ILLEGAL_CONFIGURATION)
_CYCLES, _RELEASE = int(StatusWord.CYCLES), int(StatusWord.RELEASE)  # a cycle's status words, as plain ints
# What a cycle returns, read once: an enum member read through its class costs a tenth of a microsecond
_CONTINUE, _STABLE, _OFF = Status.CONTINUE, Status.STABLE, Status.OFF
DeviceOpener = Callable[[DeviceSpec, TaskSpec], Any]  # the RTPU's: opens a device for the task whose init asks
Relay = Callable[[str, Any], Any]  # (task, a message link's receiving end) -> something with close()


@dataclass
class RuntimeTaskContext:
    """The runtime's `objects.module.TaskContext` for one task, with what the task keeps of its own:
    the devices and link ends it opened (closed when it is killed), and how it opens them."""

    task_name: str
    period: float
    dims: dict[str, int]
    resources: tuple[str, ...]
    devices: dict[str, DeviceSpec]
    opener: Callable[[DeviceSpec], Any] | None  # the task's own (Task.open_device)
    time: float = 0.0
    event: Any = None
    opened: list[Any] = field(default_factory=list)
    out_dir: str = ""  # the run's output directory: where the run's files go ("" : paths stay as given)
    outputs: list[str] = field(default_factory=list)  # the files `output_path` gave out
    run_metadata: Mapping[str, str] = field(default_factory=dict)  # reports.log_notes.run_metadata
    variable_notes: Mapping[str, tuple[str, str]] = field(default_factory=dict)  # reports.log_notes.variable_notes
    links: dict[str, RunLink] = field(default_factory=dict)  # the application's links, by name
    relay: Relay | None = None  # the RTPU's: wakes this task per message of a link it serves
    restarted: bool = False  # its RTPU was restarted after a death: the run's files it writes are continued
    header_words: Any = None  # the table's header read as plain ints (a memoryview): the flags of `actuators_held`
    table: StateTable | None = None  # for `written_at`
    variable_of: Mapping[str, str] = field(default_factory=dict)  # port name -> the variable it is bound to

    @property
    def actuators_held(self) -> bool:
        """Job control's flag: a stable episode is open (a critical task holds) or a task is in ERROR."""
        words = self.header_words
        return words is not None and bool(words[_FLAGS] & _HELD)

    def open_link(self, name: str, like: np.ndarray, role: str) -> Any:
        """One end of an application's link, carrying items shaped like the array `like`.

        role 'server' (a message link's receiving end): from then on each message releases this
        aperiodic task, its payload in `event`; the end is the relay's to read, not the module's.
        """
        from pbo_runtime.links.ends import open_link_end

        if name not in self.links:
            provided = ", ".join(sorted(self.links)) or "none: this subsystem runs alone"
            raise ModuleError(f"task '{self.task_name}' opens link '{name}', but the application provides no such link "
                              f"(links: {provided}); run the application file that declares it: pbo run APP.yaml")
        if role == "server" and self.relay is None:
            raise ModuleError(f"task '{self.task_name}' serves link '{name}', but no RTPU hosts it to wake it")
        end = open_link_end(name, self.links[name], like, role)
        if role == "server":
            assert self.relay is not None
            try:
                end = self.relay(self.task_name, end)
            except BaseException:
                end.close()
                raise
        self.opened.append(end)
        return end

    def written_at(self, port: str) -> float:
        """When the value of `port`'s variable was written (its writer's release time); -inf if never."""
        if port not in self.variable_of or self.table is None:
            raise ModuleError(f"task '{self.task_name}' has no port '{port}' bound to a variable")
        _, sequence, when, writer = self.table.read(self.variable_of[port])
        return -math.inf if writer < 0 and sequence == 0 else when

    def hand_off(self, work: Callable[[], None], what: str) -> None:
        """Run `work` in the RTPU's background thread (`task.background`), not between two cycles."""
        from pbo_runtime.task.background import process_background

        process_background().hand_off(work, self.task_name, what)

    def open_device(self, name: str) -> Any:
        if name not in self.resources:
            listed = ", ".join(self.resources) or "none"
            raise ModuleError(f"task '{self.task_name}' opens device '{name}', but its resources are: {listed}")
        if self.opener is None:
            raise ModuleError(f"task '{self.task_name}': no devices in this process")
        device = self.opener(self.devices[name])
        self.opened.append(device)
        return device


class Task:
    """A module instance bound to its local table, moved through Figure 11's states."""

    def __init__(
        self,
        spec: TaskSpec,
        module_class: type[PortBasedObject],
        table: StateTable,
        dims: dict[str, int] | None = None,
        devices: dict[str, DeviceSpec] | None = None,
        opener: DeviceOpener | None = None,
        out_dir: str = "",
        links: Mapping[str, RunLink] | None = None,
        relay: Relay | None = None,
        run_metadata: Mapping[str, str] | None = None,
        variable_notes: Mapping[str, tuple[str, str]] | None = None,
        restarted: bool = False,
    ) -> None:
        self.spec = spec
        self.name = spec.name
        self.index = spec.index
        self.state = TaskState.NOT_CREATED
        self.last_error = ""
        self.output_failed = False  # an output it promised (a data log) could not be written: the run answers for it
        self.cycles = 0
        self.errors = 0
        self._device_opener = opener
        self.context = RuntimeTaskContext(spec.name, spec.period, dict(dims or {}), spec.resources, dict(devices or {}),
                                          self.open_device if opener is not None else None,
                                          out_dir=out_dir, links=dict(links or {}), relay=relay,
                                          run_metadata=run_metadata or {}, variable_notes=variable_notes or {},
                                          restarted=restarted, header_words=table.header.data, table=table,
                                          variable_of={b.port.name: b.variable for b in spec.bindings})
        sleep_while_cycling(0)  # in a live spawn, the RTPU's due cycles run between the steps of making a task
        self.local = LocalTable(table, spec.bindings, spec.index, watch_freshness=spec.critical)
        sleep_while_cycling(0)
        self.status = self.local.status
        self._status_words: Any = self.status.data  # the same words: a cycle's stores cost half a numpy array's
        self._forget_an_earlier_tasks_figures(table.status[spec.index])
        self.module = module_class.__new__(module_class)
        self.module._pbo_ports = self.local.port_arrays
        self.module._pbo_context = self.context
        self._params = module_class.build_params(dict(spec.params))
        self.read_inputs = self.local.read_inputs
        self.write_outputs = self.local.write_outputs
        self._outputs_finite = self.local.outputs_finite
        self._cycle = self.module.cycle
        self._stable_cycle = self.module.stable_cycle

    def _forget_an_earlier_tasks_figures(self, shared: Any) -> None:
        """A task spawned live may take the status block of one killed earlier: none of that task's
        counts stay. Its RELEASE stays: it is the write time of what that task wrote last, which
        readers still judge the age of."""
        release = float(shared[StatusWord.RELEASE])
        shared[:] = 0.0
        self.status[:] = 0.0
        shared[StatusWord.RELEASE] = self.status[StatusWord.RELEASE] = release

    # --- signals ----------------------------------------------------------------------------

    def tune_params(self, spec: TaskSpec) -> Any:
        """The module's Params for a live change of `spec` (`pbo set`): built when the change is
        staged, so the cycle boundary only hands them over (`tune`). The spec was checked (`edit.live`)."""
        return type(self.module).build_params(dict(spec.params))

    def tune(self, spec: TaskSpec, params: Any) -> None:
        """A live change of tunable parameters: the module's `tune` gets `params` (`tune_params`),
        between two cycles; a module that refuses raises."""
        if self.state in (TaskState.OFF, TaskState.ON, TaskState.ERROR):
            self.module.tune(params)
        self._params = params
        self.spec = spec

    def spawn(self, now: float) -> bool:
        """Create the task: in-consts, init, out-consts. False (and killed) if init failed."""
        self._expect("spawn", TaskState.NOT_CREATED)
        self.state = TaskState.CREATED
        try:
            type(self.module).__init__(self.module)
            self.local.read_consts()
            self.context.time = now
            self.module.init(self._params)
        except Exception as exc:
            self.last_error = self._describe("init", exc)
            self._run_kill()
            self._publish(TaskState.KILLED)
            return False
        self.state = TaskState.OFF
        self.status[StatusWord.STATE] = TaskState.OFF
        self.status[StatusWord.RELEASE] = now
        self.local.write_consts()
        return True

    def open_device(self, device: DeviceSpec) -> Any:
        """Open `device` for this task, which the device database records as its holder.

        Only in init (TR §4.6.1): a task holds its devices from init until it is killed.
        """
        from pbo_runtime.table.devices import DeviceOpenError

        if self.state != TaskState.CREATED:
            raise DeviceOpenError(f"a device is opened in a task's init (TR §4.6.1); task '{self.name}' opened "
                                  f"'{device.name}' while {self.state.name}")
        assert self._device_opener is not None
        return self._device_opener(device, self.spec)

    def turn_on(self, now: float) -> bool:
        """In-vars and out-vars, on, out-vars. True if the task is ON: `on` succeeded, or it failed
        and the error component recovered (else the task is OFF or ERROR, as `error` said)."""
        self._expect("on", TaskState.OFF)
        self.local.read_for_on()
        self.context.time = now
        try:
            self.module.on()
        except Exception as exc:
            return self._on_failed(now, exc)
        if not self._outputs_finite():
            return self._on_failed(now, None, self._non_finite())
        self._enter_on(now)
        return True

    def _enter_on(self, now: float) -> None:
        self.state = TaskState.ON
        self.status[StatusWord.STATE] = TaskState.ON
        self.status[StatusWord.RELEASE] = now
        self._publish_outputs()

    def _publish_outputs(self) -> None:
        """What `on` or `off` left on the out-vars, and the status block, written at a switch's boundary
        by the cycle's own transfer (the shortest); if its wait for the lock ran out, by the one that
        waits as long as it takes: these values must reach the table."""
        if not self.write_outputs():
            self.local.publish_outputs()

    def _on_failed(self, now: float, exc: BaseException | None, problem: str = "") -> bool:
        verdict = self._error_component("on", exc, problem)
        if verdict == Status.CONTINUE and self._outputs_finite():
            self._enter_on(now)
            return True
        if verdict == Status.CONTINUE:  # recovered, but its outputs still cannot be written
            self.last_error += "; " + self._non_finite()
            verdict = Status.ERROR
        self._publish(TaskState.OFF if verdict == Status.OFF else TaskState.ERROR)
        return False

    def run_cycle(self, now: float, component: Callable[[], Status] | None = None) -> Status:
        """One cycle released at `now`: in-vars, cycle, out-vars; errors go to `error`.

        Only while ON. The outputs' write time and sequence are this release time and cycle
        count, in the status block. The executive reads the in-vars itself and then calls
        `run_read_cycle`, since a read that gave up its wait for the lock (`cycle_lock_wait`)
        changes what the release does; a task stepped here waits for the lock as its table says.
        """
        self.read_inputs()
        return self.run_read_cycle(now, component)

    def run_read_cycle(self, now: float, component: Callable[[], Status] | None = None) -> Status:
        """`run_cycle` once the in-vars were read: the executive reads a critical task's inputs
        first, to choose between `cycle` and `stable_cycle` by how fresh they are."""
        self.context.time = now
        try:
            result: Status | int = (component or self._cycle)()  # a module may return a plain 0
        except Exception as exc:
            return self._cycle_failed(exc, now)
        if not self._outputs_finite():  # NaN or Inf never reaches the table, nor an actuator after it
            return self._cycle_failed(None, now, self._non_finite())
        self.cycles = cycles = self.cycles + 1
        status = self._status_words
        status[_CYCLES] = cycles
        status[_RELEASE] = now
        if result is _CONTINUE or result == 0:
            self.write_outputs()
            return _CONTINUE
        if result is _STABLE:
            self.write_outputs()
            return _STABLE
        if result == _OFF:
            self.write_outputs()
            self.turn_off(now)
            return _OFF
        return self._cycle_failed(None, now)

    def run_stable_cycle(self, now: float) -> Status:
        """One cycle of the locally stable behaviour (critical tasks, configuration illegal)."""
        return self.run_cycle(now, self._stable_cycle)

    def run_read_stable_cycle(self, now: float) -> Status:
        """`run_stable_cycle` once the in-vars were read (they were too old for `cycle`)."""
        return self.run_read_cycle(now, self._stable_cycle)

    def turn_off(self, now: float | None = None) -> None:
        """off, out-vars: ON -> OFF. What `off` leaves on the output ports (the final values that
        keep the system stable while the task does not run, TR §4.3) is written to the table, by
        the transfer a cycle's end uses, stamped `now` (default: the last release)."""
        self._expect("off", TaskState.ON)
        if now is not None:
            self.context.time = now
        try:
            self.module.off()
        except Exception as exc:
            self._off_failed(now, exc)
            return
        if not self._outputs_finite():
            self._off_failed(now, None, self._non_finite())
            return
        self._leave_on(now)

    def _leave_on(self, now: float | None) -> None:
        """OFF, with the final values of the out-vars and the status block in one write."""
        self.state = TaskState.OFF
        self.status[StatusWord.STATE] = TaskState.OFF
        if now is not None:
            self.status[StatusWord.RELEASE] = now
        self._publish_outputs()

    def _off_failed(self, now: float | None, exc: BaseException | None, problem: str = "") -> None:
        """`off` failed: the task is stopping either way; `error` says whether it stops OFF or in ERROR."""
        verdict = self._error_component("off", exc, problem)
        if verdict != Status.ERROR and self._outputs_finite():
            self._leave_on(now)
        else:
            self._publish(TaskState.OFF if verdict != Status.ERROR else TaskState.ERROR)

    def kill(self, now: float | None = None) -> None:
        """Free the task. From ON it is turned off first, as job control would."""
        if self.state == TaskState.ON:
            self.turn_off(now)
        self._expect("kill", TaskState.OFF, TaskState.ERROR, TaskState.CREATED)
        self._run_kill(after_init=True)
        self._publish(TaskState.KILLED)

    def clear(self) -> bool:
        """The operator's clear: True if the task went back to OFF. If `clear` raises, the error
        component decides (CONTINUE or OFF: OFF; ERROR: the task stays in ERROR)."""
        self._expect("clear", TaskState.ERROR)
        try:
            cleared = bool(self.module.clear())
        except Exception as exc:
            cleared = self._error_component("clear", exc) != Status.ERROR
            if not cleared:
                return False
        if cleared:
            self.last_error = ""
            self._publish(TaskState.OFF)
        return cleared

    # --- helpers ----------------------------------------------------------------------------

    def _non_finite(self) -> str:
        names = self.local.non_finite_outputs()
        return (f"out-var{'s' if len(names) > 1 else ''} {', '.join(repr(n) for n in names)} not finite (NaN or Inf); "
                "not written to the table")

    def _cycle_failed(self, exc: BaseException | None, now: float, problem: str = "") -> Status:
        """The cycle raised, returned ERROR, or (`problem`) left outputs that must not be written."""
        reason = self.module.__dict__.pop("_pbo_fault", "")
        if not problem and exc is None:
            problem = "returned ERROR" + (f": {reason}" if reason else "")
        verdict = self._error_component("cycle", exc, problem)
        if verdict == Status.CONTINUE:
            return Status.CONTINUE
        if verdict == Status.OFF:
            self.turn_off(now)
            return Status.OFF
        self._publish(TaskState.ERROR)
        return Status.ERROR

    def _error_component(self, component: str, exc: BaseException | None, problem: str = "") -> Status:
        """Count the error, describe it, and ask the module's `error` what to do (TR §4.3): its
        verdict, or ERROR if it raised or answered something else."""
        self.errors += 1
        self.status[StatusWord.ERRORS] = self.errors
        if exc is not None:
            self.last_error = self._describe(component, exc)
        else:
            self.last_error = f"{component} {problem}" if problem.startswith("returned") else f"{component}: {problem}"
        try:
            verdict = self.module.error(exc)
        except Exception as inner:
            self.last_error += "; " + self._describe("error", inner)
            return Status.ERROR
        if verdict == Status.CONTINUE or verdict == Status.OFF:
            return Status(verdict)
        return Status.ERROR

    def _run_kill(self, after_init: bool = False) -> None:
        """kill, then close what the task opened (what `closes_slowly`, a message link's relay, and the rest
        of a driver's `close_now`, in the RTPU's background thread). After init, a kill that raises goes to
        the error component too (for the record: the task is killed whatever it answers)."""
        try:
            self.module.kill()
        except Exception as exc:
            if after_init:
                before = self.last_error
                self._error_component("kill", exc)
                self.last_error = (before + "; " if before else "") + self.last_error
            else:
                self.last_error += ("; " if self.last_error else "") + self._describe("kill", exc)
        for device in self.context.opened:
            what = f"closing the {type(device).__name__} of task '{self.name}'"
            if getattr(device, "closes_slowly", False):  # it joins a thread or waits for a process: not between cycles
                self.context.hand_off(device.close, what)
                continue
            try:
                close_now = getattr(device, "close_now", None)  # a driver: what waits is the rest it returns
                if close_now is None:
                    device.close()
                    continue
                rest = close_now()
                if rest is not None:
                    self.context.hand_off(rest, what)
            except Exception as exc:
                self.last_error += ("; " if self.last_error else "") + self._describe("device close", exc)
        self.context.opened.clear()

    def _describe(self, component: str, exc: BaseException) -> str:
        """The error's one-line description; notes an output that could not be written."""
        if isinstance(exc, OutputError):
            self.output_failed = True
        return _describe(component, exc)

    def _publish(self, state: TaskState) -> None:
        self.state = state
        self.status[StatusWord.STATE] = state
        self.local.write_status()

    def _expect(self, signal: str, *allowed: TaskState) -> None:
        if self.state not in allowed:
            names = " or ".join(s.name for s in allowed)
            raise LifecycleError(f"task '{self.name}' cannot take '{signal}' in state {self.state.name} (needs {names})")


def _describe(component: str, exc: BaseException) -> str:
    frame = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    where = f" at {frame.filename.rsplit('/', 1)[-1]}:{frame.lineno}" if frame else ""
    return f"{component} raised {type(exc).__name__}: {exc}{where}"
