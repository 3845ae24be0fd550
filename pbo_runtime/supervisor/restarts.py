"""A dead RTPU restarted alone, within its restart policy (`restart: {max: 3, within: 10 s}`).

The decisions are pure functions of the run's state: `may_restart` (restart, or stop the run),
`count_death` (past the policy, or not) and `restart_plan` (which of its tasks come back spawned,
which ON, in which configuration). `Restarter` carries them out: a new process from the RTPU's
launch description (`restarted` set), its tasks spawned in const order and turned on at a cycle
boundary, while the other RTPUs run on.
docs/faults.md says what the operator sees, during a switch and on the simulated clock too.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from pbo_runtime.clock.run_clock import RunClock
from pbo_runtime.config.model import RestartPolicy, RtpuSpec, Subsystem, TaskSpec
from pbo_runtime.ipc import messages
from pbo_runtime.supervisor.children import Child
from pbo_runtime.supervisor.failures import RtpuDied, RunFailure
from pbo_runtime.supervisor.job_control import JobControl
from pbo_runtime.supervisor.launch import RtpuLaunch
from pbo_runtime.supervisor.run_report import RunResult
from pbo_runtime.table.table import Header, StateTable


@dataclass
class Restart:
    """One death of an RTPU and its way back."""

    rtpu: str
    pid: int
    cause: str  # "killed by SIGKILL", "exit status 3"
    died_at: float  # when the death was noticed: seconds since the configuration came on
    tasks_on: tuple[str, ...]  # what was ON, and is turned on again
    on_again_at: float | None = None  # when its tasks were all ON again, likewise (None: the run stopped first)
    attempts: int = 1  # launches it took (a new process that died at once takes another)
    launched_at: float | None = None  # when the new process was started (forked), likewise
    ready_at: float | None = None  # when the new process said it was ready, likewise
    spawned_at: float | None = None  # when its tasks had all been spawned (their inits done), likewise
    origin: float = 0.0  # the run time these times count from (the configuration's on, or this start-up's death)

    def to_json(self) -> dict[str, Any]:
        seconds = None if self.on_again_at is None else self.on_again_at - self.died_at
        return {"rtpu": self.rtpu, "pid": self.pid, "cause": self.cause, "died_at": self.died_at,
                "on_again_at": self.on_again_at, "seconds": seconds, "tasks_on": list(self.tasks_on),
                "attempts": self.attempts, "launched_at": self.launched_at, "ready_at": self.ready_at,
                "spawned_at": self.spawned_at}


def may_restart(role: str, rtpus: Sequence[RtpuSpec], table_made: bool, stop_requested: str) -> bool:
    """Whether a death of `role` is restarted rather than stopping the run: an RTPU with a policy, once
    the run's table exists, unless the run is stopping."""
    if role == "plant" or not table_made or stop_requested:
        return False
    spec = next((r for r in rtpus if r.name == role), None)
    return spec is not None and spec.restart is not None


def count_death(deaths: Sequence[float], now: float, policy: RestartPolicy) -> tuple[list[float], bool]:
    """The deaths within the policy's window once this one (at `now`) is counted, and whether they are
    past the policy (the run then stops)."""
    within = [t for t in [*deaths, now] if now - t <= policy.within]
    return within, len(within) > policy.max


@dataclass(frozen=True)
class RestartPlan:
    """What a restart brings back: tasks spawned (const order), those turned on, and in which configuration."""

    spawn: list[str]
    turn_on: tuple[str, ...]
    configuration: str


def restart_plan(hosted: Sequence[str], states: Mapping[str, str], configuration: str,
                 switching_to: Sequence[str] | None = None, static: bool = False) -> RestartPlan:
    """The dead RTPU's tasks (`hosted`, those of the description the new process knows) as they were:
    spawned if they were alive, ON where they were ON. During a switch (`switching_to`: the members of
    the configuration it goes to, named `configuration`), as that configuration has them: its members
    ON, and, static, only they spawned."""
    alive = [t for t in hosted if states.get(t) not in (None, "NOT_CREATED", "KILLED")]
    if switching_to is None:
        return RestartPlan(alive, tuple(t for t in hosted if states.get(t) == "ON"), configuration)
    if static:  # only the new configuration's tasks exist; dynamic: what was spawned stays spawned
        alive = [t for t in hosted if t in switching_to]
    return RestartPlan(alive, tuple(t for t in alive if t in switching_to), configuration)


@dataclass(frozen=True)
class RunView:
    """What a restart reads of the run as it is now (the description and configuration change as it goes)."""

    subsystem: Callable[[], Subsystem]  # the description the run lives by
    configuration: Callable[[], str]  # the running configuration
    started_at: Callable[[], float | None]  # run time when the configuration came on
    table: Callable[[], StateTable | None]  # the run's table, once made
    stop_requested: Callable[[], str]  # why the run is asked to stop ("" while it is not)
    live: Callable[[], tuple[int, int]]  # the live descriptions staged last and adopted (live-N.json; 0: the file)
    now: Callable[[], float]


@dataclass(frozen=True)
class RunSteps:
    """What a restart does through the rest of the supervisor."""

    launch: Callable[[str, list[str], tuple[str, ...]], None]  # start a child (role, `-m MODULE ...`, its tasks)
    await_ready: Callable[[set[str]], None]
    list_children: Callable[[], None]  # the table's manifest names the live children
    respawn: Callable[[str], None]  # spawn a task and wait for its init
    turn_on: Callable[[str, str], None]  # turn a task on in a configuration
    take_one_event: Callable[[float], None]
    while_stepping: Callable[[], None]
    while_ticking: Callable[[], None]


class Restarter:
    """The supervisor's part that brings a dead RTPU back; it keeps each RTPU's deaths in its policy's window."""

    def __init__(self, run: RunView, steps: RunSteps, clock: RunClock, result: RunResult, job_control: JobControl,
                 children: list[Child], task_states: dict[str, str], task_errors: dict[str, str],
                 every_task: dict[str, TaskSpec], signals: dict[str, messages.Queue],
                 launched: dict[str, tuple[list[str], tuple[str, ...]]], rtpu_launches: dict[str, RtpuLaunch],
                 static: bool, say: Callable[[str], None]) -> None:
        self.run = run
        self.steps = steps
        self.clock = clock
        self.result = result
        self.job_control = job_control  # its `switching` is the switch under way, if any
        # the run's own collections, shared with the parts that fill them
        self.children = children
        self.task_states = task_states
        self.task_errors = task_errors
        self.every_task = every_task  # every task the run has had, by name
        self.signals = signals
        self.launched = launched
        self.rtpu_launches = rtpu_launches
        self.static = static
        self.say = say
        self.deaths: dict[str, list[float]] = {}  # per RTPU, when it died within its policy's window

    def may_restart(self, role: str) -> bool:
        """Whether a death of `role` is restarted rather than stopping the run."""
        return may_restart(role, self.run.subsystem().rtpus, self.run.table() is not None, self.run.stop_requested())

    def restart_rtpu(self, death: RtpuDied) -> None:
        """Bring the dead RTPU's tasks back as they were: spawned, and ON where they were ON; during a
        switch, as the configuration the switch goes to has them."""
        switch = self.job_control.switching
        # what the new process knows: the running description, or the one a live change's plan swaps in
        described = self.run.subsystem() if switch is None or not switch.change else self.job_control.switching_subsystem
        staged, adopted = self.run.live()
        live = staged if switch is not None and switch.change else adopted
        hosted = [t for t in self._hosted_by(death.rtpu) if t in described.tasks]
        configuration = self.run.configuration() if switch is None else switch.after
        members = None if switch is None else described.configurations[configuration].tasks
        plan = restart_plan(hosted, self.task_states, configuration, members, self.static)
        alive, was_on = plan.spawn, plan.turn_on
        started_at = self.run.started_at()
        started = started_at if started_at is not None else self.run.now()
        record = Restart(death.rtpu, death.pid, death.cause, self.run.now() - started, was_on, origin=started)
        self.result.restarts.append(record)
        during = "" if switch is None else f" in '{configuration}', the configuration it was switching to"
        self.say(f"{death}; restarting it{during}")
        self.relaunch(death, record, live)
        if switch is not None:
            switch.restarted.append(death.rtpu)
        while True:
            try:
                record.ready_at = self.run.now() - started
                self.bring_up(alive, [])
                record.spawned_at = self.run.now() - started
                if switch is not None:
                    self._until_activation(switch.activation)
                self.bring_up(alive, list(was_on), configuration)
                break
            except RtpuDied as again:
                if again.rtpu != death.rtpu:
                    raise RunFailure(f"{again}, while RTPU '{death.rtpu}' was restarting") from None
                record.attempts += 1
                self.relaunch(again, record, live)
        record.on_again_at = self.run.now() - started
        self.say(f"RTPU '{death.rtpu}' restarted: {', '.join(was_on) or 'no task'} ON again after "
                 f"{(record.on_again_at - record.died_at) * 1e3:.0f} ms")

    def bring_up(self, spawn: list[str], turn_on: list[str], configuration: str | None = None) -> None:
        """Spawn the tasks not yet created (in const order), then turn on those not ON (critical first),
        in `configuration` (default: the running one)."""
        for name in self._in_init_order(spawn):
            if self.task_states.get(name) == "NOT_CREATED":
                self.steps.respawn(name)
        for name in sorted(self._in_init_order(turn_on), key=lambda t: not self.every_task[t].critical):
            if self.task_states.get(name) != "ON":
                self.steps.turn_on(name, configuration or self.run.configuration())

    def _until_activation(self, activation: float) -> None:
        """A dynamic switch's tasks come on at its activation, not before: wait for it (a restart takes far
        longer than a plan's lead, so this is a safeguard), taking events meanwhile."""
        while self.run.now() < activation:  # (on the simulated clock, the ticks up to it)
            self.clock.run_for(activation - self.run.now(), self.steps.take_one_event, self.steps.while_stepping,
                               self.steps.while_ticking)

    def relaunch(self, death: RtpuDied, record: Restart, live: int = 0) -> None:
        """Count the death against the policy (RunFailure past it), then start a new process for the RTPU
        (`live`: the live description it starts from, live-N.json; 0: the subsystem's file)."""
        while True:
            self._count_death(death, record)
            for child in [c for c in self.children if c.role == death.rtpu]:
                self.children.remove(child)
            for task in self._hosted_by(death.rtpu):
                self.task_states[task] = "NOT_CREATED"  # the new process knows none of them
                self.task_errors.pop(task, None)
            self.steps.list_children()
            # a process that died applying a plan (a task's `on` crashed) left its "switching since" word
            # set: the critical tasks would take the configuration for illegal, for good
            index = next(r.index for r in self.run.subsystem().rtpus if r.name == death.rtpu)
            table = self.run.table()
            assert table is not None  # (restarts apply once the run's table exists)
            table.header[int(Header.SWITCHING_SINCE_NS) + index] = 0
            self.clock.stop_ring(death.rtpu, self.steps.while_ticking)  # the simulated clock's ticks, where they stood
            queue = self.signals[death.rtpu]
            while queue.receive(0) is not None:  # what the dead process never served is not for the new one
                pass
            _, tasks = self.launched[death.rtpu]
            # its tasks continue the run's files (a data log); after live changes, the file no longer describes the run
            launch = replace(self.rtpu_launches[death.rtpu], restarted=True, live_now=live)
            self.steps.launch(death.rtpu, ["-m", "rtpu", *launch.to_argv()], tasks)
            record.launched_at = self.run.now() - record.origin
            self.clock.forget_turn(death.rtpu)  # a hand-over to the dead one may land after the ring stopped
            try:
                self.steps.await_ready({death.rtpu})
                self.clock.finish_tick(self.steps.while_ticking)  # the others' share of the tick the death cut
                return
            except RtpuDied as again:
                if again.rtpu != death.rtpu:
                    raise RunFailure(f"{again}, while RTPU '{death.rtpu}' was restarting") from None
                record.attempts += 1
                death = again

    def _count_death(self, death: RtpuDied, record: Restart) -> None:
        policy = next(r for r in self.run.subsystem().rtpus if r.name == death.rtpu).restart
        assert policy is not None
        deaths, past_policy = count_death(self.deaths.get(death.rtpu, []), self.run.now(), policy)
        self.deaths[death.rtpu] = deaths
        if past_policy:
            raise RunFailure(f"{death}: it died {len(deaths)} times within {policy.within:g} s, more than its restart "
                             f"policy allows (restart: {{max: {policy.max}, within: {policy.within:g} s}}), so the run stops")

    def _hosted_by(self, rtpu: str) -> list[str]:
        return [name for name, spec in self.every_task.items() if spec.rtpu == rtpu]

    def _in_init_order(self, tasks: list[str]) -> list[str]:
        """Const producers before their consumers; tasks spawned live (not in the file's order) last."""
        order = {name: i for i, name in enumerate(self.run.subsystem().init_order)}
        return sorted(tasks, key=lambda t: order.get(t, len(order)))


def restart_lines(restarts: list[dict[str, Any]]) -> list[str]:
    """The summary's lines: each restart, its cause, and the time from the death to its tasks ON again."""
    lines = []
    for r in restarts:
        back = ("not back before the run stopped" if r["seconds"] is None
                else f"tasks ON again after {r['seconds'] * 1e3:.0f} ms")
        tries = f" ({r['attempts']} launches)" if r.get("attempts", 1) > 1 else ""
        lines.append(f"RTPU '{r['rtpu']}' restarted, {r['died_at']:.2f} s into the run: pid {r['pid']} {r['cause']}; "
                     f"{back}{tries}")
    return lines
