"""The supervisor's children, the plant and the RTPU processes: launching them, noticing one die,
and stopping them all on every exit path. (What crashed runs left is `supervisor.cleanup`'s.)

A stop always ends: a child stopped by SIGSTOP is resumed first (SIGCONT) so it can stop by
itself, the table lock is watched while they stop (`supervisor.lock_watch`), and whatever has
not stopped after STOP_TIMEOUT is resumed and sent SIGTERM, then SIGKILL after another."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Callable

from pbo_runtime.clock.run_clock import RunClock
from pbo_runtime.config.model import Subsystem
from pbo_runtime.ipc import messages
from pbo_runtime.ipc import shm
from pbo_runtime.ipc.control import ControlServer
from pbo_runtime.supervisor.child_watch import ChildWatch
from pbo_runtime.supervisor.failures import RtpuDied, RunFailure
from pbo_runtime.supervisor.in_process import InProcessChild
from pbo_runtime.supervisor.fork_server import ForkedProcess, ForkServer, ForkServerUnavailable, forking_enabled
from pbo_runtime.supervisor.run_report import STOP_TIMEOUT, RunResult
from pbo_runtime.table.table import StateTable

# Seconds the lock record of a reaped child is watched before its lock is released: only a taker
# that has not signed yet could be mistaken for it, a window of microseconds, while every other
# RTPU waits for the lock meanwhile. (A child that died mid-write is released at once.)
DEAD_HOLDER_SETTLE = 0.01


@dataclass
class Child:
    """One child process of the run: the plant or an RTPU, and the tasks it hosts."""

    role: str  # 'plant' or the RTPU's name
    process: subprocess.Popen[bytes] | ForkedProcess | InProcessChild  # a fresh interpreter, forked, or hosted here
    tasks: tuple[str, ...] = ()


class Children:
    """The Supervisor's part that starts, watches and stops its child processes."""

    clock: RunClock
    subsystem: Subsystem
    run_id: str
    children: list[Child]
    fork_server: ForkServer | None
    table: StateTable | None
    result: RunResult
    signals: dict[str, messages.Queue]
    events: messages.Queue | None
    control: ControlServer | None
    task_states: dict[str, str]
    started_at: float | None
    say: Callable[[str], None]
    now: Callable[[], float]
    _manifest: Callable[[], list[str]]
    _drain_events: Callable[[float], None]
    _read_final_values: Callable[[], None]
    _report_run: Callable[[], None]
    _look_at_the_lock: Callable[[], None]
    _look_at_the_lock_while_stopping: Callable[[], None]
    may_restart: Callable[[str], bool]
    launched: dict[str, tuple[list[str], tuple[str, ...]]]  # role -> its launch arguments and tasks
    child_watch: ChildWatch | None
    _startup_mark: Callable[..., None]

    def _start_fork_server(self, preload: list[str]) -> None:
        """The fork server the children are forked from (`supervisor.fork_server`), started before it is needed."""
        if not forking_enabled() or self.clock.one_process:
            return
        try:
            self.fork_server = ForkServer.start(self.subsystem.file, preload, env=self.clock.child_environment(),
                                               run_id=self.run_id)
        except OSError as exc:
            self.say(f"no fork server ({exc}): the children start as fresh interpreters")

    def _release_fork_server(self) -> None:
        """Once the children are started: kept for the run if an RTPU may be restarted (it is forked
        from it again), else ended (it exits at once, nothing to tear down)."""
        if self.fork_server is not None:
            if self.fork_server.warm_at:
                self._startup_mark("fork_server", self.fork_server.warm_at)
            if not any(self.may_restart(rtpu.name) for rtpu in self.subsystem.rtpus):
                self._end_fork_server()

    def _end_fork_server(self) -> None:
        """On every exit path: ended and reaped."""
        if self.fork_server is not None:
            self.fork_server.close()
            self.fork_server = None

    def _launch(self, role: str, arguments: list[str], tasks: tuple[str, ...] = ()) -> None:
        """Start `python -m MODULE ARGUMENTS...` (`arguments` begins with -m MODULE): forked from the fork
        server where it serves, else a fresh interpreter."""
        parent = ["--parent", str(os.getpid())]
        self.launched[role] = (arguments, tasks)  # a restart launches it the same way (from the kept fork server)
        process: subprocess.Popen[bytes] | ForkedProcess | InProcessChild | None = None
        if self.clock.one_process:  # hosted here, joining the simulated clock's ring (`supervisor.in_process`)
            assert self.events is not None
            events = self.events  # (the ring stops after a tick that sent job control an event)
            process = InProcessChild.start(arguments, self.subsystem, events,
                                           lambda step: self.clock.join(role, step, events.pending))
        elif self.fork_server is not None and arguments[0] == "-m":
            try:
                process = self.fork_server.fork(arguments[1], [*arguments[2:], *parent])
            except ForkServerUnavailable as exc:
                self.say(f"{exc}: the children start as fresh interpreters")
                self._end_fork_server()
        if process is None:
            process = subprocess.Popen([sys.executable, *arguments, *parent], stdin=subprocess.DEVNULL,
                                       start_new_session=True, env=self.clock.child_environment())
        self.children.append(Child(role, process, tasks))
        if self.child_watch is not None:
            self.child_watch.watch(role, process.pid)
        self._list_children()

    def _list_children(self) -> None:
        """The manifest names the live children: cleanup leaves the run alone while any of them lives."""
        if self.table is not None:
            self.table.set_manifest([*self._manifest(), *(f"pid {c.process.pid} {c.role}" for c in self.children)])

    def _check_children(self) -> None:
        """A child that ended: RtpuDied if its RTPU may be restarted (the caller restarts it), else RunFailure."""
        for child in self.children:
            code = child.process.poll()
            if code is not None:
                self._recover_lock_from(child.process.pid)
                how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
                hosted = f" while hosting tasks: {', '.join(child.tasks)}" if child.tasks else ""
                what = "the plant" if child.role == "plant" else f"RTPU '{child.role}'"
                message = f"{what} (pid {child.process.pid}) died ({how}){hosted}"
                if self.may_restart(child.role):
                    raise RtpuDied(message, child.role, child.process.pid, how)
                raise RunFailure(message)
        self._look_at_the_lock()

    def _recover_lock_from(self, pid: int) -> None:
        """A process that died holding the table lock must not wedge the others."""
        if self.table is not None and self.table.recover_lock_from(pid, settle=DEAD_HOLDER_SETTLE):
            self.result.lock_recoveries += 1
            self.say(f"released the table lock held by dead process {pid}")

    def _shutdown(self) -> None:
        """Stop the children (each RTPU by itself first), report, close and unlink everything: on every exit path."""
        watch, self.child_watch = self.child_watch, None  # from here on, children end because they are told to
        if watch is not None:
            watch.close()
        self._end_fork_server()
        self.result.duration = self.now() - self.started_at if self.started_at is not None else 0.0
        self.result.states_at_stop = dict(self.task_states)
        if self.table is not None:
            self.clock.announce_stop(self.table.announce_stop)
        alive = [c for c in self.children if c.process.poll() is None]
        self._resume_stopped(alive)  # the flag is up: a resumed RTPU runs no more cycles, it only stops
        for child in alive:
            if child.role != "plant":
                self.signals[child.role].try_signal(messages.StopRtpu())
                self._serve_stop(child)
        deadline = time.monotonic() + STOP_TIMEOUT
        rtpus = [c for c in alive if c.role != "plant"]
        while any(c.process.poll() is None for c in rtpus) and time.monotonic() < deadline:
            self._drain_events(0.05)
            self._look_at_the_lock_while_stopping()  # an RTPU whose stop waits on a wedged lock must not wait for good
        self._drain_events(0.0)
        self.result.unstopped = [c.role for c in rtpus if c.process.poll() is None]
        self._read_final_values()
        for child in self.children:
            if child.process.poll() is None:
                _signal_quietly(child.process, signal.SIGCONT)  # a stopped process takes SIGTERM only once resumed
                _signal_quietly(child.process, signal.SIGTERM)
        for child in self.children:
            try:
                child.process.wait(timeout=STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                child.process.kill()
                child.process.wait()
        self._drain_events(0.0)
        self.clock.close()
        self._report_run()
        if self.control is not None:
            self.control.close()
        for queue in self.signals.values():
            queue.close()
        if self.events is not None:
            self.events.close()
        if self.table is not None:
            self.table.close()
        for entry in self._manifest():  # a backstop: whatever a child could not remove
            kind, _, name = entry.partition(" ")
            shm.unlink_quietly(kind, name)
        # ... and what a child made under the run's name that the manifest does not list (a special-purpose
        # processor's memory, made by its driver in a task): every child is gone, so all of it is the run's
        for listed in shm.list_objects(self.subsystem.name):
            if listed.run_id == self.run_id and listed.distrust is None:
                shm.unlink_quietly(listed.kind, listed.name)

    def _end_at_once(self) -> None:
        """One process (`--one-process`), told twice to stop: a participant hosted here may be in a cycle
        that never returns, and nothing else would end the run. Its objects are removed; what the data
        logs had not written yet is lost (they are written in chunks); the process exits 2."""
        sys.stderr.write("error: stopped at once (told twice to stop, in one process): the last data of the logs "
                         "may be lost\n")
        for entry in self._manifest():
            kind, _, name = entry.partition(" ")
            shm.unlink_quietly(kind, name)
        for listed in shm.list_objects(self.subsystem.name):  # what a driver made under the run's name
            if listed.run_id == self.run_id and listed.distrust is None:
                shm.unlink_quietly(listed.kind, listed.name)
        os._exit(2)

    def _resume_stopped(self, children: list[Child]) -> None:
        """SIGCONT to every child stopped (SIGSTOP) when the run stops: a stopped process cannot stop by itself."""
        for child in children:
            if shm.pid_state(child.process.pid) in ("T", "t"):
                _signal_quietly(child.process, signal.SIGCONT)
                what = "the plant" if child.role == "plant" else f"RTPU '{child.role}'"
                self.say(f"{what} (pid {child.process.pid}) was stopped (SIGSTOP): resumed it so it can stop")

    def _serve_stop(self, child: Child) -> None:
        """Sim clock: step an RTPU once so it serves its stop; a dead or stuck one is left to SIGTERM."""
        self.clock.take_turn(lambda: self._drain_events(0.0))  # an application's turn: its wait is not the stop's
        deadline = time.monotonic() + STOP_TIMEOUT

        def give_up() -> bool:
            self._drain_events(0.0)
            return child.process.poll() is not None or time.monotonic() > deadline

        self.clock.serve(child.role, give_up)


def _signal_quietly(process: subprocess.Popen[bytes] | ForkedProcess | InProcessChild, signum: int) -> None:
    try:
        process.send_signal(signum)
    except OSError:  # it ended meanwhile
        pass
