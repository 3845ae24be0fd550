"""The RTPU's background thread (`task.background`): slow work a task's off or kill hands off runs
there, in order, at a lower priority, is waited for at the RTPU's stop, and a failure is reported
as the task's error, never lost."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import threading
from typing import ClassVar

import pytest

from pbo_runtime import DeviceDriver, OutputError, OutVar, PortBasedObject
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.config.model import DeviceSpec
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.messages import StateChanged
from pbo_runtime.task.background import Background, Failure, close_process_background
from pbo_runtime.task.lifecycle import Task
from rtpu._executive import Executive
from tests.support import REPO, FakeSignals, run_until, task_spec, variables


def test_work_handed_off_runs_in_another_thread_in_the_order_handed_and_hand_off_does_not_wait_for_it():
    worker = Background("test-background")
    gate, ran = threading.Event(), []
    worker.hand_off(gate.wait, "a", "waiting at the gate")
    for n in range(3):
        worker.hand_off(lambda n=n: ran.append((n, threading.current_thread().name)), "a", f"piece {n}")
    assert ran == [] and worker.pending == 4  # the first still waits at the gate: nothing after it ran
    gate.set()
    assert worker.close() == []
    assert ran == [(0, "test-background"), (1, "test-background"), (2, "test-background")]
    assert worker.pending == 0 and worker.done == 4


def test_close_waits_for_everything_handed_off_and_the_thread_ends():
    worker = Background()
    finished = []
    for n in range(5):
        worker.hand_off(lambda n=n: finished.append(n), "t", "a piece")
    assert worker.close() == [] and finished == [0, 1, 2, 3, 4]
    with pytest.raises(RuntimeError, match="closed"):
        worker.hand_off(lambda: None, "t", "too late")


@pytest.mark.parametrize(("error", "output"), [(OutputError("cannot finish log x.mcap: disk full"), True),
                                               (RuntimeError("the helper did not answer"), False)])
def test_a_failure_is_kept_with_its_task_and_what_failed_and_taken_once(error, output):
    worker = Background()

    def fail() -> None:
        raise error

    worker.hand_off(fail, "logger", "finishing log x.mcap")
    worker.hand_off(lambda: None, "logger", "after the failure")  # the thread goes on
    assert worker.drain()
    assert worker.take_failures() == [Failure("logger", "finishing log x.mcap", f"{type(error).__name__}: {error}", output)]
    assert worker.take_failures() == [] and worker.done == 2
    worker.close()


def test_work_that_has_not_ended_when_the_rtpu_stops_is_a_failure_not_a_hang():
    worker = Background()
    gate = threading.Event()
    worker.hand_off(gate.wait, "stuck", "joining a helper that never ends")
    [failure] = worker.close(patience=0.01)
    assert (failure.task, failure.what, failure.output) == ("stuck", "joining a helper that never ends", False)
    assert "had not ended" in failure.error
    gate.set()


HELPER_POLICY = ("import os, sys, threading; from pbo_runtime.task.background import Background\n"
                 "if sys.argv[1] == 'fifo':\n"
                 "    try: os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(50))\n"
                 "    except OSError as exc: print('refused', exc); sys.exit(0)\n"
                 "seen = []; worker = Background(); me = threading.get_native_id\n"
                 "worker.hand_off(lambda: seen.append((os.sched_getscheduler(me()) & ~os.SCHED_RESET_ON_FORK, "
                 "os.sched_getparam(me()).sched_priority)), 't', 'look')\n"
                 "worker.close(); print(seen[0] == (os.SCHED_FIFO, 1), seen[0] == (os.SCHED_OTHER, 0), os.sched_getscheduler(0))")


@pytest.mark.multiprocess
@pytest.mark.parametrize("executive", ["fifo", "other"])
def test_the_thread_runs_just_below_the_executive_at_the_lowest_real_time_priority_or_at_sched_other(executive):
    """At SCHED_OTHER under a SCHED_FIFO executive, preempted while it holds the GIL, it would
    hold the executive off its release: a priority inversion."""
    done = subprocess.run([sys.executable, "-c", HELPER_POLICY, executive], capture_output=True, text=True, cwd=REPO,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    if done.stdout.startswith("refused"):
        pytest.skip(f"SCHED_FIFO refused here: {done.stdout.strip()}")
    lowest_fifo, other, executive_policy = done.stdout.split()
    if executive == "fifo":
        assert (lowest_fifo, int(executive_policy) & ~os.SCHED_RESET_ON_FORK) == ("True", os.SCHED_FIFO)
    else:
        assert (other, int(executive_policy)) == ("True", os.SCHED_OTHER)


class SlowToKill(PortBasedObject):
    """Fake module: its kill hands its slow part off, as a data logger's does."""

    out = OutVar("out")
    finished: ClassVar[list[str]] = []
    fail: ClassVar[bool] = False

    def kill(self) -> None:
        def finish() -> None:
            if self.fail:
                raise OutputError(f"cannot finish {self.task_name}'s file")
            SlowToKill.finished.append(self.task_name)

        self.hand_off(finish, "finishing its file")


@pytest.mark.parametrize("fail", [False, True])
def test_the_rtpu_waits_for_what_a_kill_handed_off_at_its_stop_and_reports_a_failure_as_the_tasks_output(make_table, fail):
    SlowToKill.finished, SlowToKill.fail = [], fail
    table = make_table(variables(("o0", "float64", ())))
    clock = ManualClock(0.0)
    events: list[messages.Event] = []
    executive = Executive(clock, FakeSignals(clock, [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0]), (0.003, ["stop"])]),
                          events.append, epoch=0.0)
    spec = dataclasses.replace(task_spec(SlowToKill, name="a", index=0, ports={"out": "o0"}, period=0.001))
    executive.add(Task(spec, SlowToKill, table))
    run_until(executive, clock, 0.01)
    assert not executive.running
    assert SlowToKill.finished == ([] if fail else ["a"])  # done before the RTPU's stop returned
    failed = [e for e in events if isinstance(e, StateChanged) and e.output_failed]
    assert failed == ([StateChanged("a", "KILLED", "finishing its file failed: OutputError: cannot finish a's file", True)]
                      if fail else [])


class SlowToClose(DeviceDriver):
    """Fake driver: closing it waits for something (a process's exit), the rest `close_now` returns."""

    def close_now(self):
        SlowToClose.closed.append(("now", threading.current_thread().name))
        return lambda: SlowToClose.closed.append(("rest", threading.current_thread().name))


class OpensADevice(PortBasedObject):
    out = OutVar("out")

    def init(self, params) -> None:
        self.open_device("dev")


def test_a_killed_tasks_driver_closes_now_between_cycles_and_the_rest_of_closing_runs_in_the_background(make_table):
    SlowToClose.closed = []
    table = make_table(variables(("o0", "float64", ())))
    spec = dataclasses.replace(task_spec(OpensADevice, name="a", ports={"out": "o0"}), resources=("dev",))
    task = Task(spec, OpensADevice, table, devices={"dev": DeviceSpec("dev", "slow")},
                opener=lambda device, spec: SlowToClose("registers", {}))
    assert task.spawn(0.0), task.last_error
    task.kill(0.0)
    assert close_process_background() == []
    assert SlowToClose.closed == [("now", threading.current_thread().name), ("rest", "pbo-background")]


LATE_FIFO = ("import os, threading; from pbo_runtime.objects.helper_threads import below_the_cycle, lower_helpers\n"
             "ready, done = threading.Event(), threading.Event(); me = []\n"
             "def helper(): below_the_cycle(); me.append(threading.get_native_id()); ready.set(); done.wait()\n"
             "threading.Thread(target=helper).start(); ready.wait()\n"
             "before = os.sched_getscheduler(me[0])\n"
             "try: os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(50))\n"
             "except OSError as exc: print('refused', exc); done.set(); raise SystemExit\n"
             "lower_helpers(); print(before == os.SCHED_OTHER, (os.sched_getscheduler(me[0]) & ~os.SCHED_RESET_ON_FORK, "
             "os.sched_getparam(me[0]).sched_priority) == (os.SCHED_FIFO, 1)); done.set()")


CHILD_OF_A_HELPER = ("import os, subprocess, sys, threading; from pbo_runtime.objects.helper_threads import below_the_cycle\n"
                     "try: os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(50))\n"
                     "except OSError as exc: print('refused', exc); raise SystemExit\n"
                     "seen = []\n"
                     "def helper():\n"
                     "    below_the_cycle()\n"
                     "    seen.append(subprocess.run([sys.executable, '-c', 'import os; print(os.sched_getscheduler(0))'],\n"
                     "                               capture_output=True, text=True).stdout.strip())\n"
                     "thread = threading.Thread(target=helper); thread.start(); thread.join(); print(seen[0])")


@pytest.mark.multiprocess
def test_a_process_a_helper_thread_starts_begins_at_sched_other_not_at_its_real_time_priority():
    """A log's encoder, started by the log's writer thread: its interpreter's start-up at the helper's
    SCHED_FIFO would hold both CPUs from every ordinary process (a device's processor among them)."""
    done = subprocess.run([sys.executable, "-c", CHILD_OF_A_HELPER], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert done.returncode == 0, done.stderr
    if done.stdout.startswith("refused"):
        pytest.skip(f"SCHED_FIFO refused here: {done.stdout.strip()}")
    assert int(done.stdout) == os.SCHED_OTHER


@pytest.mark.multiprocess
def test_a_helper_started_before_a_restarted_rtpu_takes_sched_fifo_is_lowered_below_it_when_it_does():
    done = subprocess.run([sys.executable, "-c", LATE_FIFO], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert done.returncode == 0, done.stderr
    if done.stdout.startswith("refused"):
        pytest.skip(f"SCHED_FIFO refused here: {done.stdout.strip()}")
    assert done.stdout.split() == ["True", "True"]
