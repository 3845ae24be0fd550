"""A critical task never runs its cycle on stale inputs: past an input's freshness bound it runs
its locally stable behaviour, says why, and resumes by itself when fresh values return.

Two executives share one real table and one manual clock (`support.step_executives`); an RTPU
that stops (SIGSTOP, a hung module) is one the loop no longer steps, so the counts are exact.
"""

from __future__ import annotations

import pytest

from pbo_runtime import InVar, OutVar, PortBasedObject, Status
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.config.loader import check_file
from pbo_runtime.ipc import messages
from pbo_runtime.reports.run_records import StableEpisode
from pbo_runtime.supervisor.event_ledger import STABLE_EPISODES_TOLD
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.supervisor.run_report import (
    BRIEF_HOLD_PERIODS,
    BRIEF_HOLDS_SHARE,
    marked_episodes,
    stable_episode_lines,
)
from pbo_runtime.table.table import Header, StateTable, TableLayout
from pbo_runtime.task.lifecycle import Task
from rtpu._executive import Executive
from rtpu.holds import HELD_ILLEGAL, HELD_STALE_INPUT, HELD_UPSTREAM, NOT_HELD
from tests.support import EventsHeard, IdleSignals, step_executives, unique_name

PERIOD = 0.001
STAGGER = 0.00045  # rtpu1's releases come 0.45 ms after rtpu0's


class FakeWriter(PortBasedObject):
    """Fake controller: writes its cycle count into u."""

    u = OutVar("u")

    def init(self, params) -> None:
        self.count = 0

    def cycle(self) -> Status:
        self.count += 1
        self.u = float(self.count)
        return Status.CONTINUE


class FakeActuator(PortBasedObject):
    """Fake critical module: records the release time of each cycle and of each stable cycle."""

    u = InVar("u")
    y = OutVar("y")

    def init(self, params) -> None:
        self.cycles: list[float] = []
        self.stable: list[float] = []

    def cycle(self) -> Status:
        self.cycles.append(self.time)
        self.y = self.u
        return Status.CONTINUE

    def stable_cycle(self) -> Status:
        self.stable.append(self.time)
        return Status.CONTINUE


class FakeDeviceWatcher(FakeActuator):
    """Fake robot interface: says STABLE while its (fake) device has stopped updating."""

    device_stalled = False

    def cycle(self) -> Status:
        if FakeDeviceWatcher.device_stalled:
            self.stable.append(self.time)
            return Status.STABLE
        return super().cycle()


LIBRARY = {"writer": FakeWriter, "actuator": FakeActuator, "watcher": FakeDeviceWatcher}


def text(actuator: str, writer: str) -> str:
    return f"""\
subsystem: freshness
rtpus: [rtpu0, rtpu1]
variables:
  u: {{type: float64}}
  y: {{type: float64}}
tasks:
  actuator: {actuator}
  writer: {writer}
configurations:
  loop: [actuator, writer]
"""


@pytest.fixture
def rig(tmp_path, make_table):
    """build(actuator YAML) -> (clock, executives, events, the actuator's Scheduled), started at t = 1 s."""
    made: list[StateTable] = []

    def build(actuator: str = "{module: actuator, rtpu: rtpu1, period: 1 ms, critical: true}",
              writer: str = "{module: writer, rtpu: rtpu0, period: 1 ms}", on_after: float = 0.0):
        path = tmp_path / "freshness.yaml"
        path.write_text(text(actuator, writer))
        result = check_file(path, module_lookup=LIBRARY.__getitem__, module_names=lambda: sorted(LIBRARY))
        assert result.errors == [], result.errors
        subsystem = result.subsystem
        table = StateTable.create(TableLayout.of(subsystem), unique_name())
        made.append(table)
        clock = ManualClock(1.0)
        events: list[messages.Event] = []
        recon = Reconfiguration(subsystem)
        executives = {}
        for rtpu in subsystem.rtpus:
            ex = Executive(clock, IdleSignals(clock), events.append, epoch=rtpu.index * STAGGER, header=table.header,
                           reconfiguration=recon, rtpu_index=rtpu.index, n_rtpus=len(subsystem.rtpus))
            for spec in subsystem.tasks_on(rtpu.name):
                ex.add(Task(spec, LIBRARY[spec.module], table))
            executives[rtpu.name] = ex
        for name in subsystem.init_order:
            executives[subsystem.tasks[name].rtpu].handle(["spawn", name])
        for name in ("actuator", "writer"):  # critical first, as job control turns them on
            executives[subsystem.tasks[name].rtpu].handle(["on", name, clock.now() + on_after, recon.index("loop")])
        return clock, executives, events, executives[subsystem.tasks["actuator"].rtpu].tasks["actuator"]

    yield build
    FakeDeviceWatcher.device_stalled = False
    for table in made:
        table.close()


def stable_events(events: list[messages.Event]) -> list[messages.Stable]:
    return [e for e in events if isinstance(e, messages.Stable)]


def last_write(executives) -> float:
    return executives["rtpu0"].tasks["writer"].last_release


def test_inputs_within_their_bound_never_hold_the_critical_task(rig):
    clock, executives, events, actuator = rig()
    step_executives(executives, clock, clock.now() + 0.05)
    assert actuator.stable_cycles == 0 and not stable_events(events)
    assert len(actuator.task.module.cycles) == 50


def test_outputs_written_by_on_long_before_the_first_release_do_not_hold_the_critical_task(rig):
    # job control turns every task on ahead of a common first release; `on` writes the outputs
    # then. The actuator's RTPU releases first, so its first cycle reads what `on` wrote.
    clock, executives, events, actuator = rig("{module: actuator, rtpu: rtpu0, period: 1 ms, critical: true}",
                                              "{module: writer, rtpu: rtpu1, period: 1 ms}", on_after=0.1)
    step_executives(executives, clock, clock.now() + 0.2)
    assert actuator.stable_cycles == 0 and not stable_events(events)


def test_a_critical_task_whose_writer_stops_runs_stable_from_its_third_period_on(rig):
    clock, executives, events, actuator = rig()
    step_executives(executives, clock, clock.now() + 0.01)
    stopped_at = clock.now()
    written = last_write(executives)
    step_executives({"rtpu1": executives["rtpu1"]}, clock, clock.now() + 0.01)  # rtpu0 stopped (SIGSTOP)
    module = actuator.task.module
    # two more cycles read values one and two periods old (one missed write is tolerated);
    # the third release reads a value 2.45 ms old, past the default bound of two writer periods
    assert [round(t - written, 5) for t in module.cycles if t > written] == [0.00045, 0.00145]
    assert module.stable[0] == pytest.approx(written + 0.00245)
    assert module.stable[0] - stopped_at <= 3 * PERIOD
    assert actuator.held_for == HELD_STALE_INPUT and len(module.stable) == actuator.stable_cycles == actuator.expired_reads
    (entering,) = stable_events(events)
    assert (entering.task, entering.entering, entering.cause) == ("actuator", True, "stale")
    assert entering.reason == ("in-var 'u' is 2.5 ms old, past its freshness bound of 2 ms ('writer' stopped writing it)")


def test_the_critical_task_resumes_its_cycle_by_itself_when_fresh_values_return(rig):
    clock, executives, events, actuator = rig()
    step_executives(executives, clock, clock.now() + 0.01)
    step_executives({"rtpu1": executives["rtpu1"]}, clock, clock.now() + 0.01)
    resumed_at = clock.now()
    step_executives(executives, clock, clock.now() + 0.01)  # SIGCONT: the writer catches up
    module = actuator.task.module
    assert actuator.held_for == NOT_HELD
    assert module.cycles[-1] > resumed_at and all(t < resumed_at + PERIOD for t in module.stable)
    entering, leaving = stable_events(events)
    assert (leaving.entering, leaving.task) == (False, "actuator") and leaving.at > entering.at


def test_a_hold_for_a_stale_input_that_goes_on_because_a_task_is_in_error_is_a_new_episode_saying_so(rig):
    clock, executives, events, actuator = rig()
    step_executives(executives, clock, clock.now() + 0.01)
    step_executives({"rtpu1": executives["rtpu1"]}, clock, clock.now() + 0.005)  # the writer stopped: a stale hold
    header = executives["rtpu1"].header
    header[Header.TASKS_IN_ERROR] = 1  # as job control sets it when a task reports ERROR
    step_executives({"rtpu1": executives["rtpu1"]}, clock, clock.now() + 0.005)
    assert actuator.held_for == HELD_ILLEGAL
    header[Header.TASKS_IN_ERROR] = 0
    step_executives(executives, clock, clock.now() + 0.01)  # cleared, and the writer runs again
    episodes = [(e.entering, e.cause) for e in stable_events(events)]
    assert episodes == [(True, "stale"), (False, ""), (True, "illegal"), (False, "")]
    assert actuator.held_for == NOT_HELD


def test_the_cycle_never_reads_a_value_older_than_the_bound(rig):
    clock, executives, _, actuator = rig()
    table_reader = actuator.task.local
    ages = []
    module = actuator.task.module
    original = module.cycle

    def cycle_recording_age() -> Status:
        ages.append(module.time - float(table_reader.input_write_times[0]))
        return original()

    actuator.task._cycle = cycle_recording_age
    for rounds in range(5):  # the writer stops and comes back, five times
        step_executives(executives, clock, clock.now() + 0.004)
        step_executives({"rtpu1": executives["rtpu1"]}, clock, clock.now() + 0.004 + rounds * 0.001)
    assert ages and max(ages) <= 2 * PERIOD


def test_fresh_within_gives_one_port_a_longer_bound(rig):
    clock, executives, events, actuator = rig("{module: actuator, rtpu: rtpu1, period: 1 ms, critical: true, "
                                              "fresh_within: {u: 5 ms}}")
    step_executives(executives, clock, clock.now() + 0.01)
    written = last_write(executives)
    step_executives({"rtpu1": executives["rtpu1"]}, clock, clock.now() + 0.01)
    module = actuator.task.module
    assert module.stable[0] == pytest.approx(written + 0.00545)
    assert "past its freshness bound of 5 ms" in stable_events(events)[0].reason


def test_a_module_that_returns_stable_is_reported_as_a_stable_episode_and_resumes(rig):
    clock, executives, events, actuator = rig("{module: watcher, rtpu: rtpu1, period: 1 ms, critical: true}")
    step_executives(executives, clock, clock.now() + 0.005)
    FakeDeviceWatcher.device_stalled = True
    step_executives(executives, clock, clock.now() + 0.005)
    FakeDeviceWatcher.device_stalled = False
    step_executives(executives, clock, clock.now() + 0.005)
    entering, leaving = stable_events(events)
    assert (entering.cause, entering.entering, leaving.entering) == ("module", True, False)
    assert actuator.stable_cycles == 5 and actuator.held_for == NOT_HELD
    assert actuator.task.state.name == "ON"


def test_a_critical_task_holds_while_a_task_upstream_says_its_input_is_not_fresh_and_resumes_by_itself(rig):
    # job control counts, in the header, the tasks that are not critical and whose cycle returned STABLE
    # (a link_receiver whose item is past its bound): what they write is stale, so critical tasks hold
    clock, executives, events, actuator = rig()
    header = executives["rtpu0"].header
    step_executives(executives, clock, clock.now() + 0.005)
    header[Header.TASKS_NOT_FRESH] = 1
    step_executives(executives, clock, clock.now() + 0.005)
    assert actuator.held_for == HELD_UPSTREAM and actuator.stable_cycles == 5
    header[Header.TASKS_NOT_FRESH] = 0
    step_executives(executives, clock, clock.now() + 0.005)
    entering, leaving = stable_events(events)
    assert (entering.cause, entering.entering, leaving.entering) == ("upstream", True, False)
    assert "a task upstream has no fresh input" in entering.reason
    assert actuator.held_for == NOT_HELD and len(actuator.task.module.cycles) == 10


# --- what the run report makes of the episodes: faults, or timing ---------------------------------

ON_AT = 100.0  # the configuration came on (run clock seconds)
ROBOT_PERIOD = 0.001


def episode(start: float, seconds: float | None, cause: str = "stale", reason: str = "in-var 'tau_u' is 2.5 ms old",
            task: str = "robot") -> StableEpisode:
    return StableEpisode(task, ON_AT + start, None if seconds is None else ON_AT + start + seconds, reason, cause)


def lines(*episodes: StableEpisode, duration: float = 5.0) -> tuple[list[str], list[str]]:
    return stable_episode_lines(list(episodes), {"robot": ROBOT_PERIOD}, ON_AT, duration)


def test_a_brief_hold_that_ends_by_itself_is_timing_not_a_fault():
    faults, timing = lines(episode(1.0, 0.002), episode(3.0, 0.001))
    assert faults == []
    assert timing == [f"critical task 'robot' held 2 times (the longest 2.0 ms), the first from 1.000 s into the run, "
                      f"each back to its cycle within {BRIEF_HOLD_PERIODS} periods (a late input: timing, not a fault): "
                      "in-var 'tau_u' is 2.5 ms old"]


@pytest.mark.parametrize("held, said", [
    (BRIEF_HOLD_PERIODS * ROBOT_PERIOD, "for 10.0 ms, from 1.000 s into the run"),
    (None, "until the stop, from 1.000 s into the run"),
], ids=["as long as the brief bound", "until the stop"])
def test_a_hold_of_the_brief_bound_or_longer_or_until_the_stop_is_a_fault(held, said):
    faults, timing = lines(episode(1.0, held))
    assert faults == [f"critical task 'robot' ran its locally stable behaviour {said}: in-var 'tau_u' is 2.5 ms old"]
    assert timing == []


def test_brief_holds_adding_up_to_more_than_a_twentieth_of_the_run_are_a_fault():
    assert BRIEF_HOLDS_SHARE == 0.05
    faults, timing = lines(*(episode(0.01 * k, 0.005) for k in range(11)), duration=1.0)  # 55 ms of 1 s
    assert len(faults) == 1 and faults[0].startswith("critical task 'robot' ran its locally stable behaviour 11 times")
    assert timing == []


def test_a_hold_for_the_table_lock_is_timing_told_with_its_reason_not_a_fault():
    reason = "the table lock was held past its wait of 0.125 ms (its holder died holding it, or stalled)"
    faults, timing = lines(episode(1.0, 0.004, "lock", reason), episode(2.0, 0.001, "lock", reason))
    assert faults == []
    assert timing == [f"critical task 'robot' held 2 times (the longest 4.0 ms), the first from 1.000 s into the run, rather "
                      f"than wait for the table lock: {reason}"]


def test_a_hold_for_an_illegal_configuration_the_operator_ended_is_neither_and_one_until_the_stop_is_a_fault():
    illegal = "the configuration is illegal (a task in ERROR, or a switch that overran a cycle)"
    cleared = episode(1.0, 2.0, "illegal", illegal)  # pbo clear, pbo on: the operator's procedure
    assert lines(cleared) == ([], [])
    braked = episode(1.0, None, "illegal", illegal)  # nobody brought the configuration back
    assert lines(cleared, braked) == ([f"critical task 'robot' ran its locally stable behaviour until the stop, from "
                                       f"1.000 s into the run: {illegal}"], [])


def test_a_hold_while_the_configuration_comes_on_is_neither_and_is_marked():
    held = episode(-0.5, 0.3)
    assert lines(held) == ([], [])
    [marked] = marked_episodes([held], {"robot": ROBOT_PERIOD}, ON_AT)
    assert marked.while_starting is True and marked.brief is False


class StableEpisodesHeard(EventsHeard):
    """The supervisor's event handling hearing stable episodes, with a list for its lines."""

    def hold(self, cause: str, at: float) -> None:
        self.hear("rtpu1", messages.Stable("robot", True, at, f"held for {cause}", cause),
                  messages.Stable("robot", False, at + 0.001))


def test_a_hold_for_an_illegal_configuration_is_told_even_after_many_holds_for_late_inputs():
    heard = StableEpisodesHeard()
    for late in range(STABLE_EPISODES_TOLD + 3):
        heard.hold("stale", at=float(late))
    heard.hold("illegal", at=100.0)
    told = [line for line in heard.lines if "runs its locally stable behaviour" in line]
    assert told == ["critical task 'robot' runs its locally stable behaviour: held for stale"] * STABLE_EPISODES_TOLD + [
        "critical task 'robot' runs its locally stable behaviour: held for illegal"]
    assert heard.lines[2 * STABLE_EPISODES_TOLD - 1].endswith(
        "its further holds for late inputs are counted in the summary, not told")
    assert heard.lines[-1].startswith("critical task 'robot' is back to its cycle after 1.0 ms")
    assert len(heard.result.stable_episodes) == STABLE_EPISODES_TOLD + 4


def test_a_receiver_without_fresh_items_is_the_fault_and_the_robots_hold_it_caused_is_not_told_twice():
    receiver = episode(1.0, 0.6, "module", task="receive")
    held = episode(1.01, 0.6, "upstream")
    faults, timing = stable_episode_lines([receiver, held], {"robot": ROBOT_PERIOD, "receive": 0.002}, ON_AT, 5.0,
                                          critical={"robot"})
    assert timing == [] and len(faults) == 1
    assert faults[0].startswith("task 'receive' had no fresh input for 600.0 ms, from 1.000 s into the run")
