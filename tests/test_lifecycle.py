"""Figure 11, transfer by transfer and transition by transition, with real tables and no process."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np
import pytest

from pbo_runtime import InBoth, InConst, InVar, LifecycleError, ModuleError, OutBoth, OutConst, OutVar, PortBasedObject, Status
from pbo_runtime.objects.module import TaskContext
from pbo_runtime.table.table import Flag, StatusWord, TaskState
from pbo_runtime.task.lifecycle import Task
from tests.support import allocation_peak, one_array, task_spec, variables

VARS = variables(
    ("k_in", "float64", (2,)), ("k_out", "float64", (2,)), ("u", "float64", (2,)), ("y", "float64", (2,)),
    ("b_in", "float64", ()), ("b_out", "float64", ()), ("n", "int32", ()),
)


class Recorder(PortBasedObject):
    """Fake module that records what its ports held when each component ran."""

    k_in = InConst("k_in", shape=(2,))
    n = InConst("n", dtype="int32")
    b_in = InBoth("b_in")
    u = InVar("u", shape=(2,))
    k_out = OutConst("k_out", shape=(2,))
    b_out = OutBoth("b_out")
    y = OutVar("y", shape=(2,))

    fail_in: str = ""
    seen: dict

    def init(self, params):
        self.seen = {"init": (self.k_in.copy(), int(self.n), float(self.b_in))}
        self.calls = ["init"]
        if self.fail_in == "init":
            raise RuntimeError("init failed on purpose")
        self.k_out = self.k_in * 2
        self.b_out = 5.0

    def on(self):
        self.calls.append("on")
        self.seen["on"] = (self.u.copy(), self.y.copy())
        self.y = self.y + 100.0

    def cycle(self):
        self.calls.append("cycle")
        if self.fail_in == "cycle":
            raise ValueError("cycle failed on purpose")
        if self.fail_in == "cycle-status":
            return Status.ERROR
        self.seen["cycle"] = (self.u.copy(), float(self.b_in))
        np.add(self.u, 1.0, out=self.y)
        self.b_out = float(self.b_in) + 1
        return Status.OFF if self.fail_in == "stop" else Status.CONTINUE

    def off(self):
        self.calls.append("off")

    def kill(self):
        self.calls = [*getattr(self, "calls", []), "kill"]

    def error(self, exc):
        self.calls.append("error")
        return {"recover": Status.CONTINUE, "stop": Status.OFF}.get(getattr(self, "verdict", ""), Status.ERROR)

    def clear(self):
        self.calls.append("clear")
        return getattr(self, "clearable", True)


@pytest.fixture
def table(make_table):
    t = make_table(VARS)
    t.write("k_in", [1.0, 2.0], when=0)
    t.write("n", 6, when=0)
    t.write("b_in", 3.0, when=0)
    t.write("u", [10.0, 20.0], when=0)
    t.write("y", [7.0, 8.0], when=0)
    return t


def make_task(table, fail_in: str = "") -> Task:
    task = Task(task_spec(Recorder, index=1), Recorder, table)
    task.module.fail_in = fail_in
    return task


def test_in_consts_are_read_before_init(table):
    task = make_task(table)
    assert task.spawn(0.0)
    k, n, b = task.module.seen["init"]
    assert k.tolist() == [1.0, 2.0] and n == 6 and b == 3.0


def test_out_consts_are_written_after_init(table):
    task = make_task(table)
    task.spawn(0.5)
    value, _seq, when, writer = table.read("k_out")
    assert value.tolist() == [2.0, 4.0] and writer == 1 and when == 0.5
    assert table.read("b_out")[0] == 5.0


def test_spawn_leaves_the_task_off(table):
    task = make_task(table)
    task.spawn(0.0)
    assert task.state is TaskState.OFF
    assert table.status[1][0] == TaskState.OFF


def test_a_task_spawned_into_a_killed_tasks_status_block_keeps_none_of_its_counts_but_its_last_write_time(table):
    block = table.status[1]
    block[:] = 99.0  # what the killed task left: cycles, overruns, jitter, errors, percentiles
    block[StatusWord.STATE] = TaskState.KILLED
    block[StatusWord.RELEASE] = 12.5  # when it last wrote: readers judge the age of its values by it
    task = make_task(table)
    expected = [0.0] * len(block)
    expected[StatusWord.RELEASE] = 12.5
    assert block.tolist() == expected
    assert task.status.tolist() == expected[:len(task.status)] and len(task.status) > StatusWord.RELEASE
    task.spawn(13.0)
    assert table.status[1][StatusWord.STATE] == TaskState.OFF and table.status[1][StatusWord.CYCLES] == 0


def test_init_that_raises_runs_kill_and_creates_no_task(table):
    task = make_task(table, fail_in="init")
    assert not task.spawn(0.0)
    assert task.state is TaskState.KILLED
    assert task.module.calls == ["init", "kill"]
    assert "init raised RuntimeError: init failed on purpose" in task.last_error
    assert table.read("k_out")[3] == -1  # nothing was written: the out-consts never left


def test_in_vars_and_out_vars_are_read_before_on(table):
    task = make_task(table)
    task.spawn(0.0)
    task.turn_on(1.0)
    u, y = task.module.seen["on"]
    assert u.tolist() == [10.0, 20.0]
    assert y.tolist() == [7.0, 8.0]  # took over the value another task had left


def test_out_vars_are_written_after_on(table):
    task = make_task(table)
    task.spawn(0.0)
    task.turn_on(1.0)
    assert table.read("y")[0].tolist() == [107.0, 108.0]
    assert task.state is TaskState.ON


def test_in_vars_are_read_before_each_cycle_and_out_vars_written_after(table):
    task = make_task(table)
    task.spawn(0.0)
    task.turn_on(1.0)
    table.write("u", [1.0, 2.0], when=1.0)
    table.write("b_in", 9.0, when=1.0)
    assert task.run_cycle(1.001) is Status.CONTINUE
    assert task.module.seen["cycle"][0].tolist() == [1.0, 2.0]
    assert task.module.seen["cycle"][1] == 9.0  # in-both is also read every cycle
    value, seq, when, _writer = table.read("y")
    assert value.tolist() == [2.0, 3.0] and seq == 1 and when == 1.001
    assert table.read("b_out")[0] == 10.0  # out-both is also written every cycle


def test_cycle_returning_off_turns_the_task_off(table):
    task = make_task(table, fail_in="stop")
    task.spawn(0.0)
    task.turn_on(0.0)
    assert task.run_cycle(0.001) is Status.OFF
    assert task.state is TaskState.OFF
    assert task.module.calls[-1] == "off"


def test_cycle_that_raises_calls_error_and_waits_in_error(table):
    task = make_task(table, fail_in="cycle")
    task.spawn(0.0)
    task.turn_on(0.0)
    assert task.run_cycle(0.001) is Status.ERROR
    assert task.state is TaskState.ERROR
    assert task.module.calls[-2:] == ["cycle", "error"]
    assert "cycle raised ValueError: cycle failed on purpose" in task.last_error
    assert table.status[1][0] == TaskState.ERROR


def test_cycle_returning_error_calls_error_too(table):
    task = make_task(table, fail_in="cycle-status")
    task.spawn(0.0)
    task.turn_on(0.0)
    assert task.run_cycle(0.001) is Status.ERROR
    assert task.module.calls[-1] == "error"


def test_error_component_that_recovers_keeps_the_task_on(table):
    task = make_task(table, fail_in="cycle")
    task.module.verdict = "recover"
    task.spawn(0.0)
    task.turn_on(0.0)
    assert task.run_cycle(0.001) is Status.CONTINUE
    assert task.state is TaskState.ON


def test_clear_returns_a_fixed_task_to_off(table):
    task = make_task(table, fail_in="cycle")
    task.spawn(0.0)
    task.turn_on(0.0)
    task.run_cycle(0.001)
    assert task.clear()
    assert task.state is TaskState.OFF


def test_clear_leaves_an_unfixed_task_in_error(table):
    task = make_task(table, fail_in="cycle")
    task.spawn(0.0)
    task.turn_on(0.0)
    task.run_cycle(0.001)
    task.module.clearable = False
    assert not task.clear()
    assert task.state is TaskState.ERROR


def test_kill_from_on_turns_off_first_then_kills(table):
    task = make_task(table)
    task.spawn(0.0)
    task.turn_on(0.0)
    task.kill()
    assert task.module.calls[-2:] == ["off", "kill"]
    assert task.state is TaskState.KILLED


def test_on_is_refused_unless_the_task_is_off(table):
    task = make_task(table)
    with pytest.raises(LifecycleError, match=r"^task 't' cannot take 'on' in state NOT_CREATED \(needs OFF\)$"):
        task.turn_on(0.0)


class Refuser(PortBasedObject):
    """Fake module: returns ERROR with its reason through `fault`."""

    y = OutVar("y", shape=(2,))

    def cycle(self):
        return self.fault("the goal has 2 values, got 5")


def test_a_cycle_that_returns_a_fault_reports_its_reason(table):
    task = Task(task_spec(Refuser, index=2), Refuser, table)
    task.spawn(0.0)
    task.turn_on(0.0)
    assert task.run_cycle(0.001) is Status.ERROR
    assert task.last_error == "cycle returned ERROR: the goal has 2 values, got 5"


def test_a_tasks_context_is_the_task_context_modules_see(table):
    task = make_task(table)
    assert isinstance(task.context, TaskContext)
    assert task.module._pbo_context is task.context


def test_a_module_sees_actuators_held_while_job_controls_flag_is_set_at_no_allocation(table):
    task = make_task(table)
    assert task.module.actuators_held is False
    table.set_flag(Flag.ILLEGAL_CONFIGURATION)  # a critical task's stable episode is open, or a task is in ERROR
    assert task.module.actuators_held is True
    assert allocation_peak(lambda: task.module.actuators_held) < one_array()
    table.set_flag(Flag.ILLEGAL_CONFIGURATION, False)
    assert task.module.actuators_held is False


def test_a_module_reads_when_a_ports_value_was_written_and_minus_infinity_for_never(table):
    task = make_task(table)
    assert task.module.written_at("k_out") == -np.inf  # not spawned: nothing wrote it yet
    assert task.module.written_at("u") == 0.0  # the fixture's job control wrote it at 0
    table.write("u", [1.0, 2.0], when=0.25)
    assert task.module.written_at("u") == 0.25
    with pytest.raises(ModuleError, match=r"^task 't' has no port 'v' bound to a variable$"):
        task.module.written_at("v")


# --- issue 18: non-finite outputs never reach the table ------------------------------------------

NON_FINITE_VARS = variables(("x", "float64", (3,)), ("w", "float32", (2,)), ("count", "int32", (2,)), ("src", "float64", ()))


class Emitter(PortBasedObject):
    """Fake module: writes what the test sets in `emit` to its float64, float32 and int32 out-vars."""

    src = InVar("src")
    x = OutVar("x", shape=(3,))
    w = OutVar("w", dtype="float32", shape=(2,))
    count = OutVar("count", dtype="int32", shape=(2,))

    emit: Mapping[str, Any] = MappingProxyType({})  # make() gives each instance a dict of its own
    verdict = Status.ERROR
    errors_seen: list

    def init(self, params):
        self.errors_seen = []

    def on(self):
        self.cycle()

    def cycle(self):
        for name, value in self.emit.items():
            getattr(self, name)[...] = value
        np.add(self.count, 1, out=self.count)
        return Status.CONTINUE

    def error(self, exc):
        self.errors_seen.append(exc)
        return self.verdict


@pytest.fixture
def emitter(make_table):
    table = make_table(NON_FINITE_VARS)

    def make(**emit) -> Task:
        task = Task(task_spec(Emitter, name="emitter", index=0), Emitter, table)
        task.module.emit = {"x": [1.0, 2.0, 3.0], "w": [0.5, 0.25]}
        assert task.spawn(0.0) and task.turn_on(0.0)
        task.module.emit = {**task.module.emit, **emit}
        return task

    return make, table


@pytest.mark.parametrize("emit, named", [
    ({"x": [1.0, np.nan, 3.0]}, "out-var 'x'"),
    ({"x": [np.inf, 0.0, 0.0]}, "out-var 'x'"),
    ({"w": [0.0, -np.inf]}, "out-var 'w'"),
    ({"x": [np.nan] * 3, "w": [np.nan, 0.0]}, "out-vars 'x', 'w'"),
], ids=["nan", "inf", "float32", "both"])
def test_a_cycle_whose_float_outputs_are_not_finite_goes_to_error_and_writes_nothing(emitter, emit, named):
    make, table = emitter
    task = make()
    assert task.run_cycle(0.001) is Status.CONTINUE
    before = {name: table.read(name) for name in ("x", "w", "count")}
    task.module.emit.update(emit)
    assert task.run_cycle(0.002) is Status.ERROR
    assert task.state == TaskState.ERROR and task.module.errors_seen == [None]
    assert task.last_error == f"cycle: {named} not finite (NaN or Inf); not written to the table"
    for name in ("x", "w", "count"):  # not a value, not a sequence number, nothing moved (the int out-var either)
        value, seq, when, _ = table.read(name)
        assert value.tolist() == before[name][0].tolist() and (seq, when) == before[name][1:3]


def test_an_error_component_that_recovers_keeps_the_task_on_but_writes_nothing_non_finite(emitter):
    make, table = emitter
    task = make(x=[np.nan, 0.0, 0.0])
    task.module.verdict = Status.CONTINUE
    assert task.run_cycle(0.001) is Status.CONTINUE and task.state == TaskState.ON
    assert np.isfinite(table.read("x")[0]).all()


def test_outputs_that_are_not_finite_after_on_put_the_task_in_error_before_they_are_written(emitter, make_table):
    _make, table = emitter
    task = Task(task_spec(Emitter, name="emitter", index=0), Emitter, table)
    task.module.emit = {"x": [0.0, np.inf, 0.0], "w": [0.0, 0.0]}
    assert task.spawn(0.0)
    assert task.turn_on(0.0) is False and task.state == TaskState.ERROR
    assert task.last_error == "on: out-var 'x' not finite (NaN or Inf); not written to the table"
    assert table.read("x")[0].tolist() == [0.0, 0.0, 0.0]


def test_integer_out_vars_are_not_checked_and_finite_floats_of_any_size_pass(emitter):
    make, table = emitter
    task = make(x=[1e308, -1e308, 0.0], count=[2**31 - 2, -(2**31)])
    assert task.run_cycle(0.001) is Status.CONTINUE
    assert table.read("x")[0].tolist() == [1e308, -1e308, 0.0]


def test_the_finite_check_allocates_no_array(emitter):
    make, _ = emitter
    task = make()
    assert task.local.outputs_finite()
    assert allocation_peak(task.local.outputs_finite) < one_array()  # at most Python's own loop over the two float dtypes


# --- issue 22: off places final values; an error after init goes to the error component ----------

OFF_VARS = variables(("y", "float64", (2,)))


class Offender(PortBasedObject):
    """Fake module: its cycles write [1, 1], its off the final [0, 0]; `failing` names the one
    component that raises, `verdict` what its error component answers (`error`: it raises too)."""

    y = OutVar("y", shape=(2,))

    failing = ""
    verdict: object = Status.ERROR
    cycle_returns = Status.CONTINUE

    def _maybe_fail(self, component):
        self.calls.append(component)
        if self.failing == component:
            raise RuntimeError(f"{component} failed on purpose")

    def init(self, params):
        self.calls = ["init"]
        self.errors_seen = []
        self.final = np.zeros(2)

    def on(self):
        self._maybe_fail("on")

    def cycle(self):
        self._maybe_fail("cycle")
        self.y[...] = 1.0
        return self.cycle_returns

    def off(self):
        self.y[...] = self.final
        if self.failing:  # recorded only then: the allocation test measures an off that appends nothing
            self._maybe_fail("off")

    def kill(self):
        self._maybe_fail("kill")

    def clear(self):
        self._maybe_fail("clear")
        return True

    def error(self, exc):
        self.calls.append("error")
        self.errors_seen.append(str(exc))
        if self.verdict == "error":
            raise ValueError("error failed too")
        return self.verdict


@pytest.fixture
def offender(make_table):
    table = make_table(OFF_VARS)

    def make(failing: str = "", verdict: object = Status.ERROR) -> Task:
        task = Task(task_spec(Offender, name="offender", index=0), Offender, table)
        assert task.spawn(0.0)
        task.module.failing, task.module.verdict = failing, verdict
        return task

    return make, table


def cycled(task: Task) -> Task:
    assert task.turn_on(0.0)
    assert task.run_cycle(0.001) is Status.CONTINUE
    return task


def test_off_places_its_final_values_on_the_output_ports_issue_22(offender):
    make, table = offender
    task = cycled(make())
    assert table.read("y")[0].tolist() == [1.0, 1.0]
    task.turn_off(0.0015)
    value, _seq, when, writer = table.read("y")
    assert value.tolist() == [0.0, 0.0] and when == 0.0015 and writer == 0
    assert task.state is TaskState.OFF and table.status[0][StatusWord.STATE] == TaskState.OFF


@pytest.mark.parametrize("how", ["cycle returned OFF", "kill from ON", "error component turned it off"])
def test_every_way_of_turning_off_writes_the_final_values(offender, how):
    make, table = offender
    task = cycled(make())
    if how == "cycle returned OFF":
        task.module.cycle_returns = Status.OFF
        assert task.run_cycle(0.002) is Status.OFF
    elif how == "kill from ON":
        task.kill(0.002)
    else:
        task.module.failing, task.module.verdict = "cycle", Status.OFF
        assert task.run_cycle(0.002) is Status.OFF
    assert table.read("y")[0].tolist() == [0.0, 0.0]


def test_final_values_that_are_not_finite_are_not_written_and_go_to_the_error_component(offender):
    make, table = offender
    task = cycled(make())
    task.module.final[1] = np.nan
    task.turn_off(0.002)
    assert task.state is TaskState.ERROR and task.module.calls[-1] == "error"
    assert task.last_error == "off: out-var 'y' not finite (NaN or Inf); not written to the table"
    assert table.read("y")[0].tolist() == [1.0, 1.0]


def test_turning_off_allocates_no_array(offender):
    make, _ = offender
    task = cycled(make())

    def off_and_on():
        task.turn_off(0.002)
        task.state = TaskState.ON  # back ON without on's own transfers: only off's path is measured

    assert allocation_peak(off_and_on) < one_array()


ON, OFF, ERROR = TaskState.ON, TaskState.OFF, TaskState.ERROR


@pytest.mark.parametrize("component, verdict, state", [
    ("on", Status.CONTINUE, ON), ("on", Status.OFF, OFF), ("on", Status.ERROR, ERROR), ("on", "error", ERROR),
    ("cycle", Status.CONTINUE, ON), ("cycle", Status.OFF, OFF), ("cycle", Status.ERROR, ERROR), ("cycle", "error", ERROR),
    ("off", Status.CONTINUE, OFF), ("off", Status.OFF, OFF), ("off", Status.ERROR, ERROR), ("off", "error", ERROR),
    ("clear", Status.CONTINUE, OFF), ("clear", Status.OFF, OFF), ("clear", Status.ERROR, ERROR), ("clear", "error", ERROR),
    ("kill", Status.CONTINUE, TaskState.KILLED), ("kill", "error", TaskState.KILLED),
], ids=lambda v: getattr(v, "name", v))
def test_an_error_after_init_goes_to_the_error_component_whichever_component_raised_issue_22(offender, component, verdict, state):
    make, table = offender
    task = make(failing=component, verdict=Status.ERROR if component == "clear" else verdict)
    if component == "on":
        assert task.turn_on(0.0) is (state is ON)
    elif component == "cycle":
        assert task.turn_on(0.0)
        assert task.run_cycle(0.001) is {ON: Status.CONTINUE, OFF: Status.OFF, ERROR: Status.ERROR}[state]
    elif component == "off":
        cycled(task).turn_off(0.002)
    elif component == "clear":
        task.module.failing = "cycle"
        assert task.turn_on(0.0) and task.run_cycle(0.001) is Status.ERROR
        task.module.failing, task.module.verdict = "clear", verdict
        assert task.clear() is (state is OFF)
    else:
        task.kill(0.0)
    assert task.state is state and table.status[0][StatusWord.STATE] == state
    assert task.module.calls[-1] == ("off" if (component, state) == ("cycle", OFF) else "error")
    assert task.module.errors_seen[-1] == f"{component} failed on purpose"
    if state is ERROR or component == "kill":
        assert f"{component} raised RuntimeError: {component} failed on purpose" in task.last_error
    if verdict == "error":
        assert "; error raised ValueError: error failed too" in task.last_error


def test_an_on_whose_error_component_recovers_writes_its_outputs_as_on_would(offender):
    make, table = offender
    task = make(failing="on", verdict=Status.CONTINUE)
    table.write("y", [3.0, 3.0], when=0.25)  # read before on; on fails; the error component recovers
    assert task.turn_on(0.5) and table.read("y")[0].tolist() == [3.0, 3.0] and table.read("y")[2] == 0.5


def test_an_off_whose_error_component_answers_error_writes_no_final_values(offender):
    make, table = offender
    task = cycled(make(failing="off", verdict=Status.ERROR))
    task.turn_off(0.002)
    assert task.state is ERROR and table.read("y")[0].tolist() == [1.0, 1.0]


def test_a_failed_init_still_kills_without_the_error_component(offender, make_table):
    task = Task(task_spec(Offender, name="offender", index=0), Offender, make_table(OFF_VARS))
    task.module.init = lambda params: (_ for _ in ()).throw(RuntimeError("init failed"))
    task.module.error = lambda exc: pytest.fail("error must not run for a failed init")
    assert not task.spawn(0.0) and task.state is TaskState.KILLED
