"""Job control: starts a subsystem, sequences its tasks, watches it, and always cleans up.

`Supervisor.run` makes the table and queues, starts the plant and the RTPUs, spawns the tasks in
const-dependency order, turns the configuration on, watches until the duration ends, Ctrl-C or a
failure, then stops the children and unlinks what it made, whatever happened. Its parts are fields:
the children (`Children`), signals and events (`EventHandling`), the report (`RunReporting`), the
operator's commands (`ControlService`), restarts, the lock, live changes.
The run's clock (`clock.run_clock`): real, or simulated and advanced by `pump`; run times are `now()`, process waits wall time.
"""

from __future__ import annotations

import json
import math
import os
import signal
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import numpy as np
import posix_ipc

from pbo_runtime.clock.application_lockstep import TurnGate
from pbo_runtime.clock.run_clock import RealRunClock, RunClock, SimRunClock
from pbo_runtime.config.checker.loops import GAINS_NOTE
from pbo_runtime.config.model import Subsystem, TaskSpec
from pbo_runtime.edit.live import LiveDescription
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import limits, messages, shm
from pbo_runtime.ipc.control import ControlServer
from pbo_runtime.ipc.local_queue import CountedQueue, LocalQueue
from pbo_runtime.supervisor.child_watch import ChildWatch
from pbo_runtime.supervisor.children import Children
from pbo_runtime.supervisor.cleanup import remove_dead_runs, unlink_run
from pbo_runtime.supervisor.control_service import ControlService, table_flags
from pbo_runtime.supervisor.event_ledger import EventLedger, EventOutlets, error_words
from pbo_runtime.supervisor.events import EventHandling
from pbo_runtime.supervisor.exclusive_devices import refuse_if_devices_in_use
from pbo_runtime.supervisor.failures import RtpuDied, RunFailure, RunRefused, StopRequested
from pbo_runtime.supervisor.fork_server import ForkServer
from pbo_runtime.supervisor.in_process import SecondStop, end_at_once
from pbo_runtime.supervisor.job_control import JobControl, JobFailure, starting_configuration
from pbo_runtime.supervisor.launch import SIM_TICK_DEFAULT, RtpuLaunch
from pbo_runtime.supervisor.live_changes import LiveChanges
from pbo_runtime.supervisor.lock_watch import LockGuard
from pbo_runtime.supervisor.posting import PLAN_SEQUENCE, realtime_posting, rewrite_plan, write_plan
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.supervisor.restarts import Restarter, RunSteps, RunView
from pbo_runtime.supervisor.run_options import RunOptions
from pbo_runtime.supervisor.run_queues import queue_plan, run_manifest
from pbo_runtime.supervisor.run_report import RunReporting, RunResult
from pbo_runtime.supervisor.sim_tick import simulation_tick
from pbo_runtime.supervisor.stages import run_stages
from pbo_runtime.supervisor.stall_watch import StallWatch
from pbo_runtime.supervisor.status_reply import TaskRow
from pbo_runtime.table.snapshot import TableBusy
from pbo_runtime.table.table import Flag, Header, StateTable, TableLayout, TaskState
from pbo_runtime.table.table import StatusWord as W

# the run's vocabulary, for whoever imports it from here
__all__ = ["RunFailure", "RunRefused", "RunResult", "StopRequested", "Supervisor", "remove_dead_runs", "simulation_tick"]

STALL_CHECK_EVERY = 0.05  # seconds between looks at the cycle counts (StallWatch); job control pumps every 2 ms


class Supervisor:
    """Runs one subsystem: a configuration for a duration, or an application's jobs."""

    def __init__(
        self,
        subsystem: Subsystem,
        configuration: str | None = None,
        duration: float | None = 5.0,
        on_tick: Callable[[Supervisor], None] | None = None,
        say: Callable[[str], None] = lambda text: None,
        options: RunOptions | None = None,
        fork_server: ForkServer | None = None,
    ) -> None:
        self.subsystem = subsystem
        options = options or RunOptions()
        # the start-up's time line (RunResult.startup): what the caller did before (the CLI: its
        # imports, the file's load and check), then each phase here, read once, off the cycles' path
        self._startup = dict(options.startup)
        application, clock, turn = options.application, options.clock, options.turn
        if clock not in ("real", "sim"):
            raise RunFailure(f"unknown clock '{clock}': use real or sim")
        if turn and clock != "sim":
            raise RunFailure("an application's turn (--turn) is for the simulated clock only: add --clock sim")
        # in an application on the simulated clock, `turn` names the semaphores of this subsystem's turn
        # (clock.application_lockstep); it is no longer waited for once the run is stopped or has failed
        gate = TurnGate(turn, lambda: bool(self._stop_requested or self.result.failure)) if turn else None
        self.clock: RunClock = (SimRunClock(simulation_tick(subsystem), gate, options.one_process, options.pace)
                                if clock == "sim" else RealRunClock())
        self.out_dir = os.path.abspath(options.out_dir) if options.out_dir else ""
        self.links = dict(options.links or {})  # an application's links, handed to every RTPU (see _links)
        self.application = application
        self.stages = options.stages  # an application file's stages: this subsystem's part, and the joins (supervisor.stages)
        self.configuration = starting_configuration(subsystem, configuration, application)
        self.duration = duration
        self.on_tick = on_tick
        self.say = say
        # an early fork server was made with the run's id: it takes part in the run's end (`last_out`)
        self.run_id = fork_server.run_id if fork_server is not None and fork_server.run_id else shm.new_run_id()
        self.table: StateTable | None = None
        self.events: messages.Queue | None = None
        self.signals: dict[str, messages.Queue] = {}
        self.rtpu_launches: dict[str, RtpuLaunch] = {}  # what each RTPU was started with (a restart changes a field)
        self.result = RunResult(subsystem.name, self.configuration, run_id=self.run_id,
                                gains=[note for note in subsystem.robot_notes if note.startswith(GAINS_NOTE)])
        self.result.objects = self._manifest()
        self.result.links = self.links
        self.started_at: float | None = None  # run time when the configuration came on
        self._stop_requested = ""
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
        self.result.tick, self.result.pace = self.tick, options.pace
        self.processes = Children(self.run_id, self.clock, self.result, say, lambda: self.table, self._manifest,
                                  self.may_restart, self._startup_mark, fork_server,  # the plant and the RTPUs
                                  subsystem=subsystem, events=lambda: self.events, signals=self.signals)
        self.children, self.launched = self.processes.children, self.processes.launched
        self.static = options.static
        self.job_control = JobControl(self, static=options.static)
        # what the children's events change (supervisor.event_ledger); the parts share its dicts
        self.ledger = EventLedger(self.result, say, EventOutlets(
            switches=self.job_control, staged=lambda *answer: self.live_changes.staged(*answer), count_errors=self._count_errors,
            child_exited=self._child_exited, running=lambda: self.started_at is not None), self._is_critical)
        self.task_states = self.ledger.task_states
        self.task_states.update({t: TaskState.NOT_CREATED.name for t in subsystem.tasks})
        self.task_errors = self.ledger.task_errors
        self._stats = self.ledger.stats
        self._stable = self.ledger.stable
        self._refused = self.ledger.refused
        self.result.application = application or ""
        self.every_task: dict[str, TaskSpec] = dict(subsystem.tasks)
        self.event_handling = EventHandling(  # signals out, events in (supervisor.events)
            self.clock, self.ledger, self.result, self.signals, self.every_task, lambda: self.events, self._check_children,
            lambda: self._stop_requested, self._startup_mark, say)
        self.reporting = RunReporting(self.result, self.ledger, self.job_control, self.stall_watch, self.every_task,
                                      lambda: self.subsystem, lambda: self.table, lambda: self.started_at)
        self.control_service = ControlService(self, lambda: self.control)
        self.alternate = options.alternate
        # SCHED_FIFO where the OS allows it, on the real clock unless asked otherwise (docs/performance.md
        # says why); the simulated clock waits on ticks: it needs none
        self.fifo = self.clock.fifo_by_default if options.fifo is None else options.fifo
        self.control: ControlServer | None = None
        self.lock_guard: LockGuard | None = None  # made with the table (supervisor.lock_watch)
        self.live_changes: LiveChanges = LiveChanges(  # pbo spawn, kill, replace, set, app (supervisor.live_changes)
            self.run_id, lambda: self.subsystem, self.clock, self.signals, self.result, self.job_control, self.task_states,
            self.every_task, self.stall_watch, say, self.event_handling.while_stepping, self.event_handling.next_event,
            self._adopted, lambda name: setattr(self, "application", name))
        self.restarter = Restarter(  # brings a dead RTPU back, within its restart policy (supervisor.restarts)
            RunView(subsystem=lambda: self.subsystem, configuration=lambda: self.configuration,
                    started_at=lambda: self.started_at, table=lambda: self.table, stop_requested=lambda: self._stop_requested,
                    live=lambda: (self.live_changes.sequence, self.live_changes.adopted_sequence), now=self.now),
            RunSteps(launch=self.processes.launch, await_ready=self.event_handling.await_ready,
                     list_children=self.processes.list_children, respawn=self.respawn, turn_on=self.turn_on,
                     take_one_event=self.event_handling.take_one_event, while_stepping=self.event_handling.while_stepping,
                     while_ticking=self.event_handling.while_ticking),
            self.clock, self.result, self.job_control, self.children, self.task_states, self.task_errors, self.every_task,
            self.signals, self.launched, self.rtpu_launches, self.static, say)
        refuse_if_devices_in_use(self.subsystem, self.run_id)  # before anything starts

    # --- names ------------------------------------------------------------------------------

    def _manifest(self) -> list[str]:
        return run_manifest(self.subsystem, self.run_id, self.clock.semaphores(self.subsystem.name, self.run_id, self._roles()))

    def _roles(self) -> list[str]:
        """The children, in the order the simulated clock steps them: the plant first, then the RTPUs."""
        return (["plant"] if self.subsystem.plant is not None else []) + [rtpu.name for rtpu in self.subsystem.rtpus]

    def now(self) -> float:
        """The run's time: CLOCK_MONOTONIC, or the simulated clock's last tick."""
        return self.clock.now()

    # --- the run ----------------------------------------------------------------------------

    def run(self) -> RunResult:
        wall_start = time.monotonic()
        running_since = 0.0  # wall time when the configuration came on
        previous = signal.signal(signal.SIGINT, self._interrupt)
        previous_term = signal.signal(signal.SIGTERM, self._interrupt)
        second_stop = (SecondStop(lambda: end_at_once(self._manifest(), self.subsystem.name, self.run_id))
                       if self.clock.one_process else None)  # a hung cycle holds it all
        try:
            removed = remove_dead_runs(self.subsystem.name).removed
            if removed:
                self.say(f"removed {len(removed)} object(s) left by a dead run: {', '.join(removed)}")
            self._start()
            running_since = time.monotonic()
            if self.application:
                self.job_control.run_application(self.application)
                self.result.jobs_done = list(self.job_control.jobs_done)
                self.result.stopped_by = f"application '{self.application}' done"
                self.say(f"application '{self.application}' is done")
            elif self.stages:
                self.result.jobs_done = run_stages(self.job_control, self.stages, self.say)
                self.result.stopped_by = "stages done"
                self.say("every stage is done")
            elif self.alternate:
                self.job_control.alternate(self.alternate.configurations, self.alternate.switches, self.alternate.interval)
                self.result.stopped_by = f"{self.alternate.switches} switches done"
            else:
                self._watch()
        except RunRefused:
            raise  # nothing ran: no summary, the refusal alone (after the finally removed what was made)
        except StopRequested:
            self.result.stopped_by = self._stop_requested
        except (RunFailure, JobFailure) as exc:
            self.result.failure = str(exc)
            self.result.stopped_by = "failure"
        except PboError as exc:  # a switch that could not complete, a condition that could not be read, an OS limit
            self.result.failure = str(exc)
            self.result.stopped_by = "failure"
        except (OSError, MemoryError, posix_ipc.Error) as exc:  # an OS limit met making a semaphore, a child's pipes...
            limit = limits.explain(exc, "starting the run" if self.started_at is None else "running")
            if limit is None:
                raise
            self.result.failure = str(limit)
            self.result.stopped_by = "failure"
        finally:
            if running_since:
                self.result.running_wall_seconds = time.monotonic() - running_since
            self._shutdown()
            self.live_changes.end()
            signal.signal(signal.SIGINT, previous)
            signal.signal(signal.SIGTERM, previous_term)
            if second_stop is not None:
                second_stop.close()
            self.result.wall_seconds = time.monotonic() - wall_start
        return self.result

    def _shutdown(self) -> None:
        """Stop the children (each RTPU by itself first), report, close and unlink everything: on every exit path."""
        processes, drain = self.processes, self.event_handling.drain
        processes.stop_watching()
        self.result.duration = self.now() - self.started_at if self.started_at is not None else 0.0
        self.result.states_at_stop = dict(self.task_states)
        if self.table is not None:
            self.clock.announce_stop(self.table.announce_stop)
        guard = self.lock_guard  # an RTPU whose stop waits on a wedged lock must not wait for good
        processes.stop_rtpus(self.signals, drain, guard.look_while_stopping if guard is not None else lambda: None)
        self.reporting.read_final_values()
        processes.end_all()
        drain(0.0)
        self.clock.close()
        self.reporting.report_run()
        if self.control is not None:
            self.control.close()
        for queue in self.signals.values():
            queue.close()
        if self.events is not None:
            self.events.close()
        if self.table is not None:
            self.table.close()
        unlink_run(self._manifest(), self.subsystem.name, self.run_id)

    def request_stop(self, reason: str) -> None:
        self._stop_requested = reason

    def _interrupt(self, signum: int, _frame: Any) -> None:
        self._stop_requested = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"

    def queue_plan(self) -> list[limits.QueueSize]:
        """The run's queues, each sized for what it carries (`supervisor.run_queues`)."""
        return queue_plan(self.subsystem, self.run_id, self.links)

    def _make_queues(self) -> None:
        """Every queue of the run, refused whole before the first is made if they cannot fit."""
        plan = self.queue_plan()
        limits.check_queue_room(plan)
        events, *signals, _control = plan
        try:
            self.events = (LocalQueue(events.name, events) if self.clock.one_process
                           else messages.Queue(events.name, create=True, size=events))
            signal_queue = CountedQueue if self.clock.one_process else messages.Queue  # (every end in this process)
            for rtpu, size in zip(self.subsystem.rtpus, signals, strict=True):
                self.signals[rtpu.name] = signal_queue(size.name, create=True, size=size)
            self.control = ControlServer(self.subsystem.name, self.run_id)
        except (OSError, ValueError, posix_ipc.Error) as exc:
            made = len(self.signals) + (self.events is not None) + (self.control is not None)
            error = limits.explain(exc, f"creating queue {plan[made].name}", plan)
            if error is None:
                raise
            raise error from None
        made_sizes = [self.events.size, *(queue.size for queue in self.signals.values()), self.control.size]
        self.result.queue_bytes = sum(size.bytes for size in made_sizes)

    def _startup_mark(self, phase: str, at: float | None = None) -> None:
        """The CLOCK_MONOTONIC second a start-up phase ended (RunResult.startup; now if not `at`), on either run clock."""
        self._startup[phase] = time.monotonic() if at is None else at
        self.result.startup = dict(sorted(self._startup.items(), key=lambda item: item[1]))

    def _start(self) -> None:
        sub, run_id = self.subsystem, self.run_id
        self._make_queues()
        events = self.events
        assert events is not None
        if ChildWatch.available() and not self.clock.one_process:  # a child's death wakes the wait for events at once
            self.processes.child_watch = ChildWatch(
                lambda role, pid: events.report("supervisor", messages.ChildExited(role, pid), timeout=0.0))
        self.table = StateTable.create(TableLayout.of(sub), messages.table_name(sub.name, run_id), self._manifest())
        refuse_if_devices_in_use(self.subsystem, self.run_id)  # again, now that a run started at the same instant sees this one
        if self.processes.fork_server is None:  # (a refused run starts no process) it loads while this process goes on
            self.processes.start_fork_server(sub.file, ["pbo_runtime.supervisor.plant_host"] * (sub.plant is not None) + ["rtpu"])
        # from the table's creation: job control's writes wait through the guard; looks begin
        self.lock_guard = LockGuard(self.table, self.shortest_period, self.result, self.children, self.say, self._run_time,
                                    self._check_children, lambda: self._stop_requested,
                                    lambda: self.control_service.serving, self.fifo)
        self.live_changes.start(self.table.layout.n_tasks)
        epoch = self.epoch = self.clock.start(sub.name, run_id, self._roles(), self.table.header)
        self._write_initial_values()
        self._startup_mark("table")
        launches: list[tuple[str, list[str], tuple[str, ...]]] = []  # (role, arguments, tasks)
        if sub.plant is not None:
            plant = sub.plant
            launches.append(("plant", [
                "-m", "pbo_runtime.supervisor.plant_host", "--type", plant.type, "--model", plant.model,
                "--timestep", repr(plant.timestep), "--options", json.dumps(dict(plant.options)),
                "--subsystem", sub.name, "--run-id", run_id, *(["--fifo"] if self.fifo else []), *self.clock.plant_arguments(),
                *(["--out", self.out_dir] if self.out_dir else []),
                "--base-dir", str(Path(plant.loc.file or sub.file).resolve().parent),
                "--drivers", ",".join(sorted({device.driver for device in sub.devices.values()})),
            ], ()))
        ring = tuple(self._roles()) if self.clock.name == "sim" else ()
        for rtpu in sub.rtpus:
            hosted = tuple(t.name for t in sub.tasks_on(rtpu.name))
            launch = self.rtpu_launches[rtpu.name] = RtpuLaunch(
                sub.file, run_id, rtpu.name, epoch=epoch + self.stagger * rtpu.index, spin=rtpu.spin, fifo=self.fifo,
                clock=self.clock.name, tick=self.tick or SIM_TICK_DEFAULT, ring=ring, out=self.out_dir,
                configuration=self.configuration, application=self.application or "", links=self.links,
                live=self.live_changes.live_dir)
            launches.append((rtpu.name, ["-m", "rtpu", *launch.to_argv()], hosted))
        # the plant and the RTPUs start side by side: an RTPU opens the plant's registers only in a
        # task's init, after every child is ready
        self.processes.launch_all(launches)
        self.event_handling.await_ready(set(self._roles()))
        self._startup_mark("children")
        members = sub.configurations[self.configuration].tasks
        # dynamic: the union every configuration may need is spawned now (TR 4.4); static: this one's
        spawned = [t for t in sub.init_order if t in members or not self.static]
        ordered = [t for t in sub.init_order if t in members]
        ordered.sort(key=lambda t: not sub.tasks[t].critical)  # the robot interface first: it publishes q_m
        self._bring_up_restarting(spawned, [])
        self._startup_mark("spawned")
        self._bring_up_restarting(spawned, ordered)
        self._publish_plan_state()
        self.started_at = self.now()
        self._startup_mark("on")
        self.job_control.mark(self.started_at, "configuration", f"{self.configuration} on")
        if self.clock.on_monotonic:
            self.result.started_monotonic = self.started_at
        # (its exit, a large interpreter torn down, is no part of the start-up: once on, not before)
        self.processes.release_fork_server(sub.rtpus)
        self.say(f"configuration '{self.configuration}' is on: {', '.join(ordered)}")

    def _bring_up_restarting(self, spawn: list[str], turn_on: list[str]) -> None:
        """`bring_up`, through the deaths an RTPU's restart policy allows (a module that aborts in init)."""
        while True:
            try:
                self.bring_up(spawn, turn_on)
                return
            except RtpuDied as death:
                self.restart_rtpu(death)

    @property
    def live(self) -> LiveDescription | None:
        """The description the run lives by (None: live changes are off for this run)."""
        return self.live_changes.live

    def stage_live(self, live: LiveDescription) -> None:
        self.live_changes.stage(live)

    def adopt(self, live: LiveDescription) -> None:
        self.live_changes.adopt(live)

    def _adopted(self, subsystem: Subsystem) -> None:
        self.subsystem = subsystem
        self.reconfiguration = Reconfiguration(subsystem)

    def start_application(self, name: str) -> None:
        """Run application `name` from the watch loop, as soon as the command is answered."""
        self.live_changes.queued_application = name

    def may_restart(self, role: str) -> bool:
        return not self.clock.one_process and self.restarter.may_restart(role)  # hosted here, it ended with the run

    def restart_rtpu(self, death: RtpuDied) -> None:
        self.restarter.restart_rtpu(death)

    def bring_up(self, spawn: list[str], turn_on: list[str], configuration: str | None = None) -> None:
        self.restarter.bring_up(spawn, turn_on, configuration)

    def respawn(self, name: str) -> None:
        """Spawn a task and wait for its init; an init failure stops the run (no half start)."""
        state = self.event_handling.spawn_and_wait(name)
        if state == "KILLED":
            raise RunFailure(f"task '{name}' failed in init and was not created: {self.task_errors.get(name, '')}")

    def turn_on(self, name: str, configuration: str) -> None:
        """Turn a task on; critical tasks learn who writes their inputs in `configuration`."""
        index = self.reconfiguration.index(configuration)
        self.event_handling.signal(messages.TurnOn(name, None, index))
        try:  # the state its on left: OFF too, when on failed and its error component turned it off
            state = self.event_handling.await_change(name, {"ON", "ERROR", "OFF"})
        except RunFailure:
            raise
        except PboError as exc:
            raise RunFailure(str(exc)) from None
        if state != "ON":
            raise RunFailure(f"task '{name}' failed in on{' and its error component turned it off' if state == 'OFF' else ''}: "
                             f"{self.task_errors.get(name, '')}")

    def hold_critical_tasks(self, hold: bool) -> None:
        assert self.table is not None
        self.table.set_flag(Flag.STATIC_SWITCH, hold)

    def watch(self, name: str, configuration: str) -> None:
        self.event_handling.signal_and_wait(messages.Watch(name, self.reconfiguration.index(configuration)), {"ON"})

    def kill_task(self, name: str) -> None:
        self.event_handling.signal_and_wait(messages.Kill(name), {"KILLED"})

    def read_variable(self, name: str) -> np.ndarray:
        """A variable's value, lock-free; while a writer keeps the table busy, the lock watch decides."""
        assert self.table is not None
        while True:
            try:
                return self.table.read(name)[0]
            except TableBusy:
                self._while_waiting_for_the_lock()  # a writer stopped mid-write holds the lock: past the bound it is ended

    def write_variable(self, name: str, value: Any) -> None:
        assert self.table is not None
        self.table.write(name, value, when=self.now(), writer=-1)

    def post_plan(self, configuration: str, activation: float) -> int:
        """Post a switch plan in the table's header; the plan's sequence number."""
        assert self.table is not None
        words = self.table.header.data  # (plain ints: no numpy scalar in the posting)
        sequence = words[PLAN_SEQUENCE] + 1
        write_plan(words, self.reconfiguration.index(configuration), int(activation * 1e9), sequence)
        return sequence

    def rewrite_plan(self) -> None:
        """The plan's words written as they are (`posting.rewrite_plan`): no executive sees a new plan."""
        assert self.table is not None
        rewrite_plan(self.table.header)

    def posting(self) -> AbstractContextManager[object]:
        """A plan's posting: at real-time priority on the real clock (`posting.realtime_posting`)."""
        return realtime_posting() if self.clock.plans_need_a_wakeup else nullcontext()

    def wake_rtpus(self) -> None:
        """Tell every RTPU a plan was posted (on the real clock: one may wait past the activation)."""
        if self.clock.plans_need_a_wakeup:
            for queue in self.signals.values():
                queue.try_signal(messages.PlanPosted(), timeout=0.0)

    def set_configuration(self, configuration: str) -> None:
        self.configuration = configuration
        self.result.configuration = configuration
        self._count_errors()

    def _publish_plan_state(self) -> None:
        """Mark the starting configuration as applied, so executives start in step with job control."""
        assert self.table is not None
        self.table.header[Header.PLAN_CONFIGURATION] = self.reconfiguration.index(self.configuration)

    def _run_time(self) -> float:
        """Seconds since the configuration came on (0 before)."""
        return self.now() - self.started_at if self.started_at is not None else 0.0

    def _check_children(self) -> None:
        """A child that ended: RtpuDied if its RTPU may be restarted (the caller restarts it), else RunFailure."""
        self.processes.check()
        self._look_at_the_lock()

    # --- what the operator's verbs ask (CommandHost) ----------------------------------------

    @property
    def realtime(self) -> dict[str, dict[str, str]]:
        return {rtpu: settings.to_json() for rtpu, settings in self.result.realtime.items()}

    def table_flags(self) -> list[str]:
        return table_flags(self.table)

    def stalled_since(self) -> dict[str, float]:
        return self.stall_watch.stalled_since()

    def restarts(self) -> list[dict[str, Any]]:
        return [restart.to_json() for restart in self.result.restarts]

    def status_rows(self) -> list[TaskRow]:
        return self.reporting.status_rows()

    def signal_task(self, task: str, op: str, states: set[str]) -> str:
        """Send on, off or clear to a task; its state once it is one of `states` (a refusal raises PboError)."""
        signal: messages.TaskSignal
        if op == "on":  # a critical task learns who writes its inputs in the running configuration
            signal = messages.TurnOn(task, None, self.reconfiguration.index(self.configuration))
        else:
            signal = messages.TurnOff(task) if op == "off" else messages.Clear(task)
        self.event_handling.signal(signal)
        state = self.event_handling.await_change(task, states)
        self._count_errors()
        return state

    def send_event(self, task: str, values: Any) -> None:
        self.event_handling.signal(messages.OperatorEvent(task, values))

    def _look_at_the_lock(self) -> None:
        if self.lock_guard is not None:
            self.lock_guard.look()

    def _while_waiting_for_the_lock(self) -> None:
        assert self.lock_guard is not None
        self.lock_guard.while_waiting_for_the_lock()

    def _is_critical(self, task: str) -> bool:
        spec = self.subsystem.tasks.get(task)  # (one the running description does not know: counted critical)
        return spec is None or spec.critical

    def _child_exited(self) -> None:
        if self.processes.child_watch is not None:  # (closed once the run stops: children then end as asked)
            self._check_children()  # a death handled now, not at the next look

    def _count_errors(self) -> None:
        """Critical tasks run locally stable while a task of the configuration is in ERROR or not fresh."""
        if self.table is None:
            return
        members = self.subsystem.configurations[self.configuration].tasks
        words = error_words(members, self.task_states, self._stable, self.subsystem.tasks)
        self.table.header[Header.TASKS_IN_ERROR] = words.in_error
        self.table.header[Header.TASKS_NOT_FRESH] = words.not_fresh
        self.table.set_flag(Flag.ILLEGAL_CONFIGURATION, words.illegal)

    def _write_initial_values(self) -> None:
        assert self.table is not None
        for var in self.subsystem.variables.values():
            initial = var.initial
            if initial is not None:
                self.table.write(var.name, initial, when=self.now(), writer=-1)

    # --- running ----------------------------------------------------------------------------

    def _watch(self) -> None:
        """Serve events and commands until the duration is over (StopRequested ends it sooner)."""
        assert self.started_at is not None
        while self.duration is None or self.now() - self.started_at < self.duration - self.tick / 2:
            if self.live_changes.queued_application is not None:
                self.live_changes.run_queued_application()
                continue
            left = self.duration - (self.now() - self.started_at) if self.duration is not None else 0.1
            self.pump(min(0.1, left))
        self.result.stopped_by = "duration"

    def pump(self, timeout: float) -> None:
        """One turn of job control's loop: children, stop requests, events, commands, the view. On the
        real clock it waits up to `timeout` for one event; on the simulated clock it runs the ticks
        that cover `timeout` (at least one), taking every event after each."""
        assert self.events is not None
        try:
            self._check_children()
            if self._stop_requested:
                raise StopRequested(self._stop_requested)
            self._check_stalls()
            if self.lock_guard is not None and self.clock.name == "real":  # while the lock is taken, look again soon
                timeout = self.lock_guard.watch.next_look_in(timeout)  # (sim: it is taken only within turns, over by now)
            events = self.event_handling
            self.clock.run_for(timeout, events.take_one_event, events.while_stepping, events.while_ticking)
        except RtpuDied as death:  # its restart policy brings it back; the other RTPUs never stopped
            self.restart_rtpu(death)
        self.control_service.serve()
        if self.on_tick is not None:
            self.on_tick(self)

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
