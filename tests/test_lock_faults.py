"""Nothing wedges a run (issue 18): observers read the table without its lock, a lock holder past the
bound is ended, and `pbo stop`, the duration, SIGTERM and Ctrl-C end a run with stopped children."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from pbo_runtime.supervisor.failures import RunFailure, StopRequested
from pbo_runtime.supervisor.lock_watch import LOCK_HOLD_FLOOR, LOCK_LOOK_EVERY, LockGuard, LockSample, LockWatch, lock_hold_bound
from pbo_runtime.supervisor.run_report import RunResult
from pbo_runtime.table import svar
from pbo_runtime.table.snapshot import TableBusy
from pbo_runtime.table.table import Header
from tests.support import (
    PBO,
    REPO,
    assert_ended_cleanly,
    demo_copy,
    process_state,
    run_processes,
    start_run,
    stop_process,
    stop_while_holding_the_lock,
    table_of,
    until,
    variables,
)

VARS = variables(("a", "float64", (6,)), ("b", "int64", (3,)))

HOLD_THE_LOCK = """
import os, signal, sys, numpy as np, posix_ipc
from pbo_runtime.ipc import shm
name = sys.argv[1]
lock = posix_ipc.Semaphore(name + ".lock")
header = np.frombuffer(shm.attach_segment(name), dtype=np.int64, count=16)
lock.acquire()
header[4] = os.getpid()  # signed, as every holder signs it
print("holding", flush=True)
os.kill(os.getpid(), signal.SIGSTOP)
"""


def hold_the_lock(table_name: str) -> subprocess.Popen:
    """A child process that takes the table lock, signs it and stops itself (SIGSTOP) holding it."""
    holder = subprocess.Popen([sys.executable, "-c", HOLD_THE_LOCK, table_name], stdout=subprocess.PIPE, text=True, cwd=REPO)
    assert holder.stdout is not None and holder.stdout.readline().strip() == "holding"
    until(lambda: process_state(holder.pid) in ("T", "t"), "the holder to stop")
    return holder


def end(holder: subprocess.Popen) -> None:
    holder.kill()
    holder.wait()


# --- observers never take the lock ---------------------------------------------------------------


@pytest.mark.multiprocess
def test_an_observer_reads_a_consistent_snapshot_while_another_process_holds_the_lock(make_table):
    table = make_table(VARS)
    table.write("a", np.arange(6.0), when=1.5)
    table.write("b", [7, 8, 9], when=2.5)
    holder = hold_the_lock(table.name)
    try:
        assert table.lock.value == 0
        with svar.attach(table.name) as view:
            value, seq, when, writer = view.read("a")
            assert value.tolist() == list(np.arange(6.0)) and (seq, when, writer) == (1, 1.5, -1)
            assert view.read("b")[0].tolist() == [7, 8, 9]
            assert len(view.task_status()) == table.layout.n_tasks
        assert table.read("b")[0].tolist() == [7, 8, 9]  # job control's reads too
    finally:
        end(holder)


WRITE_FOR_EVER = """
import sys
import numpy as np
from pbo_runtime.table.table import StateTable, TableLayout
from tests.support import variables
table = StateTable.attach(TableLayout.build(variables(("a", "float64", (6,)), ("b", "int64", (3,))), 4), sys.argv[1])
k = 0
while True:
    k += 1
    table.write("a", np.full(6, float(k)), when=float(k))
"""


@pytest.mark.multiprocess
def test_a_snapshot_taken_while_another_process_writes_is_never_torn(make_table):
    """A read either sees one whole write or says the table is busy (the writer lost its CPU
    mid-write through every try, as a loaded machine may make it): never a torn value."""
    table = make_table(VARS)
    writer = subprocess.Popen([sys.executable, "-c", WRITE_FOR_EVER, table.name], cwd=REPO)
    try:
        with svar.attach(table.name) as view:
            until(lambda: view.read("a")[1] > 10, "the writer to write")
            whole = busy_in_a_row = 0
            while whole < 3000:
                try:
                    value, seq, when, _ = view.read("a")
                except TableBusy:
                    busy_in_a_row += 1
                    assert busy_in_a_row < 1000, "the writer never ended a write"
                    continue
                busy_in_a_row = 0
                assert value.min() == value.max() == when == seq, f"torn: {value}, written {when}, sequence {seq}"
                whole += 1
    finally:
        end(writer)


def test_a_writer_stopped_mid_write_makes_observers_report_the_table_busy_instead_of_waiting(make_table):
    table = make_table(VARS)
    table.acquire()
    before = table.begin_write()  # ... and never ends it, like a writer stopped there
    try:
        with svar.attach(table.name) as view, pytest.raises(TableBusy, match=r"^table busy: '"):
            view.read("a")
        with pytest.raises(TableBusy):
            table.read("a")
    finally:
        table.end_write(before)
        table.release()
    assert table.read("a")[1] == 0


def test_a_recovered_lock_of_a_writer_that_died_mid_write_lets_observers_read_again(make_table):
    table = make_table(VARS)
    table.acquire()
    dead = 2**22 + 1  # above pid_max: no live process has it
    table.header[Header.LOCK_SEQUENCE] = 2 * dead + 1  # its writer tag: it died writing
    assert table.lock_holder == dead
    assert table.recover_lock_from(dead, settle=0.0)
    assert table.lock_sequence % 2 == 0
    assert table.read("a")[0].tolist() == [0.0] * 6


# --- the lock watch, on a manual clock ----------------------------------------------------------


class Looks:
    """What the lock record shows at each look, and a manual clock."""

    def __init__(self) -> None:
        self.now = 0.0
        self.sample = LockSample(False, 0, 0)


@pytest.fixture
def looks() -> Looks:
    return Looks()


def test_a_holding_is_reported_once_it_has_lasted_the_bound(looks):
    watch = LockWatch(0.05, lambda: looks.sample, lambda: looks.now)
    looks.sample = LockSample(True, 1234, 8)
    for _ in range(5):
        assert watch.look() is None
        looks.now += 0.01
    holding = watch.look()
    assert holding is not None and holding.holder == 1234 and holding.seconds == pytest.approx(0.05)


@pytest.mark.parametrize("change", ["sequence", "holder", "released"])
def test_a_lock_taken_again_between_looks_is_a_new_holding(looks, change):
    watch = LockWatch(0.05, lambda: looks.sample, lambda: looks.now)
    for k in range(20):
        if change == "sequence":  # the same RTPU, writing every cycle
            looks.sample = LockSample(True, 1234, 2 * k + 1)
        elif change == "holder":  # two RTPUs taking turns
            looks.sample = LockSample(True, 1234 + k % 2, 8)
        else:  # free at every other look
            looks.sample = LockSample(k % 2 == 0, 1234, 8)
        assert watch.look() is None
        looks.now += 0.01


def test_the_watch_looks_every_half_bound_and_often_while_the_lock_is_taken(looks):
    watch = LockWatch(0.05, lambda: looks.sample, lambda: looks.now)
    watch.look()
    assert watch.next_look_in(0.1) == 0.025 and watch.next_look_in(0.01) == 0.01
    looks.sample = LockSample(True, 1234, 8)
    watch.look()
    assert watch.next_look_in(0.1) == LOCK_LOOK_EVERY


def test_the_bound_is_a_few_periods_of_the_fastest_task_and_never_under_the_floor():
    assert lock_hold_bound(0.001) == LOCK_HOLD_FLOOR
    assert lock_hold_bound(0.1) == pytest.approx(0.5)


# --- a holder past the bound, in a real run -----------------------------------------------------


@pytest.mark.multiprocess
def test_an_rtpu_stopped_while_it_holds_the_lock_is_killed_and_the_run_fails(tmp_path):
    file = demo_copy(tmp_path, "lockstop")
    report = tmp_path / "report.json"
    run = start_run(file, tmp_path, "--duration", "60", "--report", str(report))
    try:
        rtpu0 = run_processes(run)["rtpu0"]
        stop_while_holding_the_lock(rtpu0, table_of(run, "lockstop"))
    except BaseException:
        run.kill()
        raise
    _, err = assert_ended_cleanly(run, "lockstop", report, 2)
    assert f"by RTPU 'rtpu0' (pid {rtpu0}), stopped: it was killed (SIGKILL) and the lock released" in err
    events = json.loads(report.read_text())["lock_events"]
    assert [(e["role"], e["state"], e["action"]) for e in events] == [("rtpu0", "stopped", "killed")]


@pytest.mark.multiprocess
@pytest.mark.parametrize("holder_ends", ["stopped", "killed"])
def test_a_lock_held_by_a_process_outside_the_run_fails_the_run_and_is_never_signalled(tmp_path, holder_ends):
    file = demo_copy(tmp_path, f"lockout{holder_ends[0]}")
    subsystem = file.stem
    report = tmp_path / "report.json"
    run = start_run(file, tmp_path, "--duration", "60", "--report", str(report))
    holder = None
    try:
        holder = hold_the_lock(table_of(run, subsystem))
        if holder_ends == "killed":  # as `kill -9` of a reader that held the lock
            end(holder)
        out, err = assert_ended_cleanly(run, subsystem, report, 2)
        assert out.count("pbo: the table lock was held") == 1, "reported once, though it is held to the end"
        if holder_ends == "stopped":
            assert process_state(holder.pid) in ("T", "t"), "another run's or user's process is never signalled"
            assert f"by pid {holder.pid}, not a process of this run, stopped: it is not a process of this run" in err
        else:
            assert f"by pid {holder.pid}, not a process of this run, dead: the lock was released" in err
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
        if holder is not None and holder.poll() is None:
            end(holder)


# --- every way of stopping a run ends it, stopped children and all ------------------------------


@pytest.mark.multiprocess
@pytest.mark.parametrize("ending", ["pbo stop", "duration", "SIGTERM", "Ctrl-C"])
def test_a_run_with_a_stopped_rtpu_and_a_stopped_plant_always_ends_cleanly(tmp_path, ending):
    subsystem = "stopped" + ending.replace(" ", "").replace("-", "").lower()
    file = demo_copy(tmp_path, subsystem)
    report = tmp_path / "report.json"
    run = start_run(file, tmp_path, "--duration", "6" if ending == "duration" else "60", "--report", str(report))
    try:
        roles = run_processes(run)
        stop_process(roles["plant"])
        stop_process(roles["rtpu1"])
        if ending == "pbo stop":
            stopped = subprocess.run([*PBO, "stop", "--subsystem", subsystem], capture_output=True, text=True, timeout=60)
            assert stopped.returncode == 0, stopped.stderr
        elif ending != "duration":
            os.kill(run.pid, signal.SIGTERM if ending == "SIGTERM" else signal.SIGINT)
    except BaseException:
        run.kill()
        raise
    out, _ = assert_ended_cleanly(run, subsystem, report, None)  # (the stopped plant and robot are faults, exit 2)
    assert f"RTPU 'rtpu1' (pid {roles['rtpu1']}) was stopped (SIGSTOP): resumed it so it can stop" in out
    assert json.loads(report.read_text())["unstopped"] == []


# --- job control's own writes wait for the lock, never for good ----------------------------------


class JobControlHost:
    """The lock guard around a real table, as job control has it: no children, a list for its lines."""

    def __init__(self, table) -> None:
        self.result = RunResult("test", "c")
        self.lines: list[str] = []
        self._stop_requested = ""
        self.guard = LockGuard(table, 0.001, self.result, [], self.lines.append, lambda: 0.0,
                               lambda: self.guard.look(), lambda: self._stop_requested, lambda: False)


@pytest.mark.multiprocess
@pytest.mark.parametrize("holder_ends", ["stopped", "killed"])
def test_job_controls_write_never_waits_for_good_on_a_lock_held_past_the_bound(make_table, holder_ends):
    table = make_table(VARS)
    host = JobControlHost(table)
    holder = hold_the_lock(table.name)
    try:
        if holder_ends == "killed":
            end(holder)
        with pytest.raises(RunFailure, match=rf"^the table lock was held for \d+ ms \(bound 50 ms\) by pid {holder.pid}, "):
            table.write("a", np.ones(6), when=1.0)
        [event] = host.result.lock_events
        assert (event.pid, event.action) == (holder.pid, "left" if holder_ends == "stopped" else "released")
        assert host.result.failure == host.lines[0]
        if holder_ends == "stopped":
            assert process_state(holder.pid) in ("T", "t")
        else:
            assert table.lock.value == 1 and host.result.lock_recoveries == 1
            table.write("a", np.ones(6), when=1.0)  # the table works again
            assert table.read("a")[0].tolist() == [1.0] * 6
    finally:
        if holder.poll() is None:
            end(holder)


def test_a_stop_asked_for_while_job_control_waits_for_the_lock_ends_the_wait(make_table):
    table = make_table(VARS)
    host = JobControlHost(table)
    table.acquire()  # as a holder that keeps it: this process, whom the watch never ends
    try:
        host._stop_requested = "Ctrl-C"
        with pytest.raises(StopRequested):
            host.guard.take_table_lock()
    finally:
        table.release()


def test_a_holding_left_alone_is_reported_once(looks):
    watch = LockWatch(0.05, lambda: looks.sample, lambda: looks.now)
    looks.sample = LockSample(True, 1234, 8)
    reported = []
    for _ in range(30):
        holding = watch.look()
        if holding is not None:
            reported.append(holding.seconds)
            holding.ended = True  # as the supervisor marks one it could not end
        looks.now += 0.01
    assert len(reported) == 1
