"""Job control: starts a subsystem, sequences its tasks, watches it, and always cleans up.

`Supervisor.run` creates the table and queues, starts the plant and the RTPU processes,
spawns every task in const-dependency order (waiting for each `init`), turns the
configuration on, watches until the duration ends, Ctrl-C, or a failure, and then turns
everything off, kills the tasks, stops the children and unlinks every object it made,
whatever happened. A start first removes what a dead run of the same subsystem left.

The run's clock is a parameter (`clock.run_clock`): real time, or with `clock="sim"` the
simulated clock, whose master the supervisor then is: time is the tick count, advanced only by
`pump`, and the plant and the RTPUs run each tick in turn (`clock.lockstep`), so a run replays
bit for bit. Times that belong to the run (durations, job timeouts, switch times) are read
through `now()`, on either clock; waits for processes (start-up, a signal's answer) stay on
wall time, since a process that hangs must be caught whatever the clock.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import posix_ipc

from pbo_runtime.ipc import messages
from pbo_runtime.ipc import shm
from pbo_runtime.config.model import Subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import ControlServer, control_queue_name
from pbo_runtime.supervisor.job_control import JobControl, JobFailure, application_steps
from pbo_runtime.supervisor.commands import dispatch
from pbo_runtime.clock.run_clock import RealRunClock, RunClock, SimRunClock
from pbo_runtime.config.reconfiguration import Reconfiguration
from pbo_runtime.supervisor.stall_watch import StallWatch
from pbo_runtime.table.table import Flag, Header, StateTable, TableLayout, TaskState, read_manifest
from pbo_runtime.table.table import Status as W

START_TIMEOUT = 60.0  # seconds for a child to import numpy, pinocchio and mujoco on a busy machine
SIGNAL_TIMEOUT = 10.0
SIM_STALL_SECONDS = 2.0  # wall seconds one participant may take over one tick of the simulated clock before it is reported
STOP_TIMEOUT = 5.0  # seconds an RTPU has to stop by itself before it is signalled (and then again before SIGKILL)
STALL_CHECK_EVERY = 0.05  # seconds between looks at the cycle counts (StallWatch); job control pumps every 2 ms


def _table_figures(words: np.ndarray) -> dict[str, float]:
    """A task's counters from its status block: what the live view shows, and what a run report
    gives for a task whose RTPU was killed before it could report. The percentiles are over the
    last 1,024 cycles, published by the executive every 1,024 cycles (0 before)."""
    return {"cycles": int(words[W.CYCLES]), "overruns": int(words[W.OVERRUNS]), "missed": int(words[W.MISSED]),
            "jitter_max": float(words[W.JITTER_MAX]), "jitter_p50": float(words[W.JITTER_P50]),
            "jitter_p99": float(words[W.JITTER_P99]), "exec_p50": float(words[W.EXEC_P50]),
            "exec_p99": float(words[W.EXEC_P99])}


class RunFailure(PboError):
    """The run could not start or had to stop: the message says which process or task, and why."""


class StopRequested(Exception):
    """Ctrl-C, SIGTERM or `pbo stop` while job control was waiting: stop cleanly, not a failure."""


@dataclass
class RunResult:
    """What a run did: the summary's data and the JSON report's content."""

    subsystem: str
    configuration: str
    duration: float = 0.0
    stopped_by: str = "duration"
    failure: str = ""
    tasks: dict[str, dict[str, Any]] = field(default_factory=dict)
    variables: dict[str, Any] = field(default_factory=dict)
    plant: dict[str, Any] = field(default_factory=dict)
    lock_recoveries: int = 0
    run_id: str = ""
    objects: list[str] = field(default_factory=list)  # every shared object the run made ("kind /name")
    states_at_stop: dict[str, str] = field(default_factory=dict)
    application: str = ""
    jobs_done: list[str] = field(default_factory=list)
    switches: list[dict[str, Any]] = field(default_factory=list)
    stable_episodes: list[dict[str, Any]] = field(default_factory=list)
    realtime: dict[str, dict[str, str]] = field(default_factory=dict)  # per RTPU: cpu, scheduler, timer slack
    clock: str = "real"
    tick: float = 0.0  # seconds per tick of the simulated clock
    wall_seconds: float = 0.0  # how long the run took on the wall clock (a sim run's speed: duration / this)
    links: dict[str, dict[str, Any]] = field(default_factory=dict)  # an application's links this run was handed
    # CLOCK_MONOTONIC second the configuration came on (real clock; 0 on the simulated one): the
    # origin of each task's last_overruns times, to match them with a trace of the machine (tools/cpu_trace.py)
    started_monotonic: float = 0.0
    # tasks ON that finished no cycle for a while: task, rtpu, from and to (seconds since the
    # configuration came on; to None: until the stop), rtpu_killed (its RTPU did not stop by itself)
    stalls: list[dict[str, Any]] = field(default_factory=list)
    unstopped: list[str] = field(default_factory=list)  # RTPUs that did not stop within STOP_TIMEOUT and were killed

    def to_json(self) -> dict[str, Any]:
        return {
            "subsystem": self.subsystem, "configuration": self.configuration, "duration": self.duration,
            "stopped_by": self.stopped_by, "failure": self.failure, "tasks": self.tasks,
            "variables": self.variables, "plant": self.plant, "lock_recoveries": self.lock_recoveries,
            "run_id": self.run_id, "objects": self.objects, "states_at_stop": self.states_at_stop,
            "application": self.application, "jobs_done": self.jobs_done, "switches": self.switches,
            "stable_episodes": self.stable_episodes, "realtime": self.realtime,
            "clock": self.clock, "tick": self.tick, "wall_seconds": self.wall_seconds, "links": self.links,
            "started_monotonic": self.started_monotonic, "stalls": self.stalls, "unstopped": self.unstopped,
        }


@dataclass
class _Child:
    role: str  # 'plant' or the RTPU's name
    process: subprocess.Popen
    tasks: tuple[str, ...] = ()


def remove_dead_runs(subsystem: str) -> list[str]:
    """Unlink what crashed runs of this subsystem left, their queues included (via the manifest)."""
    removed: list[str] = []
    for kind, name in shm.stale_objects(subsystem):
        if kind == "shm" and name.endswith(".table"):
            try:
                mapping = shm.attach_segment(name)
                header = np.frombuffer(mapping, dtype=np.int64, count=16)
                offset = int(header[Header.MANIFEST_OFFSET])
                del header
                entries = read_manifest(mapping, offset) if offset > 0 else []
                mapping.close()
            except (posix_ipc.Error, OSError, ValueError, BufferError):
                entries = []
            for entry in entries:
                entry_kind, _, entry_name = entry.partition(" ")
                if entry_kind in ("shm", "sem", "mq") and shm.unlink_quietly(entry_kind, entry_name):
                    removed.append(entry_name)
        if shm.unlink_quietly(kind, name):
            removed.append(name)
    return sorted(set(removed))


class Supervisor:
    """Runs one subsystem: a configuration for a duration, or an application's jobs."""

    def __init__(
        self,
        subsystem: Subsystem,
        configuration: str | None = None,
        duration: float | None = 5.0,
        on_tick: Callable[[Supervisor], None] | None = None,
        say: Callable[[str], None] = lambda text: None,
        application: str | None = None,
        static: bool = False,
        alternate: tuple[list[str], int, float] | None = None,
        fifo: bool | None = None,
        clock: str = "real",
        out_dir: str | None = None,
        links: dict[str, dict[str, Any]] | None = None,
    ) -> None:
        self.subsystem = subsystem
        if clock not in ("real", "sim"):
            raise RunFailure(f"unknown clock '{clock}': use real or sim")
        self.clock: RunClock = SimRunClock(simulation_tick(subsystem)) if clock == "sim" else RealRunClock()
        self.out_dir = os.path.abspath(out_dir) if out_dir else ""
        self.links = dict(links or {})  # an application's links, handed to every RTPU (see _links)
        self.application = application
        if application is not None and application not in subsystem.applications:
            raise RunFailure(f"no application '{application}' in {subsystem.file} "
                             f"(applications: {', '.join(subsystem.applications) or 'none'})")
        if application is not None and not subsystem.applications[application].complete:
            raise RunFailure(f"application '{application}' is incomplete (a step lacks the object its job needs) and "
                             f"cannot be run; pbo check {subsystem.file} shows which step")
        if configuration is None and application is not None:
            first = application_steps(subsystem, application)
            configuration = subsystem.jobs[first[0][0]].configuration if first else None
        self.configuration = configuration or next(iter(subsystem.configurations))
        if self.configuration not in subsystem.configurations:
            raise RunFailure(
                f"no configuration '{self.configuration}' in {subsystem.file} "
                f"(configurations: {', '.join(subsystem.configurations)})"
            )
        self.duration = duration
        self.on_tick = on_tick
        self.say = say
        self.run_id = shm.new_run_id()
        self.table: StateTable | None = None
        self.events: messages.Queue | None = None
        self.signals: dict[str, messages.Queue] = {}
        self.children: list[_Child] = []
        self.task_states: dict[str, str] = {t: TaskState.NOT_CREATED.name for t in subsystem.tasks}
        self.task_errors: dict[str, str] = {}
        self.result = RunResult(subsystem.name, self.configuration, run_id=self.run_id)
        self.result.objects = self._manifest()
        self.result.links = self.links
        self.started_at: float | None = None  # run time when the configuration came on
        self._stop_requested = ""
        self._stats: dict[str, dict[str, Any]] = {}
        self.stall_watch = StallWatch(subsystem.tasks.values(), self._cycles_of, say)
        self._stalls_checked = -math.inf
        self.reconfiguration = Reconfiguration(subsystem)
        # RTPUs release at epoch + index * stagger + k * period, evenly over the shortest period
        # on the real clock (clocks.release_stagger says why).
        self.shortest_period = min(t.period for t in subsystem.tasks.values())
        self.stagger = self.clock.stagger(self.shortest_period, len(subsystem.rtpus))
        self.epoch = 0.0
        self.tick = self.clock.tick
        self.result.clock = clock
        self.result.tick = self.tick
        self.static = static
        self.job_control = JobControl(self, static=static)
        self.result.application = application or ""
        self.alternate = alternate
        # SCHED_FIFO where the OS allows it, on the real clock unless asked otherwise: under SCHED_OTHER
        # the machine's own threads take a CPU for milliseconds and RTPUs overrun several times as
        # often (8 to 14 in docs/performance.md). The simulated clock waits on ticks: it needs none.
        self.fifo = self.clock.fifo_by_default if fifo is None else fifo
        self._stable: dict[str, float] = {}
        self.control: ControlServer | None = None
        self._serving = False
        self._refused: dict[str, str] = {}  # task -> why its RTPU refused the last signal

    # --- names ------------------------------------------------------------------------------

    def _manifest(self) -> list[str]:
        s, r = self.subsystem.name, self.run_id
        table = messages.table_name(s, r)
        entries = [f"shm {table}", f"sem {table}.lock", f"mq {messages.event_queue_name(s, r)}"]
        entries += [f"mq {messages.signal_queue_name(s, r, rtpu.name)}" for rtpu in self.subsystem.rtpus]
        if self.subsystem.plant is not None:
            entries.append(f"shm {messages.plant_registers_name(s, r)}")
        entries.append(f"mq {control_queue_name(s, r)}")
        entries += [f"sem {name}" for name in self.clock.semaphores(s, r, self._roles())]
        return entries

    def _roles(self) -> list[str]:
        """The children, in the order the simulated clock steps them: the plant first, then the RTPUs."""
        return (["plant"] if self.subsystem.plant is not None else []) + [rtpu.name for rtpu in self.subsystem.rtpus]

    def now(self) -> float:
        """The run's time: CLOCK_MONOTONIC, or the simulated clock's last tick."""
        return self.clock.now()

    # --- the run ----------------------------------------------------------------------------

    def run(self) -> RunResult:
        wall_start = time.monotonic()
        previous = signal.signal(signal.SIGINT, self._interrupt)
        previous_term = signal.signal(signal.SIGTERM, self._interrupt)
        try:
            removed = remove_dead_runs(self.subsystem.name)
            if removed:
                self.say(f"removed {len(removed)} object(s) left by a dead run: {', '.join(removed)}")
            self._start()
            if self.application:
                self.job_control.run_application(self.application)
                self.result.jobs_done = [job for job, _ in application_steps(self.subsystem, self.application)]
                self.result.stopped_by = f"application '{self.application}' done"
                self.say(f"application '{self.application}' is done")
            elif self.alternate:
                self.job_control.alternate(*self.alternate)
                self.result.stopped_by = f"{self.alternate[1]} switches done"
            else:
                self._watch()
        except StopRequested:
            self.result.stopped_by = self._stop_requested
        except (RunFailure, JobFailure) as exc:
            self.result.failure = str(exc)
            self.result.stopped_by = "failure"
        except PboError as exc:  # a switch that could not complete, a condition that could not be read
            self.result.failure = str(exc)
            self.result.stopped_by = "failure"
        finally:
            self._shutdown()
            signal.signal(signal.SIGINT, previous)
            signal.signal(signal.SIGTERM, previous_term)
            self.result.wall_seconds = time.monotonic() - wall_start
        return self.result

    def request_stop(self, reason: str) -> None:
        self._stop_requested = reason

    def _interrupt(self, signum: int, _frame: Any) -> None:
        self._stop_requested = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"

    def _start(self) -> None:
        sub, run_id = self.subsystem, self.run_id
        self.events = messages.Queue(messages.event_queue_name(sub.name, run_id), create=True)
        for rtpu in sub.rtpus:
            self.signals[rtpu.name] = messages.Queue(messages.signal_queue_name(sub.name, run_id, rtpu.name), create=True)
        self.table = StateTable.create(TableLayout.of(sub), messages.table_name(sub.name, run_id), self._manifest())
        self.control = ControlServer(sub.name, run_id)
        epoch = self.epoch = self.clock.start(sub.name, run_id, self._roles(), self.table.header)
        self._write_initial_values()
        if sub.plant is not None:
            plant = sub.plant
            self._launch("plant", [
                "-m", "pbo_runtime.supervisor.plant_host", "--type", plant.type, "--model", plant.model,
                "--timestep", repr(plant.timestep), "--options", json.dumps(dict(plant.options)),
                "--subsystem", sub.name, "--run-id", run_id, *(["--fifo"] if self.fifo else []), *self.clock.plant_arguments(),
            ])
            self._await_ready({"plant"})
        for rtpu in sub.rtpus:
            hosted = tuple(t.name for t in sub.tasks_on(rtpu.name))
            self._launch(rtpu.name, ["-m", "rtpu", sub.file, "--run-id", run_id, "--rtpu", rtpu.name,
                                     "--epoch", repr(epoch + self.stagger * rtpu.index), "--spin", repr(rtpu.spin),
                                     *(["--fifo"] if self.fifo else []),
                                     *self.clock.rtpu_arguments(),
                                     *(["--out", self.out_dir] if self.out_dir else []),
                                     *(["--links", json.dumps(self.links)] if self.links else [])],
                         hosted)
        self._await_ready({r.name for r in sub.rtpus})
        members = sub.configurations[self.configuration].tasks
        # dynamic: the union every configuration may need is spawned now (TR 4.4); static: this one's
        spawned = [t for t in sub.init_order if t in members or not self.static]
        for name in spawned:
            self.respawn(name)
        ordered = [t for t in sub.init_order if t in members]
        ordered.sort(key=lambda t: not sub.tasks[t].critical)  # the robot interface first: it publishes q_m
        for name in ordered:
            self.turn_on(name, self.configuration)
        self._publish_plan_state()
        self.started_at = self.now()
        if self.clock.on_monotonic:
            self.result.started_monotonic = self.started_at
        self.say(f"configuration '{self.configuration}' is on: {', '.join(ordered)}")

    def respawn(self, name: str) -> None:
        """Spawn a task and wait for its init; an init failure stops the run (no half start)."""
        state = self.signal_and_wait(name, "spawn", {"OFF", "KILLED"})
        if state == "KILLED":
            raise RunFailure(f"task '{name}' failed in init and was not created: {self.task_errors.get(name, '')}")

    def turn_on(self, name: str, configuration: str) -> None:
        """Turn a task on; critical tasks learn who writes their inputs in `configuration`."""
        index = self.reconfiguration.index(configuration)
        state = self.signal_and_wait(name, "on", {"ON", "ERROR"}, None, index)
        if state == "ERROR":
            raise RunFailure(f"task '{name}' failed in on: {self.task_errors.get(name, '')}")

    def _await_change(self, task: str, before: str | None, states: set[str]) -> str:
        """The task's state after a signal: one of `states`; a clear that fails reports ERROR again."""
        if self.clock.signals_served_when_sent:
            return self._served_state(task, states, PboError)
        deadline = time.monotonic() + SIGNAL_TIMEOUT
        while True:
            _, event = self._next_event(deadline, f"waiting for task '{task}'")
            if isinstance(event, messages.Refused) and event.task == task:
                raise PboError(f"task '{task}': {event.reason}")
            if isinstance(event, messages.StateChanged) and event.task == task and self.task_states[task] in states:
                return self.task_states[task]

    def kill_task(self, name: str) -> None:
        self.signal_and_wait(name, "kill", {"KILLED"})

    def read_variable(self, name: str) -> np.ndarray:
        assert self.table is not None
        return self.table.read(name)[0]

    def write_variable(self, name: str, value: Any) -> None:
        assert self.table is not None
        self.table.write(name, value, when=self.now(), writer=-1)

    def post_plan(self, configuration: str, activation: float) -> int:
        """Post a switch plan in the table's header and wake the RTPUs; the plan's sequence number."""
        assert self.table is not None
        header = self.table.header
        sequence = int(header[Header.PLAN_SEQUENCE]) + 1
        header[Header.PLAN_CONFIGURATION] = self.reconfiguration.index(configuration)
        header[Header.PLAN_TIME_NS] = int(activation * 1e9)
        header[Header.PLAN_SEQUENCE] = sequence  # last: an executive that sees it sees the whole plan
        if self.clock.plans_need_a_wakeup:
            for queue in self.signals.values():
                queue.try_send("plan", timeout=0.0)
        return sequence

    def signal_and_wait(self, name: str, op: str, states: set[str], *arguments: Any) -> str:
        self._signal(name, op, *arguments)
        return self._await_state(name, states)

    def set_configuration(self, configuration: str) -> None:
        self.configuration = configuration
        self.result.configuration = configuration
        self._count_errors()

    def _publish_plan_state(self) -> None:
        """Mark the starting configuration as applied, so executives start in step with job control."""
        assert self.table is not None
        self.table.header[Header.PLAN_CONFIGURATION] = self.reconfiguration.index(self.configuration)

    def _count_errors(self) -> None:
        """Critical tasks run locally stable while a task of the configuration is in ERROR."""
        if self.table is None:
            return
        members = self.subsystem.configurations[self.configuration].tasks
        in_error = sum(1 for t in members if self.task_states.get(t) == "ERROR")
        self.table.header[Header.TASKS_IN_ERROR] = in_error
        self.table.set_flag(Flag.ILLEGAL_CONFIGURATION, bool(in_error) or bool(self._stable))

    def _launch(self, role: str, arguments: list[str], tasks: tuple[str, ...] = ()) -> None:
        command = [sys.executable, *arguments, "--parent", str(os.getpid())]
        process = subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True,
                                   env=self.clock.child_environment())
        self.children.append(_Child(role, process, tasks))

    def _write_initial_values(self) -> None:
        assert self.table is not None
        for var in self.subsystem.variables.values():
            initial = var.initial
            if initial is not None:
                self.table.write(var.name, initial, when=self.now(), writer=-1)

    # --- waiting for the children -----------------------------------------------------------

    def _signal(self, task: str, *message: Any) -> None:
        rtpu = self.subsystem.tasks[task].rtpu
        self._refused.pop(task, None)
        self.signals[rtpu].send(message[0], task, *message[1:], timeout=SIGNAL_TIMEOUT)
        self.clock.serve(rtpu, self._while_stepping)

    def _while_stepping(self) -> None:
        """While a participant runs its tick: fail if a child died, stop if asked, keep the event queue
        drained, and say so once if the tick takes seconds (a cycle there has not returned)."""
        self._check_children()
        if self._stop_requested:
            raise StopRequested(self._stop_requested)  # a tick that never ends must not hold Ctrl-C
        assert self.events is not None
        while (received := self.events.receive_event(0)) is not None:
            self._absorb(*received)
        slow = self.clock.slow_participant(SIM_STALL_SECONDS)
        if slow is not None:
            stepping, at, waited = slow
            self.say(f"{stepping} has not finished the tick at {at:.3f} s for {waited:.1f} s of wall "
                     "time: a cycle there has not returned (Ctrl-C stops the run)")

    def _await_ready(self, roles: set[str]) -> None:
        waiting = set(roles)
        deadline = time.monotonic() + START_TIMEOUT
        while waiting:
            source, event = self._next_event(deadline, f"waiting for {', '.join(sorted(waiting))} to start")
            if isinstance(event, messages.Ready):
                waiting.discard(source)
                if isinstance(event.realtime, dict):
                    self.result.realtime[source] = event.realtime

    def _served_state(self, task: str, states: set[str], failure: type[PboError]) -> str:
        """Sim clock: the signal was served in full when `_signal` returned; its events are all queued."""
        self._while_stepping()
        if task in self._refused:
            raise failure(f"task '{task}': {self._refused[task]}")
        state = self.task_states[task]
        if state not in states:
            raise failure(f"task '{task}' is {state} after the signal, not {' or '.join(sorted(states))}")
        return state

    def _await_state(self, task: str, states: set[str]) -> str:
        if self.clock.signals_served_when_sent:
            return self._served_state(task, states, RunFailure)
        deadline = time.monotonic() + SIGNAL_TIMEOUT
        while True:
            self._next_event(deadline, f"waiting for task '{task}' to reach {' or '.join(sorted(states))}")
            if self.task_states[task] in states:
                return self.task_states[task]

    def _next_event(self, deadline: float, doing: str) -> tuple[str, messages.Event]:
        assert self.events is not None
        while True:
            self._check_children()
            if self._stop_requested:
                raise RunFailure(f"stopped by {self._stop_requested} while {doing}")
            received = self.events.receive_event(0.05)
            if received is not None:
                self._absorb(*received)
                return received
            if time.monotonic() > deadline:
                raise RunFailure(f"timed out {doing}")

    def _absorb(self, source: str, event: messages.Event) -> None:
        if isinstance(event, messages.StateChanged):
            task, state, message = event.task, event.state, event.error
            previous = self.task_states.get(task)
            self.task_states[task] = state
            if message:
                self.task_errors[task] = message
            if state == "ERROR" and previous != "ERROR":
                self.say(f"task '{task}' on {source} is in ERROR: {message} (operator intervention required: pbo clear {task})")
            if (state == "ERROR") != (previous == "ERROR"):
                self._count_errors()
        elif isinstance(event, messages.Switched):
            self.job_control.switched(source, event.sequence, event.applied_at, event.done_at, event.off, event.on)
        elif isinstance(event, messages.Window):
            self.job_control.window(event.sequence, event.task, event.lost, event.stale)
        elif isinstance(event, messages.FirstCycle):
            self.job_control.first_cycle(event.sequence, event.task, event.at)
        elif isinstance(event, messages.Stable):
            task, at = event.task, event.at
            if event.entering:
                self._stable[task] = at
                self.say(f"configuration illegal: critical task '{task}' runs its locally stable behaviour")
            elif task in self._stable:
                began = self._stable.pop(task)
                self.result.stable_episodes.append({"task": task, "from": began, "to": at, "seconds": at - began})
                self.say(f"critical task '{task}' is back to its cycle after {(at - began) * 1e3:.1f} ms")
            self._count_errors()
        elif isinstance(event, messages.Stats):
            self._stats.update(event.tasks)
        elif isinstance(event, messages.PlantStats):
            self.result.plant = event.figures
        elif isinstance(event, messages.Refused):
            self._refused[event.task] = event.reason
            self.say(f"{source} refused a signal for '{event.task}': {event.reason}")
        elif isinstance(event, messages.Crashed):
            raise RunFailure(f"{source} crashed: {event.error}\n{event.trace}")

    def _check_children(self) -> None:
        for child in self.children:
            code = child.process.poll()
            if code is not None:
                self._recover_lock_from(child.process.pid)
                how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
                hosted = f" while hosting tasks: {', '.join(child.tasks)}" if child.tasks else ""
                what = "the plant" if child.role == "plant" else f"RTPU '{child.role}'"
                raise RunFailure(f"{what} (pid {child.process.pid}) died ({how}){hosted}")

    def _recover_lock_from(self, pid: int) -> None:
        """A process that died holding the table lock must not wedge the others (DESIGN §4)."""
        if self.table is not None and self.table.recover_lock_from(pid):
            self.result.lock_recoveries += 1
            self.say(f"released the table lock held by dead process {pid}")

    # --- running ----------------------------------------------------------------------------

    def _watch(self) -> None:
        """Serve events and commands until the duration is over (StopRequested ends it sooner)."""
        assert self.started_at is not None
        while self.duration is None or self.now() - self.started_at < self.duration - self.tick / 2:
            left = self.duration - (self.now() - self.started_at) if self.duration is not None else 0.1
            self.pump(min(0.1, left))
        self.result.stopped_by = "duration"

    def pump(self, timeout: float) -> None:
        """One turn of job control's loop: children, stop requests, events, commands, the view.

        On the real clock it waits up to `timeout` for one event; on the simulated clock it runs
        the ticks that cover `timeout` (at least one), taking every event after each.
        """
        assert self.events is not None
        self._check_children()
        if self._stop_requested:
            raise StopRequested(self._stop_requested)
        self._check_stalls()
        self.clock.run_for(timeout, self._take_one_event, self._while_stepping)
        self._serve_commands()
        if self.on_tick is not None:
            self.on_tick(self)

    def _take_one_event(self, timeout: float) -> None:
        assert self.events is not None
        received = self.events.receive_event(timeout)
        if received is not None:
            self._absorb(*received)

    def _cycles_of(self, index: int) -> float:
        assert self.table is not None
        return float(self.table.status[index][W.CYCLES])

    def _check_stalls(self) -> None:
        """Real clock: a task ON whose cycle count stops moving is reported (see _stall_watch)."""
        if not self.clock.watches_stalls or self.started_at is None or self.table is None:
            return
        now = self.now()
        if now - self._stalls_checked >= STALL_CHECK_EVERY:
            self._stalls_checked = now
            self.stall_watch.check(now, self.task_states)

    def _serve_commands(self) -> None:
        """Operator commands (pbo status, on, off, ...): served between events, never in a cycle."""
        if self.control is None or self._serving:
            return  # a command that waits (a switch) pumps events, but serves no second command meanwhile
        self._serving = True
        try:
            self.control.poll(lambda command, arguments: dispatch(self, command, arguments))
        finally:
            self._serving = False

    # --- the operator's verbs (commands.CommandHost) ------------------------------------------

    @property
    def realtime(self) -> dict[str, dict[str, str]]:
        return self.result.realtime

    def table_flags(self) -> list[str]:
        return [flag.name for flag in Flag if self.table is not None and self.table.flags & flag]

    def stalled_since(self) -> dict[str, float]:
        return {name: stall.since for name, stall in self.stall_watch.open.items()}

    def signal_task(self, task: str, op: str, states: set[str]) -> str:
        """Send on, off or clear to a task; its state once it is one of `states` (a refusal raises PboError)."""
        before = self.task_states.get(task)
        extra = (None, self.reconfiguration.index(self.configuration)) if op == "on" else ()
        self._signal(task, op, *extra)
        state = self._await_change(task, before, states)
        self._count_errors()
        return state

    def send_event(self, task: str, values: Any) -> None:
        self._signal(task, "event", values)

    def status_rows(self) -> list[dict[str, Any]]:
        """The live view's data, read from the table's status blocks."""
        rows = []
        if self.table is None:
            return rows
        for task in self.subsystem.tasks.values():
            words = self.table.status[task.index]
            rows.append({"task": task.name, "rtpu": task.rtpu, "state": TaskState(int(words[W.STATE])).name,
                         **_table_figures(words), "exec_last": float(words[W.EXEC_LAST])})
        return rows

    # --- stopping ---------------------------------------------------------------------------

    def _shutdown(self) -> None:
        self.result.duration = self.now() - self.started_at if self.started_at is not None else 0.0
        self.result.states_at_stop = dict(self.task_states)
        if self.table is not None:
            self.clock.announce_stop(self.table.announce_stop)
        alive = [c for c in self.children if c.process.poll() is None]
        for child in alive:
            if child.role != "plant":
                self.signals[child.role].try_send("stop")
                self._serve_stop(child)
        deadline = time.monotonic() + STOP_TIMEOUT
        rtpus = [c for c in alive if c.role != "plant"]
        while any(c.process.poll() is None for c in rtpus) and time.monotonic() < deadline:
            self._drain_events(0.05)
        self._drain_events(0.0)
        self.result.unstopped = [c.role for c in rtpus if c.process.poll() is None]
        self._read_final_values()
        for child in self.children:
            if child.process.poll() is None:
                child.process.send_signal(signal.SIGTERM)
        for child in self.children:
            try:
                child.process.wait(timeout=STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                child.process.kill()
                child.process.wait()
        self._drain_events(0.0)
        self.clock.close()
        self.result.switches = [record.to_json() for record in self.job_control.switches]
        started = self.started_at if self.started_at is not None else 0.0
        for name, stats in self._stats.items():
            # an overrun's release as seconds since the configuration came on, as the summary reads it
            overruns = [[release - started, late, took] for release, late, took in stats.get("last_overruns", [])]
            self.result.tasks[name] = {"rtpu": self.subsystem.tasks[name].rtpu, "critical": self.subsystem.tasks[name].critical,
                                       "state": self.result.states_at_stop.get(name, "?"),
                                       "error": self.task_errors.get(name, ""), **stats, "last_overruns": overruns}
        self._report_stalls(started)
        if self.control is not None:
            self.control.close()
        for queue in self.signals.values():
            queue.close()
        if self.events is not None:
            self.events.close()
        if self.table is not None:
            self.table.close()
        for entry in self._manifest():  # a backstop: whatever a child could not remove
            kind, _, name = entry.partition(" ")
            shm.unlink_quietly(kind, name)

    def _report_stalls(self, started: float) -> None:
        """Stalls into the result; the table's counters for tasks whose RTPU was killed before it could report."""
        killed = self.result.unstopped
        for stall in self.stall_watch.episodes:
            self.result.stalls.append({"task": stall.task, "rtpu": stall.rtpu, "from": stall.since - started,
                                       "to": None if stall.until is None else stall.until - started,
                                       "rtpu_killed": stall.rtpu in killed})
        if not killed:
            return
        assert self.table is not None
        for task in self.subsystem.tasks.values():
            if task.name in self.result.tasks or task.rtpu not in killed:
                continue
            words = self.table.status[task.index]
            self.result.tasks[task.name] = {
                "rtpu": task.rtpu, "critical": task.critical, "state": self.result.states_at_stop.get(task.name, "?"),
                "error": self.task_errors.get(task.name, ""), "from_table": True,  # its RTPU never reported
                **_table_figures(words), "exec_max": float(words[W.EXEC_MAX]), "last_overruns": []}
        if not self.result.failure:
            stuck = [s.task for s in self.stall_watch.episodes if s.until is None and s.rtpu in killed]
            were = "was" if len(killed) == 1 else "were"
            self.result.failure = (
                f"{', '.join(killed)} did not stop within {STOP_TIMEOUT:g} s and {were} killed: the kill components of its "
                "tasks did not run" + (f" (stalled: {', '.join(stuck)})" if stuck else ""))

    def _serve_stop(self, child: _Child) -> None:
        """Sim clock: step an RTPU once so it serves its stop; a dead or stuck one is left to SIGTERM."""
        deadline = time.monotonic() + STOP_TIMEOUT

        def give_up() -> bool:
            self._drain_events(0.0)
            return child.process.poll() is not None or time.monotonic() > deadline

        self.clock.serve(child.role, give_up)

    def _drain_events(self, timeout: float) -> None:
        if self.events is None:
            return
        while True:
            try:
                received = self.events.receive_event(timeout)
            except posix_ipc.Error:
                return
            if received is None:
                return
            try:
                self._absorb(*received)
            except RunFailure as exc:
                if not self.result.failure:
                    self.result.failure = str(exc)
                    self.result.stopped_by = "failure"
            timeout = 0.0

    def _read_final_values(self) -> None:
        if self.table is None:
            return
        for var in self.subsystem.variables.values():
            value, seq, when, writer = self.table.read(var.name)
            self.result.variables[var.name] = {
                "value": value.tolist(), "sequence": seq,
                "writer": next((t.name for t in self.subsystem.tasks.values() if t.index == writer), "job control"),
            }


def simulation_tick(subsystem: Subsystem) -> float:
    """The simulated clock's tick: the plant's timestep, or else the periods' greatest common divisor.

    Every period must be a whole number of ticks, or a task would be released between ticks.
    """
    periods_ns = {name: int(round(task.period * 1e9)) for name, task in subsystem.tasks.items()}
    if subsystem.plant is not None:
        tick_ns = int(round(subsystem.plant.timestep * 1e9))
        off_grid = [f"{name} ({ns / 1e6:g} ms)" for name, ns in periods_ns.items() if ns % tick_ns]
        if off_grid:
            raise RunFailure(f"--clock sim steps the plant every {tick_ns / 1e6:g} ms and releases tasks on those ticks, "
                             f"but these periods are not whole multiples of it: {', '.join(off_grid)}; "
                             f"make each period a multiple of the plant's timestep")
        return tick_ns / 1e9
    return math.gcd(*periods_ns.values()) / 1e9
