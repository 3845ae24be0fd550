"""The control-queue service: the operator's verbs (`supervisor.commands`) served between events,
on the running subsystem as their `CommandHost`."""

from __future__ import annotations

from collections.abc import Callable

from pbo_runtime.ipc.control import ControlServer
from pbo_runtime.supervisor.commands import CommandHost, dispatch
from pbo_runtime.table.table import Flag, StateTable


class ControlService:
    """The supervisor's part that serves operator commands; `control` gives the server once the run made it."""

    def __init__(self, host: CommandHost, control: Callable[[], ControlServer | None]) -> None:
        self.host = host
        self.control = control
        self.serving = False  # a command is being served (a switch it waits for pumps events meanwhile)

    def serve(self) -> None:
        """Operator commands (pbo status, on, off, ...): served between events, never in a cycle."""
        control = self.control()
        if control is None or self.serving:
            return  # a command that waits (a switch) pumps events, but serves no second command meanwhile
        self.serving = True
        try:
            control.poll(lambda command, arguments: dispatch(self.host, command, arguments))
        finally:
            self.serving = False


def table_flags(table: StateTable | None) -> list[str]:
    """The names of the table's flags that are set (SIM_CLOCK says which clock the times are on, not a
    state the operator must look at)."""
    return [str(flag.name) for flag in Flag if flag is not Flag.SIM_CLOCK and table is not None and table.flags & flag]
