"""The RTPU executive, stepped on a manual clock: releases, order, overruns, signals. No sleeping."""

from __future__ import annotations

import dataclasses
import threading
from typing import ClassVar

import pytest

from pbo_runtime import OutVar, PortBasedObject, Status, sleep_while_cycling
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.messages import Refused, Stable, StateChanged, Stats
from pbo_runtime.objects.waits import cycles_meanwhile
from pbo_runtime.table.table import StatusWord as W
from pbo_runtime.table.table import TaskState
from pbo_runtime.task.lifecycle import Task
from rtpu._executive import Executive
from tests.support import REPO, RUNS, FakeSignals, Quiet, Ticker, allocation_peak, one_array, run_until, task_spec, variables


class Faulty(Ticker):
    def cycle(self) -> Status:
        raise RuntimeError("broken on purpose")


@pytest.fixture
def setup(make_table):
    RUNS.clear()
    table = make_table(variables(("o0", "float64", ()), ("o1", "float64", ()), ("o2", "float64", ())))
    clock = ManualClock(0.0)
    events: list[messages.Event] = []

    def build(specs: list[tuple], script: list[tuple[float, list]], clock: ManualClock = clock) -> Executive:
        executive = Executive(clock, FakeSignals(clock, script), events.append, epoch=0.0)
        for i, (name, module, period, critical, *priority) in enumerate(specs):
            spec = task_spec(module, name=name, index=i, ports={"out": f"o{i}"}, period=period)
            spec = dataclasses.replace(spec, critical=critical, priority=priority[0] if priority else 0)
            task = Task(spec, module, table)
            task.module.clock = clock
            executive.add(task)
        return executive

    return build, clock, events


class StallingClock(ManualClock):
    """Fake clock: the wait for one release ends late, as when the machine holds the RTPU's CPU."""

    def __init__(self, stall_at: float, stall: float) -> None:
        super().__init__(0.0)
        self.stall_at, self.stall = stall_at, stall

    def sleep_until(self, deadline: float) -> float:
        if abs(deadline - self.stall_at) < 1e-12:
            deadline += self.stall
        return super().sleep_until(deadline)


class Holder(Ticker):
    """Fake critical module: records its stable cycles apart from its cycles."""

    def stable_cycle(self) -> Status:
        RUNS.append((self.task_name + " held", self.time))
        return Status.CONTINUE


def test_while_a_dead_holder_keeps_the_table_lock_the_critical_task_holds_and_the_others_lose_their_release(make_table):
    RUNS.clear()
    table = make_table(variables(("o0", "float64", ()), ("o1", "float64", ())))
    clock = ManualClock(0.0)
    events: list[messages.Event] = []
    script = [(0.0, ["spawn", "robot"]), (0.0, ["spawn", "logger"]), (0.0, ["on", "robot", 0.0]), (0.0, ["on", "logger", 0.0])]
    ex = Executive(clock, FakeSignals(clock, script), events.append, epoch=0.0, cycle_lock_wait=table.cycle_lock_wait)
    for i, (name, module, critical) in enumerate([("robot", Holder, True), ("logger", Ticker, False)]):
        spec = dataclasses.replace(task_spec(module, name=name, index=i, ports={"out": f"o{i}"}, period=0.002), critical=critical)
        ex.add(Task(spec, module, table))
    run_until(ex, clock, 0.0)
    assert table.cycle_lock_wait == [pytest.approx(0.125 * 0.002)]  # an eighth of the critical period
    table.acquire()  # the lock held by a process that died holding it
    run_until(ex, clock, 0.005)
    table.release()  # job control recovered it
    run_until(ex, clock, 0.007)
    assert RUNS == [("robot", 0.0), ("logger", 0.0), ("robot held", 0.002), ("robot held", 0.004),
                    ("robot", 0.006), ("logger", 0.006)]
    robot, logger = ex.tasks["robot"], ex.tasks["logger"]
    assert (robot.missed, robot.lock_waits_given_up, robot.stable_cycles) == (0, 2, 2)
    assert (logger.missed, logger.lock_waits_given_up) == (2, 2)
    held = [e for e in events if isinstance(e, Stable)]
    assert [(e.task, e.entering, e.cause) for e in held] == [("robot", True, "lock"), ("robot", False, "")]
    assert "the table lock was held past its wait of 0.25 ms" in held[0].reason


def test_without_a_bound_as_on_the_simulated_clock_a_critical_cycle_waits_for_the_lock_and_runs_in_full(setup):
    build, clock, _ = setup
    ex = build([("robot", Holder, 0.001, True)], [(0.0, ["spawn", "robot"]), (0.0, ["on", "robot", 0.0])])
    run_until(ex, clock, 0.0)
    table = ex.tasks["robot"].task.local.table
    assert ex.cycle_lock_wait is None and table.cycle_lock_wait == [None]  # (rtpu/__main__ passes none on that clock)
    table.acquire()
    holder = threading.Timer(0.05, table.release)  # another process's transfer, however long it takes
    holder.start()
    run_until(ex, clock, 0.001)
    holder.join()
    assert RUNS == [("robot", 0.0), ("robot", 0.001)]  # its cycle, not its stable one: a replay cannot depend on timing


def test_releases_follow_absolute_times_without_drift(setup):
    build, clock, _ = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])])
    Ticker.cost = 0.0003  # every cycle takes 0.3 ms: a relative sleep would drift by that
    try:
        run_until(ex, clock, 0.0105)
    finally:
        Ticker.cost = 0.0
    assert [t for _, t in RUNS] == pytest.approx([i * 0.001 for i in range(11)])


def test_critical_task_runs_first_when_released_together(setup):
    build, clock, _ = setup
    script = [(0.0, ["spawn", "slow"]), (0.0, ["spawn", "crit"]), (0.0, ["on", "slow", 0.0]), (0.0, ["on", "crit", 0.0])]
    ex = build([("slow", Ticker, 0.001, False), ("crit", Ticker, 0.002, True)], script)
    run_until(ex, clock, 0.0005)
    assert [name for name, _ in RUNS[:2]] == ["crit", "slow"]


def test_earliest_deadline_runs_first_among_non_critical_tasks(setup):
    build, clock, _ = setup
    script = [(0.0, ["spawn", "long"]), (0.0, ["spawn", "short"]), (0.0, ["on", "long", 0.0]), (0.0, ["on", "short", 0.0])]
    ex = build([("long", Ticker, 0.004, False), ("short", Ticker, 0.001, False)], script)
    run_until(ex, clock, 0.0005)
    assert [name for name, _ in RUNS[:2]] == ["short", "long"]


def test_user_priority_breaks_a_tie_of_equal_deadlines(setup):
    build, clock, _ = setup
    script = [(0.0, ["spawn", "low"]), (0.0, ["spawn", "high"]), (0.0, ["on", "low", 0.0]), (0.0, ["on", "high", 0.0])]
    ex = build([("low", Ticker, 0.001, False, 1), ("high", Ticker, 0.001, False, 5)], script)
    run_until(ex, clock, 0.0005)
    assert [name for name, _ in RUNS[:2]] == ["high", "low"]


def test_an_overrun_is_counted_and_the_phase_is_kept(setup):
    build, clock, _ = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])])
    Ticker.cost = 0.0025  # 2.5 periods: the releases at 1 and 2 ms are missed
    try:
        run_until(ex, clock, 0.0001)
    finally:
        Ticker.cost = 0.0
    run_until(ex, clock, 0.0045)
    scheduled = ex.tasks["a"]
    assert scheduled.overruns == 1
    assert scheduled.missed == 1
    assert scheduled.shared_status[W.MISSED] == 1  # in the table at once, for pbo status (not with the next percentiles)
    assert [t for _, t in RUNS] == pytest.approx([0.0, 0.003, 0.004])


def test_a_module_that_raises_goes_to_error_and_the_executive_goes_on(setup):
    build, clock, events = setup
    script = [(0.0, ["spawn", "bad"]), (0.0, ["spawn", "good"]), (0.0, ["on", "bad", 0.0]), (0.0, ["on", "good", 0.0])]
    ex = build([("bad", Faulty, 0.001, False), ("good", Ticker, 0.001, False)], script)
    run_until(ex, clock, 0.0055)
    assert ex.tasks["bad"].task.state is TaskState.ERROR
    assert any(isinstance(e, StateChanged) and (e.task, e.state) == ("bad", "ERROR") for e in events)
    assert len([1 for name, _ in RUNS if name == "good"]) == 6


def test_off_stops_the_releases_and_stop_kills_every_task(setup):
    build, clock, events = setup
    script = [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0]), (0.0025, ["off", "a"]), (0.004, ["stop"])]
    ex = build([("a", Ticker, 0.001, False)], script)
    run_until(ex, clock, 0.01)
    assert len(RUNS) == 3
    assert not ex.running
    assert ex.tasks["a"].task.state is TaskState.KILLED
    assert isinstance(events[-1], Stats) and (events[-1].task, events[-1].statistics.cycles) == ("a", 3)


def test_a_signal_for_an_unknown_task_is_refused_not_fatal(setup):
    build, _clock, events = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["on", "nobody"])])
    ex.run_once()
    assert events == [Refused("nobody", "no task 'nobody' on this RTPU")]


def test_on_before_spawn_is_refused_with_the_reason(setup):
    build, _clock, events = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["on", "a"])])
    ex.run_once()
    assert isinstance(events[0], Refused) and "cannot take 'on' in state NOT_CREATED" in events[0].reason
    assert ex.on == []


class EventRecorder(PortBasedObject):
    """Fake aperiodic module: records (release time, payload) of every event it serves."""

    out = OutVar("out")
    served: ClassVar[list] = []

    def cycle(self) -> Status:
        EventRecorder.served.append((self.time, self.event))
        return Status.CONTINUE


def test_an_aperiodic_task_runs_on_events_no_faster_than_its_min_interarrival(setup):
    build, clock, _ = setup
    EventRecorder.served = []
    script = [(0.0, ["spawn", "goal"]), (0.0, ["on", "goal", 0.0]), (0.002, ["event", "goal", [1.0]]),
              (0.003, ["event", "goal", [2.0]]), (0.030, ["event", "goal", [3.0]])]
    ex = build([("goal", EventRecorder, 0.01, False)], script)
    scheduled = ex.tasks["goal"]
    scheduled.aperiodic, scheduled.period = True, 0.01  # as a task with `aperiodic: true, min_interarrival: 10 ms`
    run_until(ex, clock, 0.05)
    assert [payload for _, payload in EventRecorder.served] == [[1.0], [2.0], [3.0]]
    times = [t for t, _ in EventRecorder.served]
    assert times == pytest.approx([0.002, 0.012, 0.030])  # the second waited out the 10 ms
    assert scheduled.release == float("inf")  # nothing pending: no timer release


def test_an_event_for_a_periodic_task_is_refused(setup):
    build, _clock, events = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0]), (0.0, ["event", "a", [1]])])
    ex.run_once()
    ex.run_once()
    ex.run_once()
    assert Refused("a", "event: the task is periodic") in events


def test_the_percentiles_of_the_last_1024_cycles_reach_the_table_for_pbo_status(setup):
    build, clock, _ = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])])
    Ticker.cost = 0.0002  # each cycle takes 0.2 ms of the manual clock
    try:
        run_until(ex, clock, 1.0235)  # releases 0 .. 1023 ms: exactly 1,024 cycles
    finally:
        Ticker.cost = 0.0
    shared = ex.tasks["a"].shared_status
    assert ex.tasks["a"].samples == 1024
    assert shared[W.EXEC_P50] == pytest.approx(0.0002) and shared[W.EXEC_P99] == pytest.approx(0.0002)
    assert shared[W.JITTER_P50] == pytest.approx(0.0, abs=1e-12) and shared[W.MISSED] == 0


def aperiodic_recorder(build, script):
    ex = build([("server", EventRecorder, 0.01, False)], script)
    scheduled = ex.tasks["server"]
    scheduled.aperiodic, scheduled.period = True, 0.01  # as `aperiodic: true, min_interarrival: 10 ms`
    return ex, scheduled


def test_a_link_message_that_comes_before_its_server_is_on_waits_and_is_served_when_it_turns_on(setup):
    build, clock, events = setup
    EventRecorder.served = []
    script = [(0.0, ["spawn", "server"]), (0.001, ["message", "server", [[1.0], 7]]), (0.005, ["on", "server", 0.005])]
    ex, _ = aperiodic_recorder(build, script)
    run_until(ex, clock, 0.05)
    assert EventRecorder.served == [(0.005, [[1.0], 7])]
    assert not any(isinstance(e, Refused) for e in events)  # the other subsystem started first: not a mistake


def test_an_operator_event_for_a_server_that_is_off_is_still_refused(setup):
    build, clock, events = setup
    EventRecorder.served = []
    ex, _ = aperiodic_recorder(build, [(0.0, ["spawn", "server"]), (0.001, ["event", "server", [1.0]])])
    run_until(ex, clock, 0.05)
    assert Refused("server", "event: the task is OFF, not ON") in events and EventRecorder.served == []


def test_link_messages_beyond_what_a_server_holds_are_counted_as_dropped(setup):
    from rtpu._executive import EVENTS_QUEUED

    build, clock, _ = setup
    EventRecorder.served = []
    script = [(0.0, ["spawn", "server"])] + [(0.001, ["message", "server", [[float(i)], i]]) for i in range(EVENTS_QUEUED + 3)]
    ex, scheduled = aperiodic_recorder(build, [*script, (0.002, ["on", "server", 0.002])])
    run_until(ex, clock, 1.0)
    assert scheduled.dropped_events == 3
    assert [payload[1] for _, payload in EventRecorder.served] == list(range(3, EVENTS_QUEUED + 3))  # the newest kept
    assert ex.tasks["server"].statistics().dropped_events == 3


def test_each_overrun_is_recorded_with_its_cause_a_late_release_or_a_long_cycle(setup):
    build, _, _ = setup
    clock = StallingClock(stall_at=0.002, stall=0.0015)  # the 2 ms release starts at 3.5 ms
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])], clock=clock)
    run_until(ex, clock, 0.0035)
    Ticker.cost = 0.0025  # the 4 ms cycle runs 2.5 periods on its own
    try:
        run_until(ex, clock, 0.0041)
    finally:
        Ticker.cost = 0.0
    stats = ex.tasks["a"].statistics()
    assert (stats.overruns, stats.overruns_late_release, stats.overruns_long_cycle) == (2, 1, 1)
    assert [[o.release, o.late, o.took] for o in stats.last_overruns] == [pytest.approx([0.002, 0.0015, 0.0]),
                                                                          pytest.approx([0.004, 0.0, 0.0025])]


def test_the_run_report_keeps_the_last_eight_overruns_oldest_first(setup):
    build, clock, _ = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])])
    Ticker.cost = 0.0015  # every cycle overruns: releases at 0, 2, 4, ... ms
    try:
        run_until(ex, clock, 0.0195)
    finally:
        Ticker.cost = 0.0
    stats = ex.tasks["a"].statistics()
    assert stats.overruns == 10 and stats.overruns_long_cycle == 10
    assert [overrun.release for overrun in stats.last_overruns] == pytest.approx([0.004 + 0.002 * i for i in range(8)])


def test_a_spawn_freezes_what_the_process_built_so_no_collection_walks_it_mid_run(setup):
    import gc

    build, clock, _ = setup
    ex = build([("a", Ticker, 0.001, False)], [(0.0, ["spawn", "a"])])
    gc.unfreeze()
    try:
        run_until(ex, clock, 0.0)
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_once_job_control_announces_the_stop_no_further_cycle_runs(make_table):
    # Regression (issue 6): RTPUs stopped first did their stop work while the others still ran
    # cycles, which then overran for want of a CPU and were counted as the run's overruns.
    import numpy as np

    from pbo_runtime.table.table import Flag, Header

    RUNS.clear()
    table = make_table(variables(("o0", "float64", ())))
    clock = ManualClock(0.0)
    header = np.zeros(32, dtype=np.int64)
    events: list[messages.Event] = []
    ex = Executive(clock, FakeSignals(clock, [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])]),
                   events.append, epoch=0.0, header=header)
    ex.add(Task(task_spec(Ticker, name="a", ports={"out": "o0"}, period=0.001), Ticker, table))
    run_until(ex, clock, 0.0025)
    assert len(RUNS) == 3
    header[Header.FLAGS] |= Flag.STOPPING
    run_until(ex, clock, 0.0100)
    assert len(RUNS) == 3 and not ex.running
    assert ex.tasks["a"].task.state.name == "KILLED"
    assert [e for e in events if isinstance(e, Stats)], "it still reports its statistics"


def test_what_an_rtpu_reports_at_stop_goes_by_the_patient_reporter(make_table):
    # Every RTPU reports at once at stop; job control drains its queue meanwhile, so the last
    # windows, states and statistics may wait out a full queue instead of being dropped.
    RUNS.clear()
    table = make_table(variables(("o0", "float64", ())))
    clock = ManualClock(0.0)
    during, at_stop = [], []
    ex = Executive(clock, FakeSignals(clock, [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0]), (0.0025, ["stop"])]),
                   lambda e: during.append(e.KIND), epoch=0.0, report_at_stop=lambda e: at_stop.append(e.KIND))
    ex.add(Task(task_spec(Ticker, name="a", ports={"out": "o0"}, period=0.001), Ticker, table))
    run_until(ex, clock, 0.01)
    assert "stats" not in during and during.count("state") == 2  # spawned (OFF), then ON
    assert at_stop.count("stats") == 1 and "state" in at_stop


# Run in a fresh interpreter, as an RTPU is: in a long-lived one (the test suite) glibc may have
# raised its mmap threshold, and the rings would come from recycled heap, written already.
CYCLES_IN_A_FRESH_PROCESS = """
import os, resource, sys
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.task.lifecycle import Task
from pbo_runtime.table.table import StateTable, TableLayout
from rtpu._executive import Executive
from tests.support import FakeSignals, Quiet, run_until, task_spec, unique_name, variables

table = StateTable.create(TableLayout.build(variables(("o0", "float64", ())), 1), unique_name())
try:
    clock = ManualClock(0.0)
    executive = Executive(clock, FakeSignals(clock, [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])]), lambda e: None)
    executive.add(Task(task_spec(Quiet, name="a", ports={"out": "o0"}), Quiet, table))
    run_until(executive, clock, 0.01)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    run_until(executive, clock, 4.1)  # 4,096 more cycles: 8 new pages in each ring were it untouched
    print(executive.tasks["a"].task.cycles, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
finally:
    table.close()
"""


@pytest.mark.multiprocess
def test_the_per_cycle_path_takes_no_page_fault():
    # Regression (issue 6): the jitter and execution-time rings were zeroed lazily, so every 512
    # cycles each wrote into a page the process had never touched: a page fault on the per-cycle
    # path, 4 a second for a 1 kHz task (counted in /proc/PID/stat of a running RTPU).
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", CYCLES_IN_A_FRESH_PROCESS], cwd=REPO, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    cycles, faults = map(int, done.stdout.split())
    assert cycles >= 4096
    assert faults < 8, f"{faults} page faults in 4,096 cycles"  # 22 before the fix


class SlowToSpawn(Ticker):
    """Fake module whose init takes 3 ms of the manual clock (an init that opens and allocates)."""

    def init(self, params) -> None:
        RUNS.append((self.task_name + " init", self.clock.now()))
        self.clock.advance(0.003)


@pytest.mark.parametrize("real_clock", [True, False])
def test_a_task_spawned_live_lets_the_cycles_due_meanwhile_run_between_its_steps_on_the_real_clock(make_table, real_clock):
    RUNS.clear()
    table = make_table(variables(("o0", "float64", ()), ("o1", "float64", ())))
    clock = ManualClock(0.0)
    events: list[messages.Event] = []
    script = [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0]), (0.0025, ["spawn", "b"])]
    executive = Executive(clock, FakeSignals(clock, script), events.append, epoch=0.0)
    executive.cycles_between_steps = real_clock  # as `run` sets it; the lockstep loop and stepping by hand do not
    a = Task(task_spec(Ticker, name="a", index=0, ports={"out": "o0"}), Ticker, table)
    a.module.clock = clock
    executive.add(a)

    def make_b() -> Task:  # a module imported for the first time: 3 ms of the manual clock
        clock.advance(0.003)
        RUNS.append(("b made", clock.now()))
        made = Task(task_spec(SlowToSpawn, name="b", index=1, ports={"out": "o1"}), SlowToSpawn, table)
        made.module.clock = clock
        return made

    executive.factories["b"] = make_b
    run_until(executive, clock, 0.0026)
    assert executive.tasks["b"].task.state is TaskState.OFF
    order = [name for name, _ in RUNS]
    made, init = order.index("b made"), order.index("b init")
    between = [at for name, at in RUNS[made:init] if name == "a"]
    after = [at for name, at in RUNS[init:] if name == "a"]
    if real_clock:  # the release due at 3 ms ran once b was made, before its init; the one at 6 ms after it (late
        # releases are run once and the ones already gone skipped, as after any overrun)
        assert between == pytest.approx([0.003]) and after == pytest.approx([0.006])
    else:  # every step of the spawn first (the simulated clock's time stood still meanwhile)
        assert between == [] and after == []


class WaitsForItsDevice(Ticker):
    """Fake module: its init polls a device that answers at the 20th look (a processor starting)."""

    looks = 20

    def init(self, params) -> None:
        RUNS.append((self.task_name + " init", self.clock.now()))
        for _ in range(self.looks):
            sleep_while_cycling(0.001)
        RUNS.append((self.task_name + " ready", self.clock.now()))


@pytest.mark.parametrize("real_clock", [True, False])
def test_while_a_spawned_tasks_init_waits_for_its_device_the_other_tasks_cycle_at_each_release(make_table, real_clock):
    RUNS.clear()
    table = make_table(variables(("o0", "float64", ()), ("o1", "float64", ())))
    clock = ManualClock(0.0)
    script = [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0]), (0.0025, ["spawn", "b"])]
    executive = Executive(clock, FakeSignals(clock, script), [].append, epoch=0.0)
    executive.cycles_between_steps = real_clock
    for name, index, module in (("a", 0, Ticker), ("b", 1, WaitsForItsDevice)):
        task = Task(task_spec(module, name=name, index=index, ports={"out": f"o{index}"}), module, table)
        task.module.clock = clock
        executive.add(task)
    run_until(executive, clock, 0.003)
    assert executive.tasks["b"].task.state is TaskState.OFF
    order = [name for name, _ in RUNS]
    waited = [at for name, at in RUNS[order.index("b init"):order.index("b ready")] if name == "a"]
    a = executive.tasks["a"]
    if real_clock:  # every release during the wait ran at its time: none late, none missed
        assert waited == pytest.approx([0.003 + 0.001 * k for k in range(20)])
        assert (a.overruns, a.missed, a.jitter_max) == (0, 0, 0.0)
    else:  # the simulated clock stands still while a signal is served: the cycles wait for its next tick
        assert waited == []


def test_a_wait_outside_a_spawn_or_in_another_thread_is_a_plain_sleep():
    ran: list[str] = []
    with cycles_meanwhile(lambda seconds: ran.append("cycles")):
        helper = threading.Thread(target=sleep_while_cycling, args=(0.0,))
        helper.start()
        helper.join()
        assert ran == []
        sleep_while_cycling(0.0)
        assert ran == ["cycles"]
    sleep_while_cycling(0.0)
    assert ran == ["cycles"]


@pytest.mark.parametrize("critical", [False, True])
def test_a_cycle_through_the_executive_allocates_no_array(make_table, critical):
    """The pick, the transfers, the hold policy, the timing record and the next release: no allocation
    (the percentiles published once per 1,024 cycles are left out: 200 calls a round stay clear of them)."""
    table = make_table(variables(("o0", "float64", ())))
    clock = ManualClock(0.0)
    executive = Executive(clock, FakeSignals(clock, [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0])]), [].append, epoch=0.0)
    spec = dataclasses.replace(task_spec(Quiet, name="a", index=0, ports={"out": "o0"}), critical=critical)
    executive.add(Task(spec, Quiet, table))
    run_until(executive, clock, 0.0)
    a = executive.tasks["a"]

    def one_release() -> None:
        clock.time = a.release
        executive.run_ready()

    assert allocation_peak(one_release, times=200) < one_array()
    assert a.task.cycles == 1 + 4 * 200 and a.overruns == 0


def test_a_timing_ring_is_written_in_steps_with_the_due_cycles_run_between():
    # a live spawn faults in a megabyte of ring pages: the RTPU's other tasks cycle between the steps
    from rtpu.releases import RING, RING_STEP, written_ring

    steps: list[int] = []
    ring = written_ring(lambda: steps.append(1))
    assert len(steps) == RING // RING_STEP > 1
    assert ring.shape == (RING,) and not ring.any()
