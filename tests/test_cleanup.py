"""Nothing is left behind and nothing wedges: dead lock holders, dead runs, a killed supervisor."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import posix_ipc
import pytest

from pbo_runtime.ipc import messages, process
from pbo_runtime.ipc import shm as _shm
from pbo_runtime.supervisor.supervisor import remove_dead_runs
from pbo_runtime.table.table import Header, StateTable, TableLayout
from tests.support import (
    DEMO,
    PBO,
    REPO,
    RUNS,
    SAYING_SAFETY_NET,
    Ticker,
    children_of,
    config_copy,
    dead_pid,
    demo_copy,
    ipc_names,
    killed_on_failure,
    objects_left,
    process_gone,
    read_until,
    run_objects,
    table_of,
    task_spec,
    unique_name,
    until,
    variables,
)

VARS = variables(("a", "float64", (3,)))

HOLD_THE_LOCK = """
import sys, time, numpy as np, posix_ipc
from pbo_runtime.ipc import shm as _shm
name = sys.argv[1]
lock = posix_ipc.Semaphore(name + ".lock")
header = np.frombuffer(_shm.attach_segment(name), dtype=np.int64, count=64)
lock.acquire()
header[4] = __import__("os").getpid()
print("holding", flush=True)
time.sleep(60)
"""


@pytest.mark.multiprocess
def test_a_lock_whose_holder_died_is_released(make_table):
    table = make_table(VARS)
    holder = subprocess.Popen([sys.executable, "-c", HOLD_THE_LOCK, table.name], stdout=subprocess.PIPE, text=True, cwd=REPO)
    assert holder.stdout.readline().strip() == "holding"
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    assert table.lock.value == 0
    assert table.recover_lock_from(holder.pid)
    assert table.lock.value == 1
    assert table.header[Header.LOCK_RECOVERIES] == 1
    table.write("a", [1, 2, 3], when=0.0)  # the table works again


@pytest.mark.multiprocess
def test_a_lock_held_by_someone_else_is_not_taken_away(make_table):
    table = make_table(VARS)
    table.acquire()
    try:
        assert not table.recover_lock_from(dead_pid())
        assert table.lock.value == 0
    finally:
        table.release()


@pytest.mark.multiprocess
def test_a_new_run_removes_what_a_dead_run_left_queues_included():
    subsystem = "cleanuptest"
    dead_run = f"{dead_pid()}-abc123"
    live_run = _shm.new_run_id()
    made = {}
    for run in (dead_run, live_run):
        table_name = messages.table_name(subsystem, run)
        queue_name = messages.event_queue_name(subsystem, run)
        plant_name = messages.plant_registers_name(subsystem, run)
        queue = messages.Queue(queue_name, create=True)
        _segment, mapping = _shm.create_segment(plant_name, 4096)
        mapping.close()
        table = StateTable.create(TableLayout.build(VARS, 1), table_name,
                                  [f"shm {table_name}", f"sem {table_name}.lock", f"mq {queue_name}", f"shm {plant_name}"])
        made[run] = (table, queue, table_name, queue_name, plant_name)
    try:
        # the dead run's supervisor is gone: only its objects go
        dead_table, dead_queue, *_ = made[dead_run]
        dead_table.owner = False  # as if its process had died without cleaning up
        dead_table.close()
        dead_queue.owner = False
        dead_queue.close()
        removed = remove_dead_runs(subsystem).removed
        _, _, table_name, queue_name, plant_name = made[dead_run]
        assert set(removed) == {table_name, table_name + ".lock", queue_name, plant_name}
        with pytest.raises(posix_ipc.ExistentialError):
            posix_ipc.MessageQueue(queue_name)
        with pytest.raises(posix_ipc.ExistentialError):
            posix_ipc.SharedMemory(table_name)
        _, _, live_table_name, live_queue_name, _ = made[live_run]
        posix_ipc.SharedMemory(live_table_name).close_fd()  # the live run is untouched
        posix_ipc.MessageQueue(live_queue_name).close()
    finally:
        live_table, live_queue, _, _, live_plant = made[live_run]
        live_table.close()
        live_queue.close()
        _shm.unlink_quietly("shm", live_plant)


# --- the supervisor SIGKILLed: its children stop, and the last one out removes the run ----------------

# A supervisor (test only) with threads, as `pbo run` has: Linux says its death to a child once per
# thread that ends. It makes a run's table, lock and event queue, and starts `children` processes.
FAKE_SUPERVISOR = """
import os, subprocess, sys, threading, time
from pbo_runtime.ipc import messages, shm
from pbo_runtime.table.table import StateTable, TableLayout
from tests.support import variables
subsystem, children, child = sys.argv[1], int(sys.argv[2]), sys.argv[3]
run_id = shm.new_run_id()
table_name, queue_name = messages.table_name(subsystem, run_id), messages.event_queue_name(subsystem, run_id)
queue = messages.Queue(queue_name, create=True)
table = StateTable.create(TableLayout.build(variables(("a", "float64", (3,))), 1), table_name,
                          [f"shm {table_name}", f"sem {table_name}.lock", f"mq {queue_name}"])
for _ in range(3):
    threading.Thread(target=time.sleep, args=(600,), daemon=True).start()
started = [subprocess.Popen([sys.executable, "-c", child, str(os.getpid()), run_id]) for _ in range(children)]
print(table_name, *(c.pid for c in started), flush=True)
time.sleep(600)
"""

# A process of that run (test only): it joins the run, waits for its stop, and says how many objects it removed.
RUN_PROCESS = """
import os, sys, time
from pbo_runtime.ipc.process import Stop, become_child
from pbo_runtime.supervisor import last_out
parent, run_id = int(sys.argv[1]), sys.argv[2]
try:
    last_out.expect(run_id)
    become_child(parent)
    assert last_out.join(run_id)
    os.write(1, f"joined {os.getpid()}\\n".encode())  # (one write: the run's processes share the pipe)
    while True:
        time.sleep(1)
except Stop:
    pass
finally:
    os.write(1, f"removed {len(last_out.leave())}\\n".encode())
"""


def start_fake_run(subsystem: str, children: int) -> tuple[subprocess.Popen, str, list[int]]:
    """FAKE_SUPERVISOR with `children` RUN_PROCESSes, once each has joined: (supervisor, table, their pids)."""
    supervisor = subprocess.Popen([sys.executable, "-c", FAKE_SUPERVISOR, subsystem, str(children), RUN_PROCESS], cwd=REPO,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    table, *pids = read_until(supervisor, "/pbo.").split()
    read_until(supervisor, *(f"joined {pid}" for pid in pids))
    return supervisor, table, [int(pid) for pid in pids]


@pytest.mark.multiprocess
@pytest.mark.parametrize("children", [1, 2, 3])
def test_the_processes_of_a_run_whose_supervisor_died_leave_at_once_and_exactly_one_removes_it(children):
    subsystem = f"lastout{children}"
    live_run = _shm.new_run_id()  # a run of the same subsystem alive alongside (this process is its supervisor)
    live_table = StateTable.create(TableLayout.build(VARS, 1), messages.table_name(subsystem, live_run), [])
    supervisor = None
    try:
        supervisor, table, pids = start_fake_run(subsystem, children)
        objects = run_objects(table)
        assert len(objects) == 3
        supervisor.send_signal(signal.SIGKILL)  # all of them are told at the same instant
        out, err = supervisor.communicate(timeout=SAYING_SAFETY_NET)  # until every process of the run closed the pipes
        removed = sorted(int(line.split()[1]) for line in out.splitlines() if line.startswith("removed"))
        assert removed == [0] * (children - 1) + [3], out  # the last one out removed the table, its lock and the queue
        assert objects_left(objects) == []
        assert "Traceback" not in err, err
        until(lambda: all(process_gone(pid) for pid in pids), "the processes' end")
        posix_ipc.SharedMemory(live_table.name).close_fd()  # the other run is untouched
        assert ipc_names(live_run) != []
    finally:
        if supervisor is not None and supervisor.poll() is None:
            supervisor.kill()
            supervisor.wait()
        live_table.close()
        remove_dead_runs(subsystem)


@pytest.mark.multiprocess
def test_a_process_that_leaves_while_its_supervisor_lives_removes_nothing():
    supervisor, table, [pid] = start_fake_run("lastoutalive", 1)
    try:
        objects = run_objects(table)
        os.kill(pid, signal.SIGTERM)
        assert read_until(supervisor, "removed") == "removed 0\n"
        until(lambda: process_gone(pid), "the process's end")
        assert sorted(objects_left(objects)) == sorted(name for _kind, name in objects)
    finally:
        supervisor.kill()
        supervisor.wait()
        remove_dead_runs("lastoutalive")


KILLED_WHILE = {
    "on": ("is on", ()),  # the configuration on, on the real clock
    "on, simulated clock": ("is on", ("--clock", "sim")),
    "starting": ("", ()),  # as soon as its table exists: before the children or their tasks are up
    "on, restart policy": ("is on", ()),  # the fork server is kept for the run: an RTPU may be restarted
}


@pytest.mark.multiprocess
@pytest.mark.parametrize("moment", KILLED_WHILE)
def test_killing_the_supervisor_leaves_no_process_no_object_and_no_traceback(tmp_path, moment):
    said, arguments = KILLED_WHILE[moment]
    name = "killed_" + moment.replace(",", "").replace(" ", "_")
    file = demo_copy(tmp_path, name)
    if moment == "on, restart policy":
        file = config_copy(DEMO, tmp_path, name, (("rtpus: [rtpu0, rtpu1]",
                                                   "rtpus: [rtpu0, rtpu1]\nrestart: {max: 3, within: 10 min}"),))
    pbo = subprocess.Popen([*PBO, "run", str(file), "--duration", "60", "--no-live", *arguments], cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with killed_on_failure(pbo):
        before = read_until(pbo, said) if said else ""

        def made() -> list[tuple[str, str]]:
            tables = [n for n in os.listdir("/dev/shm") if f"pbo.{name}.{pbo.pid}-" in n and n.endswith(".table")]
            return run_objects(table_of(pbo, name)) if tables else []

        until(lambda: {kind for kind, _ in made()} == {"shm", "sem", "mq"}, "the run's table, which names its queues")
        objects = made()
        children = children_of(pbo.pid)
        if said:
            assert len([c for c in children.values() if "supervisor.fork_server" not in c]) == 3  # the plant and two RTPUs
            assert any("supervisor.fork_server" in c for c in children.values()) == (moment == "on, restart policy")
        pbo.send_signal(signal.SIGKILL)
        pbo.wait()
    until(lambda: objects_left(objects) == [], f"the run's objects removed: {objects_left(objects)}")
    until(lambda: all(process_gone(pid) for pid in children), "the children's end")
    out, err = pbo.communicate(timeout=SAYING_SAFETY_NET)  # (every child wrote to these pipes: they closed them)
    assert "Traceback" not in before + out + err, before + out + err


@pytest.mark.multiprocess
def test_an_rtpu_stops_on_sigterm_even_while_waiting_on_its_queue(tmp_path):
    pbo = subprocess.Popen([*PBO, "run", str(DEMO), "--duration", "60", "--no-live"], cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        read_until(pbo, "is on")
        rtpu0 = next(pid for pid, cmd in children_of(pbo.pid).items() if "--rtpu rtpu0" in cmd)
        os.kill(rtpu0, signal.SIGTERM)
        _out, err = pbo.communicate(timeout=60)
    finally:
        if pbo.poll() is None:
            pbo.kill()
            pbo.wait()
    assert pbo.returncode == 2
    assert f"RTPU 'rtpu0' (pid {rtpu0}) died (exit status 0) while hosting tasks: traj, pid, logger" in err


# --- a stop signal lands anywhere: it must not wedge an RTPU (issue 6, a CI failure) --------------

class SignalInsideTheLock:
    """Fake table lock (test only): the real semaphore, but once armed its next acquire sends this
    process SIGTERM while it holds the lock, as PDEATHSIG or a Ctrl-C may at any instant."""

    def __init__(self, real: posix_ipc.Semaphore) -> None:
        self.real = real
        self.armed = False

    def acquire(self, timeout: float | None = None) -> None:  # (the table's per-cycle wait, None here)
        self.real.acquire(5.0)  # a process waiting on its own lock fails the test (BusyError) instead of hanging it
        if self.armed:
            self.armed = False
            os.kill(os.getpid(), signal.SIGTERM)

    def release(self) -> None:
        self.real.release()


@pytest.fixture
def stops_only_at_waits():
    """This process takes its stop signals as an RTPU does; the handlers and the request are restored after."""
    saved = {s: signal.getsignal(s) for s in process.STOP_SIGNALS}
    process.stop_only_at_waits()
    try:
        yield
    finally:
        process.stopping_done()
        for s, handler in saved.items():
            signal.signal(s, handler)
        process._requested = ""
        process._hung_up = process._only_at_waits = False


def test_a_stop_signal_that_lands_inside_a_table_transfer_is_taken_at_the_next_wait(make_table,
                                                                                    stops_only_at_waits):
    # Regression: a Stop raised between a transfer's acquire and release kept the table lock; the
    # stop path (kill -> publish the state) then waited on the RTPU's own lock for ever, and a
    # killed supervisor's RTPU outlived it (test_killing_the_supervisor..., seen once in CI).
    from pbo_runtime.clock.clocks import RealClock
    from pbo_runtime.table.table import TaskState
    from pbo_runtime.task.lifecycle import Task
    from rtpu._executive import Executive

    table = make_table(variables(("o0", "float64", ())))
    real_lock = table.lock
    table.lock = lock = SignalInsideTheLock(real_lock)
    signals = messages.Queue(unique_name("signals"), create=True)
    events: list[messages.Event] = []
    try:
        executive = Executive(RealClock(0.0002), signals, events.append, epoch=time.monotonic())
        executive.add(Task(task_spec(Ticker, name="a", ports={"out": "o0"}, period=0.001), Ticker, table))
        signals.send("spawn", "a")
        signals.send("on", "a")
        for _ in range(10):
            if executive.tasks["a"].task.state == TaskState.ON:
                break
            executive.run_once()
        assert executive.tasks["a"].task.state == TaskState.ON
        RUNS.clear()
        lock.armed = True  # the signal comes inside the next cycle's first transfer
        with pytest.raises(process.Stop):
            executive.run()
        assert not lock.armed
        executive.stop()  # as rtpu/__main__ does on Stop: kill every task, publish its state (the lock again), report
        assert executive.tasks["a"].task.state == TaskState.KILLED
        assert real_lock.value == 1, "the lock is free again"
        assert len(RUNS) == 1, "the cycle the signal landed in ran to its end; none after it"
        assert [e for e in events if isinstance(e, messages.Stats)]
    finally:
        table.lock = real_lock
        signals.close()


def test_a_second_stop_signal_stops_at_once(stops_only_at_waits):
    os.kill(os.getpid(), signal.SIGTERM)  # the first only asks: nothing is raised here
    with pytest.raises(process.Stop):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1.0)  # (the handler runs as soon as the call returns)


def test_the_supervisors_death_said_again_is_not_a_second_stop(stops_only_at_waits):
    for signum in (process.DEATH_SIGNAL, process.DEATH_SIGNAL, signal.SIGTERM):  # once per thread of the supervisor that ends
        os.kill(os.getpid(), signum)
    time.sleep(0.01)  # (no handler raised)
    assert process.stop_requested() == process.DEATH_SIGNAL.name  # the stop is taken at the next wait, as asked first
    with pytest.raises(process.Stop):
        process.raise_if_stopping()


def test_a_report_at_stop_stops_waiting_on_a_full_queue_once_its_reader_is_gone():
    # An RTPU whose supervisor was killed reports its stop to a queue nobody drains: each
    # report used to wait out its 5 s, and an RTPU of many tasks outlived its supervisor by minutes.
    queue = messages.Queue(unique_name("events"), create=True)
    try:
        while queue.try_send("filler", timeout=0):
            pass
        asked: list[int] = []

        def reader_alive() -> bool:
            asked.append(1)
            return len(asked) < 3

        assert queue.try_send("stats", timeout=60.0, reader_alive=reader_alive) is False
        assert len(asked) == 3, "it gave up when told the reader was gone, not at the 60 s timeout"
        assert queue.try_send("stats", timeout=60.0, reader_alive=lambda: False) is False
    finally:
        queue.close()
