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
and its restart succeeds. With `at: [0.5, 1.0, 1.5]` (seconds on the run's clock) the fault
happens at given times instead of after `fail_after` cycles: in the first cycle released at or
after the first listed time not before the task's `init`, once each. A task spawned again after
its RTPU was restarted (`restarted`) takes the next listed time after its `init`, never again the
one it just faulted at: with `fault: abort` and a restart policy, a run so crashes its RTPU at
each listed time, and on the simulated clock (`--clock sim`) at the same ticks every run.
With `command: 1.0e6` it does not fail itself: it drives the arm wrongly, writing that value to
every joint of its output port `command` (bind it to the arm's command: `ports: {command: tau_u}`,
in place of the controller) every cycle, so the robot interface's limits are seen at work: the
command clipped to the effort limits, then the saturation fault that brakes the arm.
Shipped as real code (not a mock) so operators can rehearse the procedure on the simulated arm.
"""

from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass
from typing import Literal

import numpy as np

from pbo_runtime import InVar, OutVar, PortBasedObject, PortSpec, Status, param


@dataclass(frozen=True)
class FaultInjectorParams:
    fail_after: int = param(1000, at_least=0, at_most=1_000_000_000)  # cycles before the fault
    recoverable: bool = False  # True: the error component recovers by itself (the task stays ON)
    fault: Literal["raise", "hang", "abort"] = "raise"  # raises once; never returns; or crashes the process (os.abort)
    in_init: bool = False  # the fault happens in init (every time the task is spawned), not after fail_after cycles
    in_on: bool = False  # the fault happens in on (once per run: not in a restarted RTPU), not after fail_after cycles
    at: tuple[float, ...] = param(
        (), at_least=0, at_most=1e6)  # s on the run's clock: fault at each of these times (once each), not after fail_after
    command: float | None = param(
        None, at_least=-1e9,
        at_most=1e9)  # writes this to every joint of the port `command` each cycle (N m, rad), and never fails

    def __post_init__(self) -> None:
        if self.fail_after < 0:
            raise ValueError(f"fail_after must be >= 0, got: {self.fail_after}")
        if [self.in_init, self.in_on, bool(self.at)].count(True) > 1:
            raise ValueError("in_init, in_on and at are exclusive: the fault happens in one place")
        times = tuple(float(t) for t in self.at)
        if any(t < 0 for t in times) or list(times) != sorted(set(times)):
            raise ValueError(f"at must list times in seconds, >= 0 and increasing, got: {list(self.at)}")
        object.__setattr__(self, "at", times)
        if self.command is not None and not math.isfinite(self.command):
            raise ValueError(f"command must be a finite number, got: {self.command}")


class FaultInjector(PortBasedObject):
    """Raises once in `cycle` after `fail_after` cycles or at each time of `at` (or hangs, or aborts the
    process); `clear` then returns it to OFF."""

    Params = FaultInjectorParams

    watched = InVar("q_m", dtype="any", shape=None, doc="any variable: read every cycle, not used")

    @classmethod
    def ports_for(cls, params: FaultInjectorParams) -> tuple[PortSpec, ...]:
        """With `command`, an out-var `command` (one value per joint) besides the watched variable."""
        if params.command is None:
            return cls.ports()
        port = OutVar("tau_u", shape=("NDOF",), doc="the wrong command written every cycle (bind it with ports:)").spec
        return (*cls.ports(), PortSpec("command", port.kind, port.variable, port.dtype, port.shape, port.doc))

    def init(self, params: FaultInjectorParams) -> None:
        self._command = params.command
        self._out = self.bound_arrays[-1] if params.command is not None else np.zeros(0)
        if params.in_init:
            self._fail(params.fault, "in init")
        self._fail_after = params.fail_after
        self._recoverable = params.recoverable
        self._fault = params.fault
        self._in_on = params.in_on
        self.cycles = 0
        self.failed = False
        # The time this task faults at (inf: never): the first listed at or after its init; after a
        # restart, the first listed after it, since the init runs at the instant of the last fault.
        self._times = [t for t in params.at if t > self.time or (t == self.time and not self.restarted)]
        self._times.append(math.inf)  # past the last: never again
        self._fail_at = self._times.pop(0)
        self._timed = bool(params.at)

    def on(self) -> None:
        if self._in_on and not self.restarted and not self.failed:
            self.failed = True
            self._fail(self._fault, "in on")

    def cycle(self) -> Status:
        self.cycles += 1
        if self._command is not None:
            self._out.fill(self._command)
            return Status.CONTINUE
        if self._timed:
            if self.time >= self._fail_at:
                at, self._fail_at = self._fail_at, self._times.pop(0)  # the next listed time, from the list made in init
                self._fail(self._fault, f"at {at:g} s")
        elif not self.failed and not self._in_on and self.cycles > self._fail_after:
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
