"""The supervisor's children, the plant and the RTPU processes: launching them, noticing one die,
and stopping them all on every exit path. (What crashed runs left is `supervisor.cleanup`'s.)

A stop always ends: a child stopped by SIGSTOP is resumed first (SIGCONT) so it can stop by
itself, the table lock is watched while they stop (`supervisor.lock_watch`), and whatever has
not stopped after STOP_TIMEOUT is resumed and sent SIGTERM, then SIGKILL after another."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from pbo_runtime.clock.run_clock import RunClock
from pbo_runtime.config.model import RtpuSpec, Subsystem
from pbo_runtime.ipc import messages, shm
from pbo_runtime.supervisor.child_watch import ChildWatch
from pbo_runtime.supervisor.failures import RtpuDied, RunFailure
from pbo_runtime.supervisor.fork_server import ForkedProcess, ForkServer, ForkServerUnavailable, forking_enabled
from pbo_runtime.supervisor.in_process import InProcessChild
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


def death_message(child: Child, code: int) -> str:
    """What the run tells of a child that ended with `code` (Popen's: negative, the signal that killed it)."""
    hosted = f" while hosting tasks: {', '.join(child.tasks)}" if child.tasks else ""
    return f"{_what(child.role)} (pid {child.process.pid}) died ({death_cause(code)}){hosted}"


def death_cause(code: int) -> str:
    return f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"


def death_failure(child: Child, code: int, restartable: bool) -> RunFailure:
    """A child's death: RtpuDied if its restart policy may bring it back (the caller restarts it), else RunFailure."""
    message = death_message(child, code)
    if restartable:
        return RtpuDied(message, child.role, child.process.pid, death_cause(code))
    return RunFailure(message)


def _what(role: str) -> str:
    return "the plant" if role == "plant" else f"RTPU '{role}'"


class Children:
    """The supervisor's part that starts, watches and stops its child processes.

    `table` gives the run's table once it is made; `manifest` the shared objects the run makes;
    `may_restart` whether a role's restart policy brings it back; `mark` notes a start-up phase;
    `subsystem`, `events` and `signals` (each RTPU's signal queue, by RTPU) are what a child hosted in
    this process (`--one-process`) is given.
    """

    def __init__(self, run_id: str, clock: RunClock, result: RunResult, say: Callable[[str], None],
                 table: Callable[[], StateTable | None], manifest: Callable[[], list[str]],
                 may_restart: Callable[[str], bool], mark: Callable[[str, float], None],
                 fork_server: ForkServer | None = None, subsystem: Subsystem | None = None,
                 events: Callable[[], messages.Queue | None] = lambda: None,
                 signals: Mapping[str, messages.Queue] | None = None) -> None:
        self.run_id = run_id
        self.subsystem = subsystem
        self.events = events
        self.signals = signals if signals is not None else {}
        self.clock = clock
        self.result = result
        self.say = say
        self.table = table
        self.manifest = manifest
        self.may_restart = may_restart
        self.mark = mark
        self.children: list[Child] = []
        self.launched: dict[str, tuple[list[str], tuple[str, ...]]] = {}  # role -> its launch arguments and tasks
        self.child_watch: ChildWatch | None = None
        # what the children are forked from while they start (supervisor.fork_server): one the caller
        # started early (the CLI, before it loaded the file), or one the run starts; ended once they are
        self.fork_server = fork_server

    def start_fork_server(self, file: str, preload: list[str]) -> None:
        """The fork server the children are forked from (`supervisor.fork_server`), started before it is needed."""
        if not forking_enabled() or self.clock.one_process:
            return
        try:
            self.fork_server = ForkServer.start(file, preload, env=self.clock.child_environment(), run_id=self.run_id)
        except OSError as exc:
            self.say(f"no fork server ({exc}): the children start as fresh interpreters")

    def release_fork_server(self, rtpus: Iterable[RtpuSpec]) -> None:
        """Once the configuration is on: kept for the run if an RTPU may be restarted (it is forked
        from it again), else ended (it exits at once, nothing to tear down). Ended before, its exit
        and reaping would come in the children's start; until then it only waits on its channel."""
        if self.fork_server is not None:
            if self.fork_server.warm_at:
                self.mark("fork_server", self.fork_server.warm_at)
            if not any(self.may_restart(rtpu.name) for rtpu in rtpus):
                self.end_fork_server()

    def end_fork_server(self) -> None:
        """On every exit path: ended and reaped."""
        if self.fork_server is not None:
            self.fork_server.close()
            self.fork_server = None

    def launch_all(self, launches: list[tuple[str, list[str], tuple[str, ...]]]) -> None:
        """`launch` each (role, arguments, tasks) in turn; where the fork server serves, all are forked
        in one request (one middle process forks them all, not one each)."""
        forked: list[ForkedProcess] = []
        if not self.clock.one_process and self.fork_server is not None and all(a[0] == "-m" for _, a, _ in launches):
            parent = ["--parent", str(os.getpid())]
            try:
                forked = self.fork_server.fork_all([(a[1], [*a[2:], *parent]) for _, a, _ in launches])
            except ForkServerUnavailable as exc:
                self.say(f"{exc}: the children start as fresh interpreters")
                self.end_fork_server()
        for index, (role, arguments, tasks) in enumerate(launches):
            self.launch(role, arguments, tasks, forked[index] if forked else None)

    def launch(self, role: str, arguments: list[str], tasks: tuple[str, ...] = (), forked: ForkedProcess | None = None) -> None:
        """Start `python -m MODULE ARGUMENTS...` (`arguments` begins with -m MODULE): forked from the fork
        server where it serves, else a fresh interpreter (`forked`: forked already, by `launch_all`)."""
        parent = ["--parent", str(os.getpid())]
        self.launched[role] = (arguments, tasks)  # a restart launches it the same way (from the kept fork server)
        process: subprocess.Popen[bytes] | ForkedProcess | InProcessChild | None = forked
        if forked is None and self.clock.one_process:  # hosted here, joining the simulated clock's ring (`supervisor.in_process`)
            events = self.events()
            assert events is not None and self.subsystem is not None
            # (the ring stops after a tick that sent job control an event)
            process = InProcessChild.start(arguments, self.subsystem, events,
                                           lambda step: self.clock.join(role, step, events.pending), self.signals.get(role))
        elif forked is None and self.fork_server is not None and arguments[0] == "-m":
            try:
                process = self.fork_server.fork(arguments[1], [*arguments[2:], *parent])
            except ForkServerUnavailable as exc:
                self.say(f"{exc}: the children start as fresh interpreters")
                self.end_fork_server()
        if process is None:
            process = subprocess.Popen([sys.executable, *arguments, *parent], stdin=subprocess.DEVNULL,
                                       start_new_session=True, env=self.clock.child_environment())
        self.children.append(Child(role, process, tasks))
        if self.child_watch is not None:
            self.child_watch.watch(role, process.pid)
        self.list_children()

    def list_children(self) -> None:
        """The manifest names the live children: cleanup leaves the run alone while any of them lives."""
        table = self.table()
        if table is not None:
            table.set_manifest([*self.manifest(), *(f"pid {c.process.pid} {c.role}" for c in self.children)])

    def check(self) -> None:
        """A child that ended: RtpuDied if its RTPU may be restarted (the caller restarts it), else RunFailure."""
        for child in self.children:
            code = child.process.poll()
            if code is not None:
                self.recover_lock_from(child.process.pid)
                raise death_failure(child, code, self.may_restart(child.role))

    def recover_lock_from(self, pid: int) -> None:
        """A process that died holding the table lock must not wedge the others."""
        table = self.table()
        if table is not None and table.recover_lock_from(pid, settle=DEAD_HOLDER_SETTLE):
            self.result.lock_recoveries += 1
            self.say(f"released the table lock held by dead process {pid}")

    def stop_watching(self) -> None:
        """From here on, children end because they are told to: the child watch and the fork server end."""
        watch, self.child_watch = self.child_watch, None
        if watch is not None:
            watch.close()
        self.end_fork_server()

    def stop_rtpus(self, signals: dict[str, messages.Queue], drain: Callable[[float], None],
                   look_at_the_lock: Callable[[], None]) -> None:
        """Ask each RTPU to stop by itself (the table's stop flag is up), `drain`ing events meanwhile;
        those that did not within STOP_TIMEOUT go to `result.unstopped`."""
        alive = [c for c in self.children if c.process.poll() is None]
        self.resume_stopped(alive)  # the flag is up: a resumed RTPU runs no more cycles, it only stops
        for child in alive:
            if child.role != "plant":
                signals[child.role].try_signal(messages.StopRtpu())
                self.serve_stop(child, drain)
        deadline = time.monotonic() + STOP_TIMEOUT
        rtpus = [c for c in alive if c.role != "plant"]
        while any(c.process.poll() is None for c in rtpus) and time.monotonic() < deadline:
            drain(0.05)
            look_at_the_lock()  # an RTPU whose stop waits on a wedged lock must not wait for good
        drain(0.0)
        self.result.unstopped = [c.role for c in rtpus if c.process.poll() is None]

    def end_all(self) -> None:
        """SIGTERM to every child still alive (resumed first), then SIGKILL to one that outlives STOP_TIMEOUT."""
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

    def resume_stopped(self, children: list[Child]) -> None:
        """SIGCONT to every child stopped (SIGSTOP) when the run stops: a stopped process cannot stop by itself."""
        for child in children:
            if shm.pid_state(child.process.pid) in ("T", "t"):
                _signal_quietly(child.process, signal.SIGCONT)
                self.say(f"{_what(child.role)} (pid {child.process.pid}) was stopped (SIGSTOP): resumed it so it can stop")

    def serve_stop(self, child: Child, drain: Callable[[float], None]) -> None:
        """Sim clock: step an RTPU once so it serves its stop; a dead or stuck one is left to SIGTERM."""
        self.clock.take_turn(lambda: drain(0.0))  # an application's turn: its wait is not the stop's
        deadline = time.monotonic() + STOP_TIMEOUT

        def give_up() -> bool:
            drain(0.0)
            return child.process.poll() is not None or time.monotonic() > deadline

        self.clock.serve(child.role, give_up)


def _signal_quietly(process: subprocess.Popen[bytes] | ForkedProcess | InProcessChild, signum: int) -> None:
    with contextlib.suppress(OSError):  # it ended meanwhile
        process.send_signal(signum)
