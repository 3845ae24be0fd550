"""Why a run stopped early: a failure of the run, or the operator asking it to stop."""

from __future__ import annotations

from pbo_runtime.errors import PboError


class RunFailure(PboError):
    """The run could not start or had to stop: the message says which process or task, and why."""


class WrongArgument(PboError):
    """An argument of `pbo run` names what the file does not have (`--config nope`): bad input, exit 1."""


class RunRefused(PboError):
    """The run may not start: another live run holds what it needs. Nothing of it is left running."""


class StopRequested(Exception):
    """Ctrl-C, SIGTERM or `pbo stop` while job control was waiting: stop cleanly, not a failure."""


class RtpuDied(RunFailure):
    """An RTPU whose restart policy may bring it back died: caught where job control can restart it.

    Uncaught, it is the same failure as any child's death, with the same message."""

    def __init__(self, message: str, rtpu: str, pid: int, cause: str) -> None:
        super().__init__(message)
        self.rtpu, self.pid, self.cause = rtpu, pid, cause
