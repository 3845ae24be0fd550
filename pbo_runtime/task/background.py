"""Work that is not real time, off an RTPU's cycle: one low-priority thread per process.

A task's `off` and `kill` run between two cycles of every task on its RTPU. Whatever is slow
there (a log's last chunk encoded and its footer written, a helper process or thread joined, a
file closed) makes the next releases late. A component hands such work to this thread instead
(`PortBasedObject.hand_off`) and returns at once. The thread runs below the executive's thread:
it takes the CPU time the executive leaves idle. Its work should spend its time waiting (system
calls, a child process, a join) with the GIL released: Python computing here holds the GIL, and
the executive's thread waits for it at its next release, for at most the RTPU's switch interval
(CPU-heavy work belongs in a process of its own). For the same reason the thread runs at the
lowest real-time priority when the executive runs SCHED_FIFO (`below_the_cycle`): holding the
GIL, it must not wait behind the machine's other processes for its CPU while the executive waits.

Nothing handed off is lost: the work runs in the order handed, the RTPU waits for all of it
when it stops (`close`), and a failure is kept with the task that handed it (`failures`), for the
executive to report as that task's error.
"""

from __future__ import annotations

import collections
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from pbo_runtime.errors import OutputError
from pbo_runtime.objects.helper_threads import below_the_cycle

CLOSE_PATIENCE = 60.0  # s the RTPU waits at its stop for the work handed off to end


@dataclass(frozen=True)
class Failure:
    """Work handed off that raised, or did not end by the RTPU's stop."""

    task: str
    what: str
    error: str
    output: bool  # an output the run promised could not be written (an OutputError): the run's exit says so


@dataclass(frozen=True)
class _Work:
    run: Callable[[], None]
    task: str
    what: str


class Background:
    """A FIFO of work run by one thread of lower priority; `close` waits for all of it."""

    def __init__(self, name: str = "pbo-background") -> None:
        self.name = name
        self._queue: collections.deque[_Work] = collections.deque()
        self._changed = threading.Condition()
        self._pending = 0  # handed off and not yet ended (running included)
        self._running: _Work | None = None
        self._closing = False
        self._thread: threading.Thread | None = None
        self._failures: list[Failure] = []
        self.done = 0  # pieces of work ended, failed or not

    def start(self) -> None:
        """Start the thread now (else at the first `hand_off`): the executive starts it before any cycle."""
        with self._changed:
            self._start()

    def hand_off(self, work: Callable[[], None], task: str, what: str) -> None:
        """Run `work` in the background thread after what was handed before; returns at once.

        `what` names the work for a failure's report ("finishing log /run/x.mcap")."""
        with self._changed:
            if self._closing:
                raise RuntimeError(f"{what}: the RTPU's background work is closed")
            self._queue.append(_Work(work, task, what))
            self._pending += 1
            self._start()
            self._changed.notify_all()

    @property
    def pending(self) -> int:
        """Pieces of work handed off and not yet ended."""
        return self._pending

    def take_failures(self) -> list[Failure]:
        """The failures since the last call (each reported once)."""
        with self._changed:
            failures, self._failures = self._failures, []
        return failures

    def drain(self, patience: float = CLOSE_PATIENCE) -> bool:
        """Wait until everything handed off so far has ended; False if some still runs after `patience`."""
        give_up = time.monotonic() + patience
        with self._changed:
            while self._pending:
                left = give_up - time.monotonic()
                if left <= 0:
                    return False
                self._changed.wait(left)
        return True

    def close(self, patience: float = CLOSE_PATIENCE) -> list[Failure]:
        """At the RTPU's stop: wait for the work handed off (at most `patience`), end the thread, and
        return the failures not taken yet; work still running then is a failure of its own."""
        ended = self.drain(patience)
        with self._changed:
            self._closing = True
            self._changed.notify_all()
            if not ended:
                for work in ([self._running] if self._running is not None else []) + list(self._queue):
                    self._failures.append(Failure(work.task, work.what, f"had not ended {patience:g} s after the RTPU's stop "
                                                                        "(left running: its result is unknown)", False))
        if ended and self._thread is not None:
            self._thread.join(patience)
        return self.take_failures()

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name=self.name, daemon=True)
            self._thread.start()

    def _serve(self) -> None:
        below_the_cycle()
        while True:
            with self._changed:
                while not self._queue and not self._closing:
                    self._changed.wait()
                if not self._queue:
                    return
                work = self._running = self._queue.popleft()
            failure = None
            try:
                work.run()
            except Exception as exc:  # kept for the task's report, never a thread gone silent
                failure = Failure(work.task, work.what, f"{type(exc).__name__}: {exc}", isinstance(exc, OutputError))
            with self._changed:
                if failure is not None:
                    self._failures.append(failure)
                self._running = None
                self._pending -= 1
                self.done += 1
                self._changed.notify_all()


_process: Background | None = None


def process_background() -> Background:
    """This process's background thread (an RTPU has one, for every task it hosts)."""
    global _process
    if _process is None:
        _process = Background()
    return _process


def close_process_background(patience: float = CLOSE_PATIENCE) -> list[Failure]:
    """At the RTPU's stop: wait for this process's background work (`Background.close`); a later
    hand-off starts a new thread."""
    global _process
    closing, _process = _process, None
    return closing.close(patience) if closing is not None else []


def _forget_in_child() -> None:
    """A forked child (an RTPU from the fork server) has none of its parent's threads: it starts its own."""
    global _process
    _process = None


os.register_at_fork(after_in_child=_forget_in_child)
