"""Why a run stopped early: a failure of the run, or the operator asking it to stop."""

from __future__ import annotations

from pbo_runtime.errors import PboError


class RunFailure(PboError):
    """The run could not start or had to stop: the message says which process or task, and why."""


class RunRefused(PboError):
    """The run may not start: another live run holds what it needs. Nothing of it is left running."""


class StopRequested(Exception):
    """Ctrl-C, SIGTERM or `pbo stop` while job control was waiting: stop cleanly, not a failure."""
