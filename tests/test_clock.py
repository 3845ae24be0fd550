"""The clocks' `sleep_until` and how the executive times a release from it (issue 6).

The real clock is driven by a scripted time source, so nothing here sleeps or depends on how
fast the machine is: the tests check which reading is returned and used, never a duration.
"""

from __future__ import annotations

import numpy as np
import pytest

from pbo_runtime import OutVar, PortBasedObject, Status
from pbo_runtime.clock.clocks import ManualClock, RealClock, SimClock, release_stagger
from pbo_runtime.table.table import HEADER_WORDS, Header
from pbo_runtime.table.table import StatusWord as W
from pbo_runtime.task.lifecycle import Task
from rtpu._executive import Executive
from tests.support import task_spec, variables


class ScriptedTime:
    """A time source returning the scripted readings in turn; it fails when read once too often."""

    def __init__(self, *readings: float) -> None:
        self.readings = list(readings)
        self.reads = 0

    def __call__(self) -> float:
        self.reads += 1
        return self.readings.pop(0)


def test_real_clock_returns_the_reading_that_ended_the_spin():
    clock = RealClock(spin=1.0)  # the deadline is within the spin: no kernel sleep
    clock.now = ScriptedTime(9.5, 9.7, 9.9, 10.000002, 10.5)
    assert clock.sleep_until(10.0) == 10.000002
    assert clock.now.readings == [10.5]  # no reading taken after the one that ended the spin


def test_real_clock_past_deadline_returns_the_first_reading_at_or_after_it():
    clock = RealClock(spin=0.0002)
    clock.now = ScriptedTime(11.0, 11.0, 12.0)
    assert clock.sleep_until(10.0) == 11.0


def test_real_clock_reading_is_never_before_the_deadline_on_the_real_time_source():
    clock = RealClock(spin=0.0002)
    deadline = clock.now()  # already reached: returns without sleeping
    assert clock.sleep_until(deadline) >= deadline


def test_manual_clock_moves_to_the_deadline_and_returns_it():
    clock = ManualClock(1.0)
    assert clock.sleep_until(2.5) == 2.5 and clock.now() == 2.5
    assert clock.sleep_until(2.0) == 2.5  # a deadline gone: time does not go back


def test_sim_clock_never_waits_and_returns_the_released_tick():
    header = np.zeros(HEADER_WORDS, dtype=np.int64)
    header[Header.SIM_TIME_NS] = 3_000_000
    clock = SimClock(header, 0.001)
    assert clock.sleep_until(5.0) == 0.003


# --- the executive's use of the reading --------------------------------------------------------


class Idle(PortBasedObject):
    """Fake module: does nothing."""

    out = OutVar("out")

    def cycle(self) -> Status:
        return Status.CONTINUE


class LateReadingClock(ManualClock):
    """A manual clock whose wait ends at the deadline, but every later reading is `work` further on:
    the Python work a real executive does after its spin."""

    def __init__(self, work: float) -> None:
        super().__init__(0.0)
        self.work = work

    def now(self) -> float:
        self.time += self.work
        return self.time


class NoSignals:
    def receive(self, timeout):
        return None


@pytest.fixture
def executive_on(make_table):
    def build(clock: ManualClock) -> tuple[Executive, Task]:
        table = make_table(variables(("o0", "float64", ())))
        executive = Executive(clock, NoSignals(), lambda event: None, epoch=0.0)
        task = Task(task_spec(Idle, name="idle", ports={"out": "o0"}, period=0.001), Idle, table)
        executive.add(task)
        executive.handle(["spawn", "idle"])
        executive.handle(["on", "idle", 0.001])
        return executive, task

    return build


def test_executive_times_the_release_at_the_instant_the_wait_ended(executive_on):
    clock = LateReadingClock(work=0.00001)
    executive, task = executive_on(clock)
    executive.run_once()
    assert task.cycles == 1
    assert task.status[W.JITTER_LAST] == 0.0  # the wait's reading, not the later one (10 µs on)
    assert task.status[W.EXEC_LAST] > 0.0  # the work after the wait counts as execution time


def test_executive_reads_the_clock_again_for_a_second_task_released_together(executive_on, make_table):
    clock = LateReadingClock(work=0.00001)
    executive, first = executive_on(clock)
    table = make_table(variables(("o1", "float64", ())))
    second = Task(task_spec(Idle, name="other", ports={"out": "o1"}, period=0.001), Idle, table)
    executive.add(second)
    executive.handle(["spawn", "other"])
    executive.handle(["on", "other", 0.001])
    executive.run_once()
    assert first.cycles == second.cycles == 1
    jitters = sorted((first.status[W.JITTER_LAST], second.status[W.JITTER_LAST]))
    assert jitters[0] == 0.0 and jitters[1] > 0.0  # the second waited for the first's cycle


@pytest.mark.parametrize("n_rtpus, offsets_ms", [(1, [0.0]), (2, [0.0, 0.5]), (4, [0.0, 0.25, 0.5, 0.75])])
def test_rtpus_release_evenly_spaced_over_the_shortest_period(n_rtpus, offsets_ms):
    stagger = release_stagger(0.001, n_rtpus)
    assert [round(i * stagger * 1e3, 9) for i in range(n_rtpus)] == offsets_ms


def test_the_last_rtpu_releases_a_full_stagger_before_the_first_one_releases_again():
    stagger = release_stagger(0.002, 3)
    assert 0.002 - 2 * stagger == pytest.approx(stagger)
