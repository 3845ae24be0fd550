"""Dynamic reconfiguration across two RTPUs, simulated deterministically: no lost cycles (TR §4.4).

Two executives share one real table and one manual clock; a tiny discrete-event loop always
steps the one whose next event (a release or a plan's activation) comes first. Job control's
part is played by writing the plan into the table's header, as the supervisor does. Nothing
here sleeps or depends on the machine's timing, so the counts are exact.
"""

from __future__ import annotations

import math
import threading
from types import SimpleNamespace

import pytest

from pbo_runtime import InVar, OutVar, PortBasedObject, Status, sleep_while_cycling
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.config.loader import check_file
from pbo_runtime.edit.live import LiveDescription, TaskChange, to_wire
from pbo_runtime.ipc import messages
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.table.table import Header, StateTable, TableLayout, TaskState
from pbo_runtime.task.lifecycle import Task
from rtpu._executive import Executive
from rtpu.holds import HELD_ILLEGAL, NOT_HELD
from rtpu.releases import first_release
from tests.support import IdleSignals, step_executives, unique_name, until

PERIOD = 0.001
STAGGER = 0.00045


class FakeControllerA(PortBasedObject):
    """Fake module: writes +1 (its identity) into u every cycle."""

    u = OutVar("u")

    def cycle(self) -> Status:
        self.u = 1.0
        return Status.CONTINUE


class FakeControllerB(FakeControllerA):
    """Fake module: writes -1 into u every cycle."""

    def cycle(self) -> Status:
        self.u = -1.0
        return Status.CONTINUE


class FakeActuator(PortBasedObject):
    """Fake critical module: records what it read; holds still while the configuration is illegal."""

    u = InVar("u")
    y = OutVar("y")

    def init(self, params) -> None:
        self.seen: list[float] = []
        self.stable = 0

    def cycle(self) -> Status:
        self.seen.append(float(self.u))
        self.y = self.u
        return Status.CONTINUE

    def stable_cycle(self) -> Status:
        self.stable += 1
        return Status.CONTINUE


LIBRARY = {"a": FakeControllerA, "b": FakeControllerB, "actuator": FakeActuator}

TEXT = """\
subsystem: switching
rtpus: [rtpu0, rtpu1]
variables:
  u: {type: float64}
  y: {type: float64}
tasks:
  actuator: {module: actuator, rtpu: rtpu1, period: 1 ms, critical: true}
  ctl_a:    {module: a, rtpu: rtpu0, period: 1 ms}
  ctl_b:    {module: b, rtpu: rtpu0, period: 1 ms}
configurations:
  with_a: [actuator, ctl_a]
  with_b: [actuator, ctl_b]
"""


@pytest.fixture
def rig(tmp_path, make_table):
    path = tmp_path / "switching.yaml"
    path.write_text(TEXT)
    result = check_file(path, module_lookup=LIBRARY.__getitem__, module_names=lambda: sorted(LIBRARY))
    assert result.errors == []
    subsystem = result.subsystem
    table = StateTable.create(TableLayout.of(subsystem), unique_name())
    clock = ManualClock(1.0)
    events: list[tuple[str, messages.Event]] = []
    executives = {}
    for rtpu in subsystem.rtpus:
        ex = Executive(clock, IdleSignals(clock), lambda e, r=rtpu.name: events.append((r, e)),
                       epoch=rtpu.index * STAGGER, header=table.header, reconfiguration=Reconfiguration(subsystem),
                       rtpu_index=rtpu.index, n_rtpus=len(subsystem.rtpus))
        for spec in subsystem.tasks_on(rtpu.name):
            ex.add(Task(spec, LIBRARY[spec.module], table))
        executives[rtpu.name] = ex
    yield subsystem, table, clock, executives, events
    table.close()


def start(subsystem, executives, clock) -> None:
    recon = Reconfiguration(subsystem)
    for name in subsystem.init_order:
        executives[subsystem.tasks[name].rtpu].handle(["spawn", name])
    for name in ("actuator", "ctl_a"):
        executives[subsystem.tasks[name].rtpu].handle(["on", name, clock.now(), recon.index("with_a")])


def post_plan(table: StateTable, configuration: int, activation: float) -> None:
    header = table.header
    header[Header.PLAN_CONFIGURATION] = configuration
    header[Header.PLAN_TIME_NS] = round(activation * 1e9)
    header[Header.PLAN_SEQUENCE] += 1


def test_two_hundred_switches_lose_no_cycle_of_the_critical_task(rig):
    subsystem, table, clock, executives, events = rig
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.01)
    actuator = executives["rtpu1"].tasks["actuator"]
    recon = Reconfiguration(subsystem)
    target = "with_b"
    for _ in range(200):
        # like the supervisor: activate on the first RTPU's release grid, a few periods ahead
        activation = math.ceil((clock.now() + 0.004) / PERIOD) * PERIOD
        post_plan(table, recon.index(target), activation)
        step_executives(executives, clock, activation + 0.010)
        active = "ctl_b" if target == "with_b" else "ctl_a"
        idle = "ctl_a" if active == "ctl_b" else "ctl_b"
        assert executives["rtpu0"].tasks[active].task.state is TaskState.ON
        assert executives["rtpu0"].tasks[idle].task.state is TaskState.OFF
        target = "with_a" if target == "with_b" else "with_b"
    assert actuator.lost_to_switch == 0, actuator.last_lost
    assert actuator.stale_reads == 0, actuator.last_stale
    assert actuator.stable_cycles == 0
    switched = [e for _, e in events if isinstance(e, messages.Switched)]
    assert len(switched) == 2 * 200  # every RTPU applied every plan
    # each pair of reports for one plan: both RTPUs applied it at the activation instant
    by_plan: dict[int, list[float]] = {}
    for e in switched:
        by_plan.setdefault(e.sequence, []).append(e.applied_at)
    assert all(max(t) - min(t) < 1e-9 for t in by_plan.values())
    # what the actuator read flips exactly at the switches: +1 from ctl_a, -1 from ctl_b, never 0
    seen = actuator.task.module.seen
    assert set(seen) == {1.0, -1.0}


def test_the_entering_task_runs_its_first_cycle_at_the_activation_instant(rig):
    subsystem, table, clock, executives, events = rig
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.005)
    activation = math.ceil((clock.now() + 0.004) / PERIOD) * PERIOD
    post_plan(table, Reconfiguration(subsystem).index("with_b"), activation)
    step_executives(executives, clock, activation + 0.005)
    first = [e for _, e in events if isinstance(e, messages.FirstCycle)]
    assert first and first[-1].task == "ctl_b" and first[-1].at == pytest.approx(activation)


def test_the_leaving_task_runs_no_cycle_at_the_activation_boundary_issue_23(rig):
    subsystem, table, clock, executives, _events = rig
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.005)
    leaving = executives["rtpu0"].tasks["ctl_a"]
    activation = math.ceil((clock.now() + 0.004) / PERIOD) * PERIOD
    post_plan(table, Reconfiguration(subsystem).index("with_b"), activation)
    step_executives(executives, clock, activation - 0.0003)
    executives["rtpu0"].run_once()  # as on the real clock: it waits from before the boundary, then runs it
    assert clock.now() == pytest.approx(activation)
    assert leaving.task.state is TaskState.OFF
    assert leaving.last_release == pytest.approx(activation - PERIOD)  # its last cycle: the boundary before


@pytest.mark.parametrize("late", ["rtpu0", "rtpu1"])
def test_an_rtpu_that_reads_the_plan_after_its_activation_applies_it_before_its_next_cycle(rig, late):
    """rtpu0 hosts the controllers, rtpu1 the critical consumer; the late one was stalled (not
    stepped) from before the activation until 0.3 ms past it, so it reads the plan late."""
    subsystem, table, clock, executives, events = rig
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.005)
    activation = math.ceil((clock.now() + 0.004) / PERIOD) * PERIOD
    step_executives(executives, clock, activation - 0.0008)
    post_plan(table, Reconfiguration(subsystem).index("with_b"), activation)
    on_time = {name: ex for name, ex in executives.items() if name != late}
    step_executives(on_time, clock, activation + 0.0003)
    step_executives(executives, clock, activation + 0.010)
    switched = {rtpu: e for rtpu, e in events if isinstance(e, messages.Switched)}
    assert switched[late].activation == switched["rtpu0" if late == "rtpu1" else "rtpu1"].activation == pytest.approx(activation)
    assert switched[late].applied_at == pytest.approx(activation + 0.0003)  # at once when it ran again: late, and says so
    assert executives["rtpu0"].tasks["ctl_a"].last_release < activation  # no cycle of the old configuration after it
    assert executives["rtpu0"].tasks["ctl_b"].task.state is TaskState.ON
    actuator = executives["rtpu1"].tasks["actuator"]
    # the consumer's first read after the activation (at +0.45 ms, or at +0.3 ms when it was the late one) is ctl_b's
    assert actuator.task.module.seen[-10:] == [-1.0] * 10
    assert actuator.lost_to_switch == 0 and actuator.stable_cycles == 0


@pytest.mark.parametrize("meanwhile", [["off", "ctl_a"], ["on", "ctl_b", None, None]])
def test_a_plan_read_ahead_is_read_again_at_its_boundary_when_a_signal_changed_the_tasks_meanwhile(rig, meanwhile):
    """rtpu0 reads the plan to with_b when it first sees it (ctl_a leaves, ctl_b enters); an operator's
    signal then turns ctl_a off, or ctl_b on, before the activation: the boundary switches the tasks
    as they are then, neither turning off a task already off nor on one already on."""
    subsystem, table, clock, executives, events = rig
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.005)
    activation = math.ceil((clock.now() + 0.004) / PERIOD) * PERIOD
    post_plan(table, Reconfiguration(subsystem).index("with_b"), activation)
    step_executives(executives, clock, activation - 0.002)
    rtpu0 = executives["rtpu0"]
    read_ahead = rtpu0.plans.prepared
    assert read_ahead is not None and [s.task.name for s in read_ahead.leaving] == ["ctl_a"]
    assert [s.task.name for s in read_ahead.entering] == ["ctl_b"]
    rtpu0.handle(meanwhile)
    step_executives(executives, clock, activation + 0.005)
    assert not [e for _, e in events if isinstance(e, messages.Refused)]
    switched = next(e for r, e in events if r == "rtpu0" and isinstance(e, messages.Switched))
    assert (switched.off, switched.on) == ((["ctl_a"], []) if meanwhile[0] == "on" else ([], ["ctl_b"]))
    assert rtpu0.tasks["ctl_a"].task.state is TaskState.OFF and rtpu0.tasks["ctl_b"].task.state is TaskState.ON


def test_an_activation_read_back_from_the_headers_nanoseconds_is_the_boundary_it_was_posted_for_issue_23():
    """CLOCK_MONOTONIC epochs are ~1e5 s with whole nanoseconds: epoch + k x period, written as ns
    and read back, may come out a few ns either side of the boundary; it is that boundary."""
    epoch = 74059.734851116
    executive = Executive(ManualClock(epoch), IdleSignals(ManualClock(epoch)), lambda event: None, epoch=epoch)
    task = SimpleNamespace(period=PERIOD, release_index=0)
    for k in range(10_000, 10_200):
        boundary = epoch + k * PERIOD
        activation = int(boundary * 1e9) / 1e9  # as the supervisor posts it and an executive reads it
        assert first_release(task, activation, executive.epoch) == boundary, k


def test_a_switch_that_overruns_a_cycle_makes_the_critical_task_hold_still(rig):
    subsystem, table, clock, executives, events = rig
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.005)
    # rtpu0 began a switch 3 periods ago and has not finished it (a slow `on`)
    table.header[Header.SWITCHING_SINCE_NS + 0] = int((clock.now() - 0.003) * 1e9)
    step_executives(executives, clock, clock.now() + 0.003)
    actuator = executives["rtpu1"].tasks["actuator"]
    assert actuator.stable_cycles >= 2
    rtpu, stable = next((r, e) for r, e in events if isinstance(e, messages.Stable))
    assert (rtpu, stable.task, stable.entering) == ("rtpu1", "actuator", True)
    table.header[Header.SWITCHING_SINCE_NS + 0] = 0
    step_executives(executives, clock, clock.now() + 0.003)
    assert actuator.held_for == NOT_HELD


def test_a_task_in_error_makes_the_critical_task_hold_still_until_it_is_cleared(rig):
    subsystem, table, clock, executives, _events = rig
    start(subsystem, executives, clock)
    table.header[Header.TASKS_IN_ERROR] = 1  # as job control sets it when a task reports ERROR
    step_executives(executives, clock, clock.now() + 0.003)
    actuator = executives["rtpu1"].tasks["actuator"]
    assert actuator.held_for == HELD_ILLEGAL and actuator.task.module.stable >= 2
    table.header[Header.TASKS_IN_ERROR] = 0
    step_executives(executives, clock, clock.now() + 0.002)
    assert actuator.held_for == NOT_HELD


def test_a_live_replace_is_staged_then_applied_at_the_plans_boundary_losing_no_cycle(rig):
    subsystem, table, clock, executives, events = rig
    live = LiveDescription.start(subsystem, table.layout.n_tasks, module_lookup=LIBRARY.__getitem__)
    new = live.replace("ctl_a", "ctl_c", TaskChange(module="b")).subsystem
    stage = SimpleNamespace(reconfiguration=Reconfiguration.of_members(
                                to_wire(new)["configurations"],
                                {name: (t["index"], t["period"], t["writes"]) for name, t in to_wire(new)["tasks"].items()}),
                            tasks={name: (t.index, dict(t.params)) for name, t in new.tasks.items()},
                            spec=new.tasks.__getitem__,
                            factories={"ctl_c": lambda: Task(new.tasks["ctl_c"], LIBRARY["b"], table)})
    for executive in executives.values():
        executive.plans.live_loader = lambda sequence: stage
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.005)
    for executive in executives.values():
        executive.handle(["live", 1])
    executives["rtpu0"].handle(["spawn", "ctl_c"])  # a task the staged description adds: created and spawned
    assert [e.sequence for _, e in events if isinstance(e, messages.Staged)] == [1, 1]
    assert executives["rtpu0"].tasks["ctl_c"].task.state is TaskState.OFF
    actuator = executives["rtpu1"].tasks["actuator"]
    assert actuator.task.module.seen[-1] == 1.0  # still ctl_a's: nothing applied before the plan
    activation = math.ceil((clock.now() + 0.004) / PERIOD) * PERIOD
    post_plan(table, 0, activation)  # the running configuration, with its new members
    step_executives(executives, clock, activation + 0.010)
    assert executives["rtpu0"].tasks["ctl_a"].task.state is TaskState.OFF
    assert executives["rtpu0"].tasks["ctl_c"].task.state is TaskState.ON
    assert actuator.lost_to_switch == 0 and actuator.stale_reads == 0 and actuator.stable_cycles == 0
    seen = actuator.task.module.seen
    # ctl_c's from the activation on: the actuator's 10 releases in those 10 ms (at +0.45 ms, ...) read it, none missed
    assert seen[seen.index(-1.0):] == [-1.0] * 10


def test_a_live_description_an_rtpu_cannot_read_is_answered_with_why(rig):
    _subsystem, _table, _clock, executives, events = rig

    def unreadable(sequence):
        raise FileNotFoundError(f"live-{sequence}.json")

    executives["rtpu0"].plans.live_loader = unreadable
    executives["rtpu0"].handle(["live", 2])
    staged = [e for _, e in events if isinstance(e, messages.Staged)]
    assert staged == [messages.Staged(2, "FileNotFoundError: live-2.json")] and executives["rtpu0"].plans.staged is None


def test_on_the_real_clock_a_live_description_is_read_off_the_cycle_and_staged_from_there(rig):
    # a file read and a JSON text parsed between two cycles would make the RTPU's releases late
    _subsystem, _table, _clock, executives, events = rig
    executive = executives["rtpu0"]
    executive.cycles_between_steps = True  # as `run` has it on the real clock
    readers: list[int] = []
    stage = SimpleNamespace(reconfiguration=executive.plans.reconfiguration, tasks={}, spec=None, factories={})

    def loader(sequence):
        readers.append(threading.get_ident())
        return stage

    executive.plans.live_loader = loader
    executive.handle(["live", 5])
    until(lambda: any(isinstance(e, messages.Staged) for _, e in events), "the live description staged")
    assert readers and readers[0] != threading.get_ident()
    assert [e for _, e in events if isinstance(e, messages.Staged)] == [messages.Staged(5)]
    assert executive.plans.staged is stage


class SlowToStartB(FakeControllerB):
    """Fake module: its init polls a device that answers at the 10th look (a processor starting)."""

    def init(self, params) -> None:
        for _ in range(10):
            sleep_while_cycling(0.001)


def test_a_plan_whose_boundary_comes_while_a_spawns_init_waits_is_applied_at_that_boundary(rig):
    subsystem, table, clock, executives, events = rig
    start(subsystem, executives, clock)
    step_executives(executives, clock, clock.now() + 0.005)
    rtpu0 = executives["rtpu0"]
    rtpu0.handle(["kill", "ctl_b"])
    rtpu0.factories["ctl_b"] = lambda: Task(subsystem.tasks["ctl_b"], SlowToStartB, table)
    activation = math.ceil((clock.now() + 0.004) / PERIOD) * PERIOD
    post_plan(table, Reconfiguration(subsystem).index("with_a"), activation)
    rtpu0.cycles_between_steps = True  # as on the real clock
    spawned_from = clock.now()
    rtpu0.handle(["spawn", "ctl_b"])  # its init waits 10 ms: the boundary comes meanwhile
    assert rtpu0.tasks["ctl_b"].task.state is TaskState.OFF and clock.now() > activation
    [switched] = [e for rtpu, e in events if rtpu == "rtpu0" and isinstance(e, messages.Switched)]
    assert spawned_from < switched.applied_at == pytest.approx(activation)
