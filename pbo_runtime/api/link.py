"""How the API reaches the run it serves: the control queue for verbs, the table for streams.

`LiveRunLink` finds the run at each request, as every operator verb does (`ipc.runs.find_run`, by
`--subsystem` and `--run` when several are alive), so `pbo hmi` started before its run, or left
open across runs, serves whichever run is alive when asked. Tests give the app a fake link.
"""

from __future__ import annotations

from typing import Any, Protocol

from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import ControlClient, find_live_run
from pbo_runtime.ipc.runs import SeveralRuns, live_runs
from pbo_runtime.table.svar import TableView, attach


class NoRun(PboError):
    """No live run is the one meant (none alive, or several and none picked: `several`): the message says which."""

    def __init__(self, message: str, several: bool = False) -> None:
        super().__init__(message)
        self.several = several


class RunLink(Protocol):
    """What the API needs of the run it serves."""

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        """The supervisor's reply to one verb (`{"ok": ...}`); NoRun, or PboError when nobody answered."""

    def open_table(self) -> TableView:
        """A read-only, lock-free view of the run's table (the caller closes it); NoRun when there is no run."""

    def runs(self) -> list[dict[str, Any]]:
        """This user's live runs, as `pbo runs --format json` lists them (without asking their supervisors)."""


class LiveRunLink:
    """The live run meant by `subsystem` and `run` (a run id's prefix), or the only one; found at each request."""

    def __init__(self, subsystem: str | None = None, run: str | None = None) -> None:
        self.subsystem = subsystem
        self.run = run

    def find(self) -> tuple[str, str, str]:
        """(subsystem, run id, table name) of the run meant now; NoRun with the operator verbs' message if none."""
        try:
            return find_live_run(self.subsystem, self.run)
        except SeveralRuns as exc:
            raise NoRun(str(exc), several=True) from None
        except PboError as exc:
            raise NoRun(str(exc)) from None

    def request(self, command: str, arguments: dict[str, Any], timeout: float) -> dict[str, Any]:
        subsystem, run_id, _table = self.find()
        return ControlClient(subsystem, run_id).request(command, arguments, timeout)

    def open_table(self) -> TableView:
        subsystem, run_id, table = self.find()
        return attach(table, subsystem, run_id)

    def runs(self) -> list[dict[str, Any]]:
        return [run.to_json() for run in live_runs(self.subsystem)]
