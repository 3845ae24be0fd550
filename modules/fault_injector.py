"""A module that fails on purpose: to see and rehearse error handling end to end (TR §4.3).

It watches a variable (e.g. q_m) and, after `fail_after` cycles, raises in `cycle` once, as a
driver fault or a numerical blow-up would. Its `error` component cannot recover, so the task
waits in ERROR and job control shows it; its `clear` component reports the fault fixed, so the
operator's `pbo clear` returns it to OFF and `pbo on` resumes it. With `fault: hang` its cycle
never returns instead, as a driver call waiting for a device that never answers: every task of
its RTPU stops with it, and the critical tasks that read their outputs hold the arm. With
`fault: abort` it crashes its whole process natively (`os.abort()`, as a segfault in an
extension would): its RTPU dies, and a restart policy (`restart:`) decides what follows. With
`in_init: true` the fault happens in `init` instead of a cycle; with `in_on: true` it happens in
`on`, when the task is turned on (a switch to a configuration that has it, `pbo on`), and only
in the run's first process of its RTPU: a task whose RTPU was restarted (`self.restarted`) does
not fail again, so `fault: abort, in_on: true` crashes the RTPU once, in the middle of a switch,
and its restart succeeds. Shipped as real code (not a
mock) so operators can rehearse the procedure on the simulated arm.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from typing import Literal

from pbo_runtime import InVar, PortBasedObject, Status


@dataclass(frozen=True)
class FaultInjectorParams:
    fail_after: int = 1000  # cycles before the fault
    recoverable: bool = False  # True: the error component recovers by itself (the task stays ON)
    fault: Literal["raise", "hang", "abort"] = "raise"  # raises once; never returns; or crashes the process (os.abort)
    in_init: bool = False  # the fault happens in init (every time the task is spawned), not after fail_after cycles
    in_on: bool = False  # the fault happens in on (once per run: not in a restarted RTPU), not after fail_after cycles

    def __post_init__(self) -> None:
        if self.fail_after < 0:
            raise ValueError(f"fail_after must be >= 0, got: {self.fail_after}")
        if self.in_init and self.in_on:
            raise ValueError("in_init and in_on are exclusive: the fault happens in one place")


class FaultInjector(PortBasedObject):
    """Raises once in `cycle` after `fail_after` cycles (or hangs, or aborts the process); `clear` then returns it to OFF."""

    Params = FaultInjectorParams

    watched = InVar("q_m", dtype="any", shape=None, doc="any variable: read every cycle, not used")

    def init(self, params: FaultInjectorParams) -> None:
        if params.in_init:
            self._fail(params.fault, "in init")
        self._fail_after = params.fail_after
        self._recoverable = params.recoverable
        self._fault = params.fault
        self._in_on = params.in_on
        self.cycles = 0
        self.failed = False

    def on(self) -> None:
        if self._in_on and not self.restarted and not self.failed:
            self.failed = True
            self._fail(self._fault, "in on")

    def cycle(self) -> Status:
        self.cycles += 1
        if not self.failed and not self._in_on and self.cycles > self._fail_after:
            self.failed = True
            self._fail(self._fault, f"after {self._fail_after} cycles")
        return Status.CONTINUE

    @staticmethod
    def _fail(fault: str, when: str) -> None:
        if fault == "hang":
            threading.Event().wait()  # nobody sets it: blocked as on a device that never answers
        if fault == "abort":
            os.abort()  # SIGABRT: the process ends here, as on a native crash
        raise RuntimeError(f"injected fault {when}")

    def error(self, exc: BaseException | None) -> Status:
        return Status.CONTINUE if self._recoverable else Status.ERROR

    def clear(self) -> bool:
        return True
