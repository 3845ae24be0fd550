"""FakeJobHost: a running subsystem without a process, for unit tests of job control and the operator's verbs.

It implements `JobHost` (job_control) and `CommandHost` (commands) on a manual clock: variables
are numpy arrays in a dict, tasks are states in a dict, and its RTPUs apply a posted plan when
the clock reaches the plan's activation (as the executives do at that cycle boundary), unless
told they never will. `pump` moves the clock; `on_pump` lets a test change the world meanwhile
(the arm reaching its goal). Live changes are staged (`staged`) and adopted as the supervisor
does; `init_fails` names tasks whose spawn fails. `dies_at` names a (task, op) whose signal kills
its RTPU (once): `restart_rtpu` then brings the RTPU's tasks back as the switch under way has them
(ON where its configuration has them, else not created). Nothing is started, nothing sleeps.

FakeRunLink is the local API's link to one (`api.link.RunLink`), for the API's unit tests.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from pbo_runtime.api.link import NoRun
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.config.model import Subsystem
from pbo_runtime.edit.live import LiveDescription
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import answer
from pbo_runtime.supervisor.commands import dispatch
from pbo_runtime.supervisor.failures import RtpuDied
from pbo_runtime.supervisor.job_control import JobControl
from pbo_runtime.supervisor.status_reply import TaskRow
from pbo_runtime.table.svar import TableView, attach
from pbo_runtime.table.table import SPARE_TASK_SLOTS
from tests.support import REPO

# configs/switch_joint.yaml with jobs for every path of job control: a pre-condition that never
# holds, a job with no object (its trajectory keeps the goal it has), one that only runs for a while
SUBSYSTEM = (REPO / "configs" / "switch_joint.yaml").read_text().replace("\njobs:\n", """
jobs:
  guarded: {configuration: pd, object: none, pre: "max(abs(q_m)) > 10", post: "max(abs(q_m - q_d)) < 0.01"}
  hold:    {configuration: pd, object: none}
  dwell:   {configuration: pd, object: none, timeout: 50 ms}
""")


def fake_subsystem(directory: Path) -> Subsystem:
    path = directory / "switch_joint.yaml"
    path.write_text(SUBSYSTEM)
    return load_subsystem(str(path))


class FakeJobHost:
    """A run as job control and the operator's verbs see it; see the module's docstring."""

    def __init__(self, subsystem: Subsystem, configuration: str | None = None, static: bool = False) -> None:
        self.subsystem = subsystem
        self.configuration = configuration or next(iter(subsystem.configurations))
        self.clock = ManualClock(0.0)
        self.epoch = 0.0
        self.shortest_period = min(t.period for t in subsystem.tasks.values())
        self.stagger = 0.0  # every RTPU on the first one's grid (a test sets another)
        self.tick = 0.0
        self.said: list[str] = []
        self.say: Callable[[str], None] = self.said.append
        self.values = {name: np.zeros(var.shape, dtype=var.dtype) if var.initial is None else np.array(var.initial)
                       for name, var in subsystem.variables.items()}
        members = subsystem.configurations[self.configuration].tasks
        self.task_states = {name: "ON" if name in members else "OFF" for name in subsystem.tasks}
        self.task_errors: dict[str, str] = {}
        self.plans: list[tuple[int, str, float]] = []  # (sequence, configuration, activation) as posted
        self.rtpus_apply_plans = True
        self.posting_delay = 0.0  # how long a switch's request waits before its posting runs
        self.held_in_posting = 0.0  # how long the posting is held off after its first clock reading (once)
        self.in_posting = False
        self.rewrites = 0  # the plan's words written as they were: a posting timed, no plan
        self.read_delay: float | None = None  # each RTPU first reads a plan this long after its request (None: not stamped)
        self.signals: list[tuple[str, str]] = []  # (task, op) as sent
        self.clear_fixes_the_fault = True
        self.on_leaves = "ON"  # OFF: the task's on failed and its error component turned it off
        self.events: list[tuple[str, Any]] = []
        self.stopped_by = ""
        self.on_pump: Callable[[FakeJobHost], None] | None = None
        self.job_control = JobControl(self, static=static)
        # what the operator's status reads
        self.run_id = "1234-abcdef"
        self.application: str | None = None
        self.started_at: float | None = 0.0
        self.realtime: dict[str, dict[str, str]] = {}
        # live changes
        self.live: LiveDescription | None = LiveDescription.start(subsystem, len(subsystem.tasks) + SPARE_TASK_SLOTS)
        self.staged: Subsystem | None = None
        self.init_fails: set[str] = set()
        self.dies_at: set[tuple[str, str]] = set()  # (task, op): that signal kills the task's RTPU, once
        self.started_applications: list[str] = []

    # --- JobHost ----------------------------------------------------------------------------

    def now(self) -> float:
        now = self.clock.now()
        if self.in_posting and self.held_in_posting:
            self.clock.advance(self.held_in_posting)
            self.held_in_posting = 0.0
        return now

    def pump(self, timeout: float) -> None:
        self.clock.advance(timeout)
        if self.on_pump is not None:
            self.on_pump(self)
        record = self.job_control.pending
        if record is None or not self.rtpus_apply_plans or self.now() < record.activation:
            return
        planned = self.staged or self.subsystem  # a live change's plan applies its staged description
        after = planned.configurations[record.after].tasks
        before = self.subsystem.configurations[record.before].tasks
        for rtpu in self.subsystem.rtpus:
            hosted = list(dict.fromkeys(t.name for s in (self.subsystem, planned) for t in s.tasks_on(rtpu.name)))
            off = [t for t in hosted if t in before and t not in after]
            on = [t for t in hosted if t in after and self.task_states[t] == "OFF"]
            for task in off:
                self.task_states[task] = "OFF"
            for task in on:
                self.task_states[task] = "ON"
                self.job_control.first_cycle(record.sequence, task, record.activation)
            read_at = record.posted_at + self.read_delay if self.read_delay is not None else 0.0
            self.job_control.switched(rtpu.name, record.sequence, record.activation, record.activation, off, on, read_at)

    def read_variable(self, name: str) -> np.ndarray:
        return self.values[name]

    def write_variable(self, name: str, value: Any) -> None:
        self.values[name] = np.asarray(value, dtype=self.subsystem.variables[name].dtype)

    def post_plan(self, configuration: str, activation: float) -> int:
        assert self.in_posting or self.tick > 0, "a plan on the real clock is posted inside the host's posting()"
        sequence = len(self.plans) + 1
        self.plans.append((sequence, configuration, activation))
        return sequence

    def rewrite_plan(self) -> None:
        assert self.in_posting, "a posting is timed inside the host's posting()"
        self.rewrites += 1

    @contextmanager
    def posting(self) -> Iterator[None]:
        self.clock.advance(self.posting_delay)  # the request waited this long for a CPU
        self.in_posting = True
        try:
            yield
        finally:
            self.in_posting = False

    def wake_rtpus(self) -> None:
        pass  # each fake RTPU reads a plan `read_delay` after it was posted

    def set_configuration(self, configuration: str) -> None:
        self.configuration = configuration

    def _maybe_die(self, task: str, op: str) -> None:
        if (task, op) in self.dies_at:
            self.dies_at.discard((task, op))
            rtpu = self.subsystem.tasks[task].rtpu
            raise RtpuDied(f"RTPU '{rtpu}' (pid 1) died (killed by SIGABRT)", rtpu, 1, "killed by SIGABRT")

    def restart_rtpu(self, death: RtpuDied) -> None:
        self.signals.append((death.rtpu, "restart"))
        switch = self.job_control.switching
        members = self.subsystem.configurations[self.configuration if switch is None else switch.after].tasks
        for spec in self.subsystem.tasks_on(death.rtpu):
            self.task_states[spec.name] = "ON" if spec.name in members else "NOT_CREATED"
        if switch is not None:
            switch.restarted.append(death.rtpu)

    def kill_task(self, task: str) -> None:
        self.signals.append((task, "kill"))
        self._maybe_die(task, "kill")
        self.task_states[task] = "KILLED"

    def respawn(self, task: str) -> None:
        self.signals.append((task, "spawn"))
        self._maybe_die(task, "spawn")
        if task in self.init_fails:
            self.task_states[task] = "KILLED"
            raise PboError(f"task '{task}' failed in init and was not created: the fake's init_fails")
        self.task_states[task] = "OFF"

    def turn_on(self, task: str, configuration: str) -> None:
        self.signals.append((task, "on"))
        self._maybe_die(task, "on")
        self.task_states[task] = "ON"

    def hold_critical_tasks(self, hold: bool) -> None:
        self.signals.append(("critical tasks", "hold" if hold else "release"))

    def watch(self, task: str, configuration: str) -> None:
        self.signals.append((task, f"watch {configuration}"))

    def stage_live(self, live: LiveDescription) -> None:
        self.signals.append(("every RTPU", f"live {', '.join(live.subsystem.tasks)}"))
        self.staged = live.subsystem
        for name in live.subsystem.tasks:
            self.task_states.setdefault(name, "NOT_CREATED")

    def adopt(self, live: LiveDescription) -> None:
        self.live, self.subsystem, self.staged = live, live.subsystem, None

    # --- CommandHost ------------------------------------------------------------------------

    def start_application(self, name: str) -> None:
        self.started_applications.append(name)

    def status_rows(self) -> list[TaskRow]:
        return [TaskRow(t.name, t.rtpu, self.task_states[t.name], cycles=100) for t in self.subsystem.tasks.values()]

    def table_flags(self) -> list[str]:
        return ["ILLEGAL_CONFIGURATION"] if "ERROR" in self.task_states.values() else []

    def stalled_since(self) -> dict[str, float]:
        return {}

    def restarts(self) -> list[dict]:
        return []

    def signal_task(self, task: str, op: str, states: set[str]) -> str:
        self.signals.append((task, op))
        if op == "on":
            self.task_states[task] = self.on_leaves
        elif op == "off" or (op == "clear" and self.clear_fixes_the_fault):
            self.task_states[task] = "OFF"
        assert self.task_states[task] in states
        return self.task_states[task]

    def send_event(self, task: str, values: Any) -> None:
        self.events.append((task, values))

    def request_stop(self, reason: str) -> None:
        self.stopped_by = reason


class FakeRunLink:
    """A unit test's run: verbs served by `commands.dispatch` on a fake job host, as the supervisor
    answers them (`ipc.control.answer`), and a real table made by the test."""

    def __init__(self, host: FakeJobHost, table: str | None = None, subsystem: str = "fake") -> None:
        self.host = host
        self.table = table
        self.subsystem = subsystem
        self.requests: list[tuple[str, dict[str, Any]]] = []

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        self.requests.append((command, dict(arguments)))
        return answer(lambda c, a: dispatch(self.host, c, a), command, arguments)

    def open_table(self) -> TableView:
        if self.table is None:
            raise NoRun("no subsystem is running")
        return attach(self.table, self.subsystem, "1234-abcdef")

    def runs(self) -> list[dict[str, Any]]:
        return [{"subsystem": self.subsystem, "run_id": "1234-abcdef"}]
