"""Job control proper: switching configurations, running jobs and applications (TR §4.4, Onika §4.4).

The supervisor owns the processes; this module decides what to switch to and when. A dynamic
switch posts a plan in the table's header (configuration, activation a few milliseconds ahead)
and wakes the RTPUs; each applies it at its first cycle boundary at or after the activation,
so all switch at one instant. A static switch kills the leaving tasks and spawns the entering
ones. A job writes its object, switches, and waits for its post-condition; an application runs
its jobs one at a time, and stops in the configuration it is in when a pre-condition fails or a
job times out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from pbo_runtime.config.model import Subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.config.expressions import compile_condition
from pbo_runtime.table.table import Header

if TYPE_CHECKING:
    from pbo_runtime.supervisor.supervisor import Supervisor

PLAN_LEAD = 0.002  # seconds from posting a plan to its activation: every RTPU is woken by then (wake-ups take ~0.1 ms)
SWITCH_TIMEOUT = 5.0
POLL = 0.01  # how often a job's post-condition is evaluated


class JobFailure(PboError):
    """A job's pre-condition failed or it timed out: the application stops, the message says why."""


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

    def to_json(self) -> dict[str, Any]:
        return {"sequence": self.sequence, "from": self.before, "to": self.after, "latency": self.latency,
                "skew": self.skew, "longest": self.longest, "off": self.off, "on": self.on,
                "cycles_lost": self.lost, "stale_reads": self.stale}


def evaluate(supervisor: Supervisor, text: str) -> tuple[bool, dict[str, Any]]:
    """Evaluate a condition on the table's current values: (holds, the values it read)."""
    condition = compile_condition(text)
    assert supervisor.table is not None
    values = {name: supervisor.table.read(name)[0] for name in sorted(condition.variables)}
    return condition.evaluate(values), values


def _show(values: dict[str, Any]) -> str:
    return "; ".join(f"{name} = {np.array2string(np.asarray(v), precision=4, separator=', ', max_line_width=10**6)}" for name, v in values.items())


def application_steps(subsystem: Subsystem, application: str, _seen: tuple[str, ...] = ()) -> list[tuple[str, dict[str, Any]]]:
    """(job, object values) in order, with applications used as steps expanded in place."""
    steps: list[tuple[str, dict[str, Any]]] = []
    for step in subsystem.applications[application].steps:
        if step.job in subsystem.applications and application not in _seen:
            steps.extend(application_steps(subsystem, step.job, (*_seen, application)))
        elif step.job in subsystem.jobs:
            steps.append((step.job, dict(step.arguments)))
    return steps


class JobControl:
    """Switches and jobs for one running subsystem."""

    def __init__(self, supervisor: Supervisor, static: bool = False) -> None:
        self.supervisor = supervisor
        self.subsystem = supervisor.subsystem
        self.static = static
        self.switches: list[SwitchRecord] = []
        self.pending: SwitchRecord | None = None
        self.job: str | None = None
        self.application: str | None = None

    # --- switching --------------------------------------------------------------------------

    def switch(self, configuration: str) -> SwitchRecord:
        sup = self.supervisor
        if configuration not in self.subsystem.configurations:
            raise PboError(f"no configuration '{configuration}' (configurations: {', '.join(self.subsystem.configurations)})")
        before = sup.configuration
        leaving = [t for t in self.subsystem.configurations[before].tasks if t not in self.subsystem.configurations[configuration].tasks]
        entering = [t for t in self.subsystem.configurations[configuration].tasks
                    if t not in self.subsystem.configurations[before].tasks]
        if self.static:
            return self._switch_static(before, configuration, leaving, entering)
        table = sup.table
        assert table is not None
        header = table.header
        requested = sup.now()
        # activate on the first RTPU's release grid: the entering tasks' first cycle is the cycle
        # boundary itself, so the critical consumer's next read already sees their output
        grid = sup.shortest_period
        lead = sup.tick if sup.lockstep is not None else PLAN_LEAD  # simulated: the next tick on the grid
        activation = sup.epoch + math.ceil((requested + lead - sup.epoch) / grid - 1e-9) * grid
        record = SwitchRecord(int(header[Header.PLAN_SEQUENCE]) + 1, before, configuration, requested, activation)
        self.pending = record
        header[Header.PLAN_CONFIGURATION] = sup.reconfiguration.index(configuration)
        header[Header.PLAN_TIME_NS] = int(activation * 1e9)
        header[Header.PLAN_SEQUENCE] = record.sequence  # last: an executive that sees it sees the whole plan
        if sup.lockstep is None:  # the simulated clock's RTPUs read the header every tick anyway
            for queue in sup.signals.values():
                queue.try_send("plan", timeout=0.0)
        entering_active = [t for t in entering if sup.task_states.get(t) == "OFF"]
        deadline = sup.now() + SWITCH_TIMEOUT
        while len(record.applied) < len(sup.signals) or any(t not in record.first_cycles for t in entering_active
                                                             if not getattr(self.subsystem.tasks[t], "aperiodic", False)):
            if sup.now() > deadline:
                raise PboError(f"switch to '{configuration}' did not complete within {SWITCH_TIMEOUT:g} s "
                               f"(applied on: {', '.join(record.applied) or 'no RTPU'})")
            sup.pump(0.002)
        self.pending = None
        sup.set_configuration(configuration)
        self.switches.append(record)
        return record

    def switched(self, rtpu: str, sequence: int, applied_at: float, done_at: float, off: list[str], on: list[str]) -> None:
        """An RTPU's report that it applied a plan."""
        record = self.pending
        if record is None or record.sequence != sequence:
            return
        record.applied[rtpu] = (applied_at, done_at)
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
        sup = self.supervisor
        requested = sup.now()
        record = SwitchRecord(len(self.switches) + 1, before, after, requested, requested, off=list(leaving), on=list(entering))
        for name in leaving:
            sup.signal_and_wait(name, "kill", {"KILLED"})
        for name in [t for t in self.subsystem.init_order if t in entering]:
            if sup.task_states.get(name) in ("NOT_CREATED", "KILLED"):
                sup.respawn(name)
            sup.turn_on(name, after)
        record.applied["job control"] = (requested, sup.now())
        sup.set_configuration(after)
        self.switches.append(record)
        return record

    def alternate(self, configurations: list[str], switches: int, interval: float) -> None:
        """Switch between configurations `switches` times, one every `interval` seconds (a switch test)."""
        sup = self.supervisor
        for name in configurations:
            if name not in self.subsystem.configurations:
                raise PboError(f"no configuration '{name}' (configurations: {', '.join(self.subsystem.configurations)})")
        order = [c for c in configurations if c != sup.configuration] + [c for c in configurations if c == sup.configuration]
        next_at = sup.now() + interval
        for number in range(switches):
            while sup.now() < next_at - sup.tick / 2:
                sup.pump(min(0.002, max(next_at - sup.now(), 0.0)))
            self.switch(order[number % len(order)])
            next_at += interval

    # --- jobs and applications --------------------------------------------------------------

    def run_job(self, name: str, arguments: dict[str, Any], step: str = "") -> None:
        """Pre-condition, object, switch, then wait for the post-condition (or the timeout)."""
        sup = self.supervisor
        job = self.subsystem.jobs[name]
        where = f"job '{name}'{step}"
        self.job = name
        if job.pre:
            holds, values = evaluate(sup, job.pre)
            if not holds:
                raise JobFailure(f"{where}: pre-condition '{job.pre}' does not hold ({_show(values)})")
        for variable, value in arguments.items():
            assert sup.table is not None
            sup.table.write(variable, value, when=sup.now(), writer=-1)
        if job.configuration != sup.configuration:
            self.switch(job.configuration)
        sup.say(f"{where}: running in '{job.configuration}'" + (f", waiting for {job.post}" if job.post else ""))
        if not job.post and not job.timeout:
            return
        started = sup.now()
        while True:
            if job.post:
                holds, values = evaluate(sup, job.post)
                if holds:
                    sup.say(f"{where}: done in {sup.now() - started:.2f} s ({job.post})")
                    return
            if job.timeout and sup.now() - started > job.timeout:
                if not job.post:
                    return  # a job with a timeout and no post-condition runs for that long
                raise JobFailure(f"{where}: timed out after {job.timeout:g} s; post-condition '{job.post}' "
                                 f"still false ({_show(values)})")
            sup.pump(POLL)

    def start_job(self, name: str, arguments: dict[str, Any]) -> None:
        """An operator's job: its object and its configuration now; its post-condition is shown, not awaited."""
        sup = self.supervisor
        job = self.subsystem.jobs[name]
        if job.pre:
            holds, values = evaluate(sup, job.pre)
            if not holds:
                raise JobFailure(f"job '{name}': pre-condition '{job.pre}' does not hold ({_show(values)})")
        assert sup.table is not None
        for variable, value in arguments.items():
            variable_spec = self.subsystem.variables[variable]
            array = np.asarray(value, dtype=variable_spec.dtype)
            if array.size != variable_spec.size:
                raise PboError(f"job '{name}': object '{variable}' takes {variable_spec.size} values "
                               f"(shape {list(variable_spec.shape)}), got {array.size}")
            sup.table.write(variable, array.reshape(variable_spec.shape), when=sup.now(), writer=-1)
        if job.configuration != sup.configuration:
            self.switch(job.configuration)
        self.job = name

    def run_application(self, application: str) -> None:
        spec = self.subsystem.applications[application]
        if not spec.complete:
            raise JobFailure(f"application '{application}' is incomplete (a step lacks its object) and cannot run; "
                             f"see pbo check {self.subsystem.file}")
        self.application = application
        steps = application_steps(self.subsystem, application)
        for number, (job, arguments) in enumerate(steps, start=1):
            self.run_job(job, arguments, step=f" (step {number} of {len(steps)} of application '{application}')")
        self.job = None
