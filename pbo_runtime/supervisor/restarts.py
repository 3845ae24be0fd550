"""A dead RTPU restarted alone, within its restart policy (`restart: {max: 3, within: 10 s}`).

The decisions are pure functions of the run's state: `count_death` (past the policy, or not) and
`restart_plan` (which of its tasks come back spawned, which ON, in which configuration). `Restarts`
carries them out: a new process from the RTPU's launch description (`restarted` set), its tasks
spawned in const order and turned on at a cycle boundary, while the other RTPUs run on.
docs/faults.md says what the operator sees, during a switch and on the simulated clock too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping, Sequence

from pbo_runtime.config.model import RestartPolicy, RtpuSpec, Subsystem
from pbo_runtime.ipc import messages
from pbo_runtime.supervisor.failures import RtpuDied, RunFailure
from pbo_runtime.supervisor.launch import RtpuLaunch
from pbo_runtime.supervisor.run_report import RunResult
from pbo_runtime.table.table import Header


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
                "attempts": self.attempts, "launched_at": self.launched_at, "ready_at": self.ready_at, "spawned_at": self.spawned_at}


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


class Restarting:
    """The Supervisor's part that brings a dead RTPU back."""

    subsystem: Subsystem
    result: RunResult
    table: Any
    clock: Any
    children: list[Any]
    launched: dict[str, tuple[list[str], tuple[str, ...]]]
    rtpu_launches: dict[str, RtpuLaunch]
    task_states: dict[str, str]
    task_errors: dict[str, str]
    every_task: dict[str, Any]
    signals: dict[str, messages.Queue]
    configuration: str
    started_at: float | None
    _stop_requested: str
    say: Callable[[str], None]
    now: Callable[[], float]
    respawn: Callable[[str], None]
    turn_on: Callable[[str, str], None]
    _launch: Callable[..., None]
    _await_ready: Callable[[set[str]], None]
    _list_children: Callable[[], None]
    _take_one_event: Callable[[float], None]
    _while_stepping: Callable[[], None]
    _while_ticking: Callable[[], None]
    _deaths: dict[str, list[float]]  # per RTPU, when it died within its policy's window
    job_control: Any  # supervisor.job_control.JobControl: its `switching` is the switch under way, if any
    static: bool
    _live_sequence: int  # the live description staged last (live-N.json)
    _live_adopted: int  # the one the run lives by (0: the file)

    def may_restart(self, role: str) -> bool:
        """Whether a death of `role` is restarted rather than stopping the run."""
        return may_restart(role, self.subsystem.rtpus, self.table is not None, self._stop_requested)

    def restart_rtpu(self, death: RtpuDied) -> None:
        """Bring the dead RTPU's tasks back as they were: spawned, and ON where they were ON; during a
        switch, as the configuration the switch goes to has them."""
        switch = self.job_control.switching
        # what the new process knows: the running description, or the one a live change's plan swaps in
        described = self.subsystem if switch is None or not switch.change else self.job_control.switching_subsystem
        live = self._live_sequence if switch is not None and switch.change else self._live_adopted
        hosted = [t for t in self._hosted_by(death.rtpu) if t in described.tasks]
        configuration = self.configuration if switch is None else switch.after
        members = None if switch is None else described.configurations[configuration].tasks
        plan = restart_plan(hosted, self.task_states, configuration, members, self.static)
        alive, was_on = plan.spawn, plan.turn_on
        started = self.started_at if self.started_at is not None else self.now()
        record = Restart(death.rtpu, death.pid, death.cause, self.now() - started, was_on, origin=started)
        self.result.restarts.append(record)
        during = "" if switch is None else f" in '{configuration}', the configuration it was switching to"
        self.say(f"{death}; restarting it{during}")
        self.relaunch(death, record, live)
        if switch is not None:
            switch.restarted.append(death.rtpu)
        while True:
            try:
                record.ready_at = self.now() - started
                self.bring_up(alive, [])
                record.spawned_at = self.now() - started
                if switch is not None:
                    self._until_activation(switch.activation)
                self.bring_up(alive, list(was_on), configuration)
                break
            except RtpuDied as again:
                if again.rtpu != death.rtpu:
                    raise RunFailure(f"{again}, while RTPU '{death.rtpu}' was restarting") from None
                record.attempts += 1
                self.relaunch(again, record, live)
        record.on_again_at = self.now() - started
        self.say(f"RTPU '{death.rtpu}' restarted: {', '.join(was_on) or 'no task'} ON again after "
                 f"{(record.on_again_at - record.died_at) * 1e3:.0f} ms")

    def bring_up(self, spawn: list[str], turn_on: list[str], configuration: str | None = None) -> None:
        """Spawn the tasks not yet created (in const order), then turn on those not ON (critical first),
        in `configuration` (default: the running one)."""
        for name in self._in_init_order(spawn):
            if self.task_states.get(name) == "NOT_CREATED":
                self.respawn(name)
        for name in sorted(self._in_init_order(turn_on), key=lambda t: not self.every_task[t].critical):
            if self.task_states.get(name) != "ON":
                self.turn_on(name, configuration or self.configuration)

    def _until_activation(self, activation: float) -> None:
        """A dynamic switch's tasks come on at its activation, not before: wait for it (a restart takes far
        longer than a plan's lead, so this is a safeguard), taking events meanwhile."""
        while self.now() < activation:  # (on the simulated clock, the ticks up to it)
            self.clock.run_for(activation - self.now(), self._take_one_event, self._while_stepping, self._while_ticking)

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
            self._list_children()
            # a process that died applying a plan (a task's `on` crashed) left its "switching since" word
            # set: the critical tasks would take the configuration for illegal, for good
            index = next(r.index for r in self.subsystem.rtpus if r.name == death.rtpu)
            self.table.header[int(Header.SWITCHING_SINCE_NS) + index] = 0
            self.clock.stop_ring(death.rtpu, self._while_ticking)  # the simulated clock's ticks, where they stood
            queue = self.signals[death.rtpu]
            while queue.receive(0) is not None:  # what the dead process never served is not for the new one
                pass
            _, tasks = self.launched[death.rtpu]
            # its tasks continue the run's files (a data log); after live changes, the file no longer describes the run
            launch = replace(self.rtpu_launches[death.rtpu], restarted=True, live_now=live)
            self._launch(death.rtpu, ["-m", "rtpu", *launch.to_argv()], tasks)
            record.launched_at = self.now() - record.origin
            self.clock.forget_turn(death.rtpu)  # a hand-over to the dead one may land after the ring stopped
            try:
                self._await_ready({death.rtpu})
                self.clock.finish_tick(self._while_ticking)  # the others' share of the tick the death cut
                return
            except RtpuDied as again:
                if again.rtpu != death.rtpu:
                    raise RunFailure(f"{again}, while RTPU '{death.rtpu}' was restarting") from None
                record.attempts += 1
                death = again

    def _count_death(self, death: RtpuDied, record: Restart) -> None:
        policy = next(r for r in self.subsystem.rtpus if r.name == death.rtpu).restart
        assert policy is not None
        deaths, past_policy = count_death(self._deaths.get(death.rtpu, []), self.now(), policy)
        self._deaths[death.rtpu] = deaths
        if past_policy:
            raise RunFailure(f"{death}: it died {len(deaths)} times within {policy.within:g} s, more than its restart "
                             f"policy allows (restart: {{max: {policy.max}, within: {policy.within:g} s}}), so the run stops")

    def _hosted_by(self, rtpu: str) -> list[str]:
        return [name for name, spec in self.every_task.items() if spec.rtpu == rtpu]

    def _in_init_order(self, tasks: list[str]) -> list[str]:
        """Const producers before their consumers; tasks spawned live (not in the file's order) last."""
        order = {name: i for i, name in enumerate(self.subsystem.init_order)}
        return sorted(tasks, key=lambda t: order.get(t, len(order)))


def restart_lines(restarts: list[dict[str, Any]]) -> list[str]:
    """The summary's lines: each restart, its cause, and the time from the death to its tasks ON again."""
    lines = []
    for r in restarts:
        back = ("not back before the run stopped" if r["seconds"] is None
                else f"tasks ON again after {r['seconds'] * 1e3:.0f} ms")
        tries = f" ({r['attempts']} launches)" if r.get("attempts", 1) > 1 else ""
        lines.append(f"RTPU '{r['rtpu']}' restarted, {r['died_at']:.2f} s into the run: pid {r['pid']} {r['cause']}; {back}{tries}")
    return lines
