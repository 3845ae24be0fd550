"""Job control proper: switching configurations, running jobs and applications (TR §4.4, Onika §4.4).

The supervisor owns the processes; this module decides what to switch to and when, through the
narrow `JobHost` protocol the supervisor implements (a fake host in the unit tests). A dynamic
switch posts a plan in the table's header (configuration, activation on the release grid at least
the plan's lead ahead: `plan_lead`, sized from how long the RTPUs took to read the last plans)
and wakes the RTPUs; each applies it at its first cycle boundary at or after the activation,
so all switch at one instant. A static switch kills the leaving tasks and spawns the entering
ones. A job writes its object, switches, and waits for its post-condition; an application runs
its jobs one at a time, and stops in the configuration it is in when a pre-condition fails or a
job times out.

An RTPU with a restart policy that dies during a switch is restarted in the configuration the
switch goes to (`Restarter.restart_rtpu` reads `JobControl.switching`): the switch waits for
no report from it, the other RTPUs' part stands, and its record names the restart (`restarted`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Protocol

import numpy as np

from pbo_runtime.config.decisions import decides, paths
from pbo_runtime.config.expressions import ExpressionError, compile_condition
from pbo_runtime.config.model import Subsystem
from pbo_runtime.edit.live import LiveDescription
from pbo_runtime.errors import PboError, closest_name
from pbo_runtime.reports.run_records import DecisionTaken, Mark
from pbo_runtime.reports.run_result import SwitchReport
from pbo_runtime.supervisor.decisions import DecidingRun
from pbo_runtime.supervisor.failures import RtpuDied, RunFailure, WrongArgument
from pbo_runtime.supervisor.plan_lead import POST_LEAD_MIN, PlanLead, RtpuAround, earliest_activation

SWITCH_TIMEOUT = 5.0
POLL = 0.01  # how often a job's post-condition is evaluated


class JobFailure(PboError):
    """A job's pre-condition failed or it timed out: the application stops, the message says why.

    `values`: the variables the failed condition read, as it read them.
    """

    def __init__(self, message: str, values: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.values = values or {}


@dataclass
class SwitchRecord:
    """One switch as it happened: what changed, when each RTPU applied it, when the new cycles ran."""

    sequence: int
    before: str
    after: str
    requested_at: float
    activation: float
    applied: dict[str, tuple[float, float]] = field(default_factory=dict)  # rtpu -> (applied_at, done_at)
    first_cycles: dict[str, float] = field(default_factory=dict)  # entering task -> start of its first cycle
    off: list[str] = field(default_factory=list)
    on: list[str] = field(default_factory=list)
    # per critical task, until the next switch: cycles that read a switched-out writer, and stale reads
    lost: dict[str, int] = field(default_factory=dict)
    stale: dict[str, int] = field(default_factory=dict)
    change: str = ""  # a live change applied by this plan (`pbo spawn` ...), "" for a switch
    lead: float = 0.0  # the least time from the request to the activation this plan was given
    read: dict[str, float] = field(default_factory=dict)  # rtpu -> when it first read the plan
    posted_at: float = math.nan  # when the plan was in the header (the RTPUs were signalled after)
    counted_from: float = math.nan  # the clock reading the activation was counted from (the request, or later)
    restarted: list[str] = field(default_factory=list)  # RTPUs that died during the switch and came back in `after`

    @property
    def read_delay(self) -> float:
        """From the clock reading the activation was counted from to the last RTPU's first read of the
        plan (what the lead must cover)."""
        start = self.requested_at if math.isnan(self.counted_from) else self.counted_from
        return max(self.read.values()) - start if self.read else math.nan

    @property
    def grid_wait(self) -> float:
        """What the activation adds to the lead: the wait for the release grid's next boundary."""
        return self.activation - self.requested_at - self.lead

    @property
    def work(self) -> float:
        """Activation to the new configuration's first cycle: the RTPUs' wake-up and switch work."""
        return self.latency - (self.activation - self.requested_at)

    @property
    def latency(self) -> float:
        """Request to the first cycle of the new configuration (of its last entering task)."""
        if self.first_cycles:
            return max(self.first_cycles.values()) - self.requested_at
        if self.applied:
            return max(done for _, done in self.applied.values()) - self.requested_at
        return math.nan

    @property
    def skew(self) -> float:
        """How far apart the RTPUs applied the switch."""
        times = [applied for applied, _ in self.applied.values()]
        return max(times) - min(times) if len(times) > 1 else 0.0

    @property
    def longest(self) -> float:
        """The longest time one RTPU spent switching (off + on components and transfers)."""
        return max((done - applied for applied, done in self.applied.values()), default=0.0)

    def report(self) -> SwitchReport:
        return SwitchReport(self.sequence, self.before, self.after, self.latency, self.skew, self.longest, tuple(self.off),
                            tuple(self.on), dict(self.lost), dict(self.stale), self.lead, self.read_delay, self.grid_wait,
                            self.work, self.posted_at - self.requested_at,
                            {rtpu: at - self.requested_at for rtpu, at in self.read.items()}, self.change,
                            tuple(self.restarted))

    def to_json(self) -> dict[str, Any]:
        return self.report().to_json()


class JobHost(Protocol):
    """What job control needs of the process that runs the subsystem, and nothing more.

    The Supervisor is the host of a run; tests use a fake host and a manual clock, so every
    decision here is tested without a process. `tick` is the simulated clock's tick (0 on the
    real clock); `epoch` and `shortest_period` make the first RTPU's release grid.
    """

    @property
    def subsystem(self) -> Subsystem: ...
    @property
    def configuration(self) -> str: ...
    @property
    def task_states(self) -> Mapping[str, str]: ...
    @property
    def epoch(self) -> float: ...
    @property
    def shortest_period(self) -> float: ...
    @property
    def stagger(self) -> float:
        """RTPU i releases at epoch + i x stagger + k x period (0 on the simulated clock)."""
    @property
    def tick(self) -> float: ...
    @property
    def say(self) -> Callable[[str], None]: ...

    def now(self) -> float:
        """The run's time, on whichever clock runs it."""
    def pump(self, timeout: float) -> None:
        """Let the run go on for `timeout` seconds: events (which call back `switched`...), commands, the view."""
    def read_variable(self, name: str) -> np.ndarray:
        """A state variable's current value."""
    def write_variable(self, name: str, value: Any) -> None:
        """Write a state variable as job control (a job's object)."""
    def post_plan(self, configuration: str, activation: float) -> int:
        """Post a switch plan in the table's header; the plan's sequence number."""
    def rewrite_plan(self) -> None:
        """Write the header's plan words as they are, as `post_plan` writes them (no new plan: a posting timed)."""
    def posting(self) -> AbstractContextManager[object]:
        """Around a plan's activation, its posting and the RTPUs' wake-up (the real clock: at real-time priority)."""
    def wake_rtpus(self) -> None:
        """Tell every RTPU a plan was posted."""
    def set_configuration(self, configuration: str) -> None:
        """The switch is done: `configuration` is the running one."""
    def kill_task(self, task: str) -> None:
        """Kill a task and wait until it is KILLED."""
    def respawn(self, task: str) -> None:
        """Spawn a task and wait for its init."""
    def turn_on(self, task: str, configuration: str) -> None:
        """Turn a task on in `configuration` and wait until it is ON."""
    def restart_rtpu(self, death: RtpuDied) -> None:
        """Restart an RTPU that died (its restart policy allows it; RunFailure past it), in the switch's configuration."""
    def hold_critical_tasks(self, hold: bool) -> None:
        """While a static switch kills and spawns tasks, critical tasks run their locally stable behaviour."""
    def watch(self, task: str, configuration: str) -> None:
        """A critical task that stays ON watches the writers of its inputs in `configuration`."""
    def stage_live(self, live: LiveDescription) -> None:
        """Every RTPU reads the live description and keeps it for the next plan; its new tasks can be spawned."""
    def adopt(self, live: LiveDescription) -> None:
        """The live change is applied: `live` is the running subsystem's description from now on."""


def plan_activation(requested: float, lead: float, epoch: float, grid: float) -> float:
    """A plan's activation: the first boundary of the first RTPU's release grid at least `lead` after `requested`.

    On the grid, the entering tasks' first cycle is the boundary itself, so the critical consumer's
    next read already sees their output; a boundary closer than the lead is taken only if the lead
    fits before it, never by rounding the lead itself up.
    """
    return epoch + math.ceil((requested + lead - epoch) / grid - 1e-9) * grid


def evaluate(host: JobHost, text: str) -> tuple[bool, dict[str, Any]]:
    """Evaluate a condition on the table's current values: (holds, the values it read)."""
    condition = compile_condition(text)
    values = {name: host.read_variable(name) for name in sorted(condition.variables)}
    try:
        return condition.evaluate(values), values
    except ExpressionError as exc:  # e.g. an int variable's power beyond int64: refused, never a wrapped answer
        raise JobFailure(f"condition '{text}' cannot be evaluated on the values read ({_show(values)}): {exc}") from None


def _show(values: dict[str, Any]) -> str:
    return "; ".join(f"{name} = {np.array2string(np.asarray(v), precision=4, separator=', ', max_line_width=10**6)}"
                     for name, v in values.items())


def application_steps(subsystem: Subsystem, application: str, _seen: tuple[str, ...] = (),
                      fill: Any = None) -> list[tuple[str, dict[str, Any]]]:
    """(job, object values) in order, with applications used as steps expanded in place (Onika §4.4.2).

    A step's named object is read from the subsystem now, so the value it has when the
    application starts is the one written. An application given an object fills each of its
    gaps with it (`fill`), down through the incomplete applications it uses.
    """
    steps: list[tuple[str, dict[str, Any]]] = []
    for step in subsystem.applications[application].steps:
        given = subsystem.objects[step.object].value if step.object is not None else step.fill
        if given is None:
            given = fill
        if step.job in subsystem.applications and application not in _seen:
            steps.extend(application_steps(subsystem, step.job, (*_seen, application), given))
        elif step.job in subsystem.jobs:
            arguments = dict(step.arguments)
            variable = subsystem.jobs[step.job].object
            if variable is not None and variable not in arguments and given is not None:
                arguments[variable] = given
            steps.append((step.job, arguments))
    return steps


class JobControl:
    """Switches and jobs for one running subsystem."""

    def __init__(self, host: JobHost, static: bool = False) -> None:
        self.host = host
        self.subsystem = host.subsystem
        self.static = static
        self.switches: list[SwitchRecord] = []
        self.pending: SwitchRecord | None = None  # a dynamic switch's plan, waiting for the RTPUs' reports
        # the switch under way (static or dynamic): a restart comes back in its `after`
        self.switching: SwitchRecord | None = None
        self.switching_subsystem = self.subsystem  # what a live change's plan swaps in, while it is under way
        # each RTPU around a switch (`_around`), for the descriptions it was made of
        self._arounds: tuple[Subsystem | None, Subsystem | None, dict[Any, list[RtpuAround]]] = (None, None, {})
        self.job: str | None = None
        self.application: str | None = None
        self.lead = PlanLead()  # on the real clock, from the read delays of the plans so far
        self.post_lead = PlanLead(minimum=POST_LEAD_MIN)  # from the post delays (request to the plan in the header)
        # what a plot of the run's logs marks: switches and jobs, at their times on the run's clock
        # (the clock a data log's rows are stamped with: each cycle's release time)
        self.marks: list[Mark] = []
        # an application that decides: each decision with its values, and where it is now (`pick > try > reach`)
        self.decisions: list[DecisionTaken] = []
        self.path: list[str] = []
        self.place: list[int] = []  # the same as positions: a step's index in its row, a row's in its step (the HMI's)
        self.jobs_done: list[str] = []  # the jobs the application ran to their end, in order

    def mark(self, at: float, kind: str, label: str) -> None:
        self.marks.append(Mark(at, kind, label))

    # --- switching --------------------------------------------------------------------------

    def switch(self, configuration: str) -> SwitchRecord:
        host = self.host
        if configuration not in self.subsystem.configurations:
            raise PboError(f"no configuration '{configuration}' (configurations: {', '.join(self.subsystem.configurations)})")
        before = host.configuration
        configurations = self.subsystem.configurations
        leaving = [t for t in configurations[before].tasks if t not in configurations[configuration].tasks]
        entering = [t for t in self.subsystem.configurations[configuration].tasks
                    if t not in self.subsystem.configurations[before].tasks]
        if self.static:
            return self._switch_static(before, configuration, leaving, entering)
        return self._switch_dynamic(before, configuration, entering)

    def _switch_dynamic(self, before: str, configuration: str, entering: list[str], change: str = "",
                        described: Subsystem | None = None) -> SwitchRecord:
        """Post a plan for `configuration` and wait until every RTPU applied it and `entering` tasks ran
        (`described`: the subsystem as a live change makes it, its new tasks included)."""
        host = self.host
        self.switching_subsystem = described or self.subsystem
        specs = self.switching_subsystem.tasks
        requested = host.now()
        if host.tick > 0:  # simulated: the next tick on the grid
            lead = host.tick
            activation = plan_activation(requested, lead, host.epoch, host.shortest_period)
            sequence = host.post_plan(configuration, activation)
            counted_from, posted_at = requested, host.now()
            host.wake_rtpus()
        else:
            with host.posting():  # from the request to the plan in the header: no ordinary process runs first
                around = self._around(before, entering)
                self._time_the_writing()
                leads = self.post_lead.value, self.lead.value
                counted_from = host.now()
                activation, lead = earliest_activation(counted_from, host.epoch, host.shortest_period, around, *leads)
                # The post lead covers the plan's writing alone: counted again from the last clock reading
                # before it, the activation moves on only if the computing was held off past its lead.
                while (counted_from := host.now()) + lead > activation + 1e-12:
                    activation, lead = earliest_activation(counted_from, host.epoch, host.shortest_period, around, *leads)
                sequence = host.post_plan(configuration, activation)
                posted_at = host.now()
                host.wake_rtpus()
        record = SwitchRecord(sequence, before, configuration, requested, activation, change=change, lead=lead,
                              posted_at=posted_at, counted_from=counted_from)
        self.pending = self.switching = record
        entering_active = [t for t in entering if host.task_states.get(t) == "OFF" and not getattr(specs[t], "aperiodic", False)]
        deadline = host.now() + SWITCH_TIMEOUT
        rtpus = len(self.subsystem.rtpus)
        restarts = 0
        try:
            # an RTPU restarted during the switch (in `pump`) came back in `configuration` with its
            # tasks ON: no report of the plan comes from it, and none is waited for
            while (len(record.applied.keys() | set(record.restarted)) < rtpus
                   or any(t not in record.first_cycles and specs[t].rtpu not in record.restarted for t in entering_active)):
                if len(record.restarted) != restarts:  # the restart's own time is not the switch's
                    restarts, deadline = len(record.restarted), host.now() + SWITCH_TIMEOUT
                if host.now() > deadline:
                    raise PboError(f"switch to '{configuration}' did not complete within {SWITCH_TIMEOUT:g} s "
                                   f"(applied on: {', '.join(record.applied) or 'no RTPU'})")
                host.pump(0.002)
        finally:
            self.pending = self.switching = None
        if host.tick == 0 and record.read:  # (simulated: RTPUs read a plan at the next tick, by construction)
            self.lead.record(record.read_delay, late=max(record.read.values()) > activation)
        if host.tick == 0:
            self.post_lead.record(record.posted_at - counted_from, late=record.posted_at > activation)
        host.set_configuration(configuration)
        self.switches.append(record)
        # the plan's activation: the cycle boundary at which every RTPU switched
        self.mark(record.activation, "change" if change else "switch", change or f"{before} -> {configuration}")
        return record

    def _time_the_writing(self) -> None:
        """Before a run's first plans, the post delay timed on the plan's words as they are: the first
        plans' post lead is measured too, not the bound."""
        host, post_lead = self.host, self.post_lead
        while len(post_lead.ordered) < post_lead.first_samples:
            start = host.now()
            host.rewrite_plan()
            post_lead.record(host.now() - start)

    def _around(self, before: str, entering: list[str]) -> list[RtpuAround]:
        """Each RTPU around a switch from `before`: what it releases (`plan_lead.deadline`), its tasks
        ON now from the running description, those entering from the one the switch goes to."""
        running, described = self.subsystem, self.switching_subsystem
        states = self.host.task_states
        # kept for the descriptions it was made of: it is counted in every switch's latency
        key = (before, tuple(entering), tuple(map(states.get, running.configurations[before].tasks)), self.host.epoch)
        if self._arounds[0] is not running or self._arounds[1] is not described:
            self._arounds = (running, described, {})
        kept = self._arounds[2]
        return kept[key] if key in kept else kept.setdefault(key, self._made_around(running, described, before, entering))

    def _made_around(self, running: Subsystem, described: Subsystem, before: str, entering: list[str]) -> list[RtpuAround]:
        states = self.host.task_states
        on = [running.tasks[name] for name in running.configurations[before].tasks
              if name not in entering and states.get(name) == "ON"]
        coming = [described.tasks[name] for name in entering if name in described.tasks]
        return [RtpuAround(self.host.epoch + self.host.stagger * rtpu.index,
                           tuple(t.period for t in on if t.rtpu == rtpu.name and not t.aperiodic),
                           tuple(t.period for t in coming if t.rtpu == rtpu.name and not t.aperiodic),
                           any(t.aperiodic for t in (*on, *coming) if t.rtpu == rtpu.name))
                for rtpu in described.rtpus]

    def apply_live(self, live: LiveDescription, change: str) -> SwitchRecord:
        """A live change, checked already (`edit.live`): applied at one cycle boundary, as a switch is.

        Every RTPU stages the new description; new tasks are spawned (their init runs, they wait
        OFF); one plan for the running configuration then turns leaving tasks off and entering ones
        on at the same boundary, swaps in who writes what for the critical tasks' freshness watch,
        and gives tuned tasks their parameters; tasks gone from the description are killed after.
        A new task whose init fails refuses the change, with nothing else changed.
        """
        host = self.host
        if self.static:
            raise PboError("live changes apply at a cycle boundary, as a dynamic switch does; this run switches "
                           "statically (--static): restart it without --static")
        before, after = self.subsystem, live.subsystem
        configuration = host.configuration
        was = before.configurations[configuration].tasks
        now = after.configurations[configuration].tasks
        added = [name for name in after.init_order if name not in before.tasks]
        removed = [name for name in before.tasks if name not in after.tasks]
        try:
            host.stage_live(live)
        except RtpuDied as death:  # restarted as the run is described now; the others forget what they staged
            host.restart_rtpu(death)
            host.stage_live(LiveDescription(live.file, live.doc, before, live.slots))
            raise PboError(f"{change} is refused: {death}, and was restarted; nothing else changed") from None
        spawned: list[str] = []
        try:
            for name in added:
                host.respawn(name)
                spawned.append(name)
        except PboError as exc:
            if isinstance(exc, RtpuDied):  # restarted as the run is described now (without the new tasks)
                host.restart_rtpu(exc)
                exc = PboError(f"{exc}, and was restarted")
            for name in spawned:
                self._through_restarts(partial(self._kill, name))
            host.stage_live(LiveDescription(live.file, live.doc, before, live.slots))  # what the RTPUs had
            raise PboError(f"{change} is refused: {exc}; nothing else changed") from None
        record = self._switch_dynamic(configuration, configuration, [t for t in now if t not in was], change, after)
        self.subsystem = after
        host.adopt(live)
        for name in removed:
            self._through_restarts(partial(self._kill, name))
        return record

    def switched(self, rtpu: str, sequence: int, applied_at: float, done_at: float, off: list[str], on: list[str],
                 read_at: float = 0.0) -> None:
        """An RTPU's report that it applied a plan (`read_at`: when it first read it; 0: not known)."""
        record = self.pending
        if record is None or record.sequence != sequence:
            return
        record.applied[rtpu] = (applied_at, done_at)
        if read_at > 0.0:
            record.read[rtpu] = read_at
        record.off.extend(off)
        record.on.extend(on)

    def window(self, sequence: int, task: str, lost: int, stale: int) -> None:
        """A critical task's counts from switch `sequence` until the next one."""
        for record in reversed(self.switches):
            if record.sequence == sequence:
                record.lost[task] = lost
                record.stale[task] = stale
                return

    def first_cycle(self, sequence: int, task: str, at: float) -> None:
        record = self.pending
        if record is not None and record.sequence == sequence:
            record.first_cycles[task] = at

    def _switch_static(self, before: str, after: str, leaving: list[str], entering: list[str]) -> SwitchRecord:
        """Static reconfiguration: only the next configuration's tasks exist (TR §4.4)."""
        host = self.host
        requested = host.now()
        record = SwitchRecord(len(self.switches) + 1, before, after, requested, requested, off=list(leaving), on=list(entering))
        states = host.task_states

        def bring_on(name: str) -> None:
            if states.get(name) in ("NOT_CREATED", "KILLED"):
                host.respawn(name)
            if states.get(name) != "ON":  # (a restarted RTPU turned it on already)
                host.turn_on(name, after)

        self.switching = record
        host.hold_critical_tasks(True)  # their writers stop now: holding is the switch's doing, not a fault
        try:
            for name in leaving:
                self._through_restarts(partial(self._kill, name))
            for name in [t for t in self.subsystem.init_order if t in entering]:
                self._through_restarts(partial(bring_on, name))
            for name in self.subsystem.configurations[after].tasks:
                if self.subsystem.tasks[name].critical and name not in entering:
                    self._through_restarts(partial(host.watch, name, after))
        finally:
            self.switching = None
            host.hold_critical_tasks(False)
        record.applied["job control"] = (requested, host.now())
        host.set_configuration(after)
        self.switches.append(record)
        self.mark(record.applied["job control"][1], "switch", f"{before} -> {after}")
        return record

    def _kill(self, name: str) -> None:
        if self.host.task_states.get(name) not in ("NOT_CREATED", "KILLED"):  # (a restarted RTPU no longer has it)
            self.host.kill_task(name)

    def _through_restarts(self, step: Callable[[], None]) -> None:
        """A step of a static switch or a live change; an RTPU that died meanwhile is restarted (in the switch's
        configuration), and the step done again (each step does only what is not done yet). Past the policy,
        RunFailure stops the run."""
        while True:
            try:
                step()
                return
            except RtpuDied as death:
                self.host.restart_rtpu(death)  # (which names it in the switch's record)

    def alternate(self, configurations: list[str], switches: int, interval: float) -> None:
        """Switch between configurations `switches` times, one every `interval` seconds (a switch test)."""
        host = self.host
        for name in configurations:
            if name not in self.subsystem.configurations:
                raise PboError(f"no configuration '{name}' (configurations: {', '.join(self.subsystem.configurations)})")
        order = [c for c in configurations if c != host.configuration] + [c for c in configurations if c == host.configuration]
        next_at = host.now() + interval
        for number in range(switches):
            while host.now() < next_at - host.tick / 2:
                host.pump(min(0.002, max(next_at - host.now(), 0.0)))
            self.switch(order[number % len(order)])
            next_at += interval

    # --- jobs and applications --------------------------------------------------------------

    def run_job(self, name: str, arguments: dict[str, Any], step: str = "") -> None:
        """Pre-condition, object, switch, then wait for the post-condition (or the timeout)."""
        host = self.host
        job = self.subsystem.jobs[name]
        where = f"job '{name}'{step}"
        self.job = name
        if job.pre:
            holds, values = evaluate(host, job.pre)
            if not holds:
                raise JobFailure(f"{where}: pre-condition '{job.pre}' does not hold ({_show(values)})", values)
        for variable, value in arguments.items():
            host.write_variable(variable, value)
        if job.configuration != host.configuration:
            self.switch(job.configuration)
        host.say(f"{where}: running in '{job.configuration}'" + (f", waiting for {job.post}" if job.post else ""))
        started = host.now()
        self.mark(started, "job", f"job {name} starts")
        if not job.post and not job.timeout:
            return
        while True:
            if job.post:
                holds, values = evaluate(host, job.post)
                if holds:
                    host.say(f"{where}: done in {host.now() - started:.2f} s ({job.post})")
                    self.mark(host.now(), "job", f"job {name} done")
                    return
            if job.timeout and host.now() - started > job.timeout:
                if not job.post:
                    self.mark(host.now(), "job", f"job {name} ends")
                    return  # a job with a timeout and no post-condition runs for that long
                self.mark(host.now(), "job", f"job {name} timed out")
                raise JobFailure(f"{where}: timed out after {job.timeout:g} s; post-condition '{job.post}' "
                                 f"still false ({_show(values)})", values)
            host.pump(POLL)

    def start_job(self, name: str, arguments: dict[str, Any]) -> None:
        """An operator's job: its object and its configuration now; its post-condition is shown, not awaited."""
        host = self.host
        job = self.subsystem.jobs[name]
        if job.pre:
            holds, values = evaluate(host, job.pre)
            if not holds:
                raise JobFailure(f"job '{name}': pre-condition '{job.pre}' does not hold ({_show(values)})")
        for variable, value in arguments.items():
            variable_spec = self.subsystem.variables[variable]
            array = np.asarray(value, dtype=variable_spec.dtype)
            if array.size != variable_spec.size:
                raise PboError(f"job '{name}': object '{variable}' takes {variable_spec.size} values "
                               f"(shape {list(variable_spec.shape)}), got {array.size}")
            host.write_variable(variable, array.reshape(variable_spec.shape))
        if job.configuration != host.configuration:
            self.switch(job.configuration)
        self.job = name
        self.mark(host.now(), "job", f"job {name} starts")

    def run_application(self, application: str) -> None:
        spec = self.subsystem.applications[application]
        if not spec.complete:
            raise JobFailure(f"application '{application}' is incomplete (a step lacks its object) and cannot run; "
                             f"see pbo check {self.subsystem.file}")
        self.application = application
        self.jobs_done = []
        if decides(self.subsystem, application):
            DecidingRun(self, evaluate, JobFailure, POLL).run(application)
            self.job = None
            return
        steps = application_steps(self.subsystem, application)
        for number, (job, arguments) in enumerate(steps, start=1):
            self.run_job(job, arguments, step=f" (step {number} of {len(steps)} of application '{application}')")
            self.jobs_done.append(job)
        self.job = None


def starting_configuration(subsystem: Subsystem, configuration: str | None, application: str | None) -> str:
    """The configuration a run starts in: the one asked for, else the application's first job's, else
    the file's first; WrongArgument for a name the file does not have, RunFailure for an incomplete application."""
    if application is not None and application not in subsystem.applications:
        close = closest_name(application, subsystem.applications)
        raise WrongArgument(f"no application '{application}' in {subsystem.file}"
                            + (f": did you mean '{close}'?" if close else "")
                            + f" (applications: {', '.join(subsystem.applications) or 'none'})")
    if application is not None and not subsystem.applications[application].complete:
        raise RunFailure(f"application '{application}' is incomplete (a step lacks the object its job needs) and "
                         f"cannot be run; pbo check {subsystem.file} shows which step")
    if configuration is None and application is not None:
        first = [job for job, _ in application_steps(subsystem, application)]
        if decides(subsystem, application):  # the first job of its first path
            first = list(paths(subsystem, application)[0][0].jobs)
        configuration = subsystem.jobs[first[0]].configuration if first else None
    chosen = configuration or next(iter(subsystem.configurations))
    if chosen not in subsystem.configurations:
        close = closest_name(chosen, subsystem.configurations)
        raise WrongArgument(f"no configuration '{chosen}' in {subsystem.file}"
                            + (f": did you mean '{close}'?" if close else "")
                            + f" (configurations: {', '.join(subsystem.configurations)})")
    return chosen
