"""A module that fails on purpose: to see and rehearse error handling end to end (TR §4.3).

It watches a variable (e.g. q_m) and, after `fail_after` cycles, raises in `cycle` once, as a
driver fault or a numerical blow-up would. Its `error` component cannot recover, so the task
waits in ERROR and job control shows it; its `clear` component reports the fault fixed, so the
operator's `pbo clear` returns it to OFF and `pbo on` resumes it. With `fault: hang` its cycle
never returns instead, as a driver call waiting for a device that never answers: every task of
its RTPU stops with it, and the critical tasks that read their outputs hold the arm. Shipped as
real code (not a mock) so operators can rehearse the procedure on the simulated arm.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Literal

from pbo_runtime import InVar, PortBasedObject, Status


@dataclass(frozen=True)
class FaultInjectorParams:
    fail_after: int = 1000  # cycles before the fault
    recoverable: bool = False  # True: the error component recovers by itself (the task stays ON)
    fault: Literal["raise", "hang"] = "raise"  # "raise": the cycle raises once; "hang": the cycle never returns

    def __post_init__(self) -> None:
        if self.fail_after < 0:
            raise ValueError(f"fail_after must be >= 0, got: {self.fail_after}")


class FaultInjector(PortBasedObject):
    """Raises once in `cycle` after `fail_after` cycles (or hangs there); `clear` then returns it to OFF."""

    Params = FaultInjectorParams

    watched = InVar("q_m", dtype="any", shape=None, doc="any variable: read every cycle, not used")

    def init(self, params: FaultInjectorParams) -> None:
        self._fail_after = params.fail_after
        self._recoverable = params.recoverable
        self._hangs = params.fault == "hang"
        self.cycles = 0
        self.failed = False

    def cycle(self) -> Status:
        self.cycles += 1
        if not self.failed and self.cycles > self._fail_after:
            self.failed = True
            if self._hangs:
                threading.Event().wait()  # nobody sets it: blocked as on a device that never answers
            raise RuntimeError(f"injected fault after {self._fail_after} cycles")
        return Status.CONTINUE

    def error(self, exc: BaseException | None) -> Status:
        return Status.CONTINUE if self._recoverable else Status.ERROR

    def clear(self) -> bool:
        return True
