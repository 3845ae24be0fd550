"""The control-queue service: the operator's verbs (`supervisor.commands`) served between events,
and what the Supervisor offers them as their `CommandHost`."""

from __future__ import annotations

from typing import Any, Callable, cast

from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.control import ControlServer
from pbo_runtime.supervisor.commands import CommandHost, dispatch
from pbo_runtime.supervisor.run_report import RunResult
from pbo_runtime.supervisor.stall_watch import StallWatch
from pbo_runtime.table.table import Flag, StateTable


class ControlService:
    """The Supervisor's part that serves operator commands."""

    table: StateTable | None
    result: RunResult
    control: ControlServer | None
    stall_watch: StallWatch
    reconfiguration: Reconfiguration
    configuration: str
    task_states: dict[str, str]
    _serving: bool
    _signal: Callable[[messages.TaskSignal], None]
    _await_change: Callable[[str, str | None, set[str]], str]
    _count_errors: Callable[[], None]

    def _serve_commands(self) -> None:
        """Operator commands (pbo status, on, off, ...): served between events, never in a cycle."""
        if self.control is None or self._serving:
            return  # a command that waits (a switch) pumps events, but serves no second command meanwhile
        self._serving = True
        try:
            host = cast(CommandHost, self)  # the Supervisor this mixin is part of
            self.control.poll(lambda command, arguments: dispatch(host, command, arguments))
        finally:
            self._serving = False

    @property
    def realtime(self) -> dict[str, dict[str, str]]:
        return self.result.realtime

    def table_flags(self) -> list[str]:
        # SIM_CLOCK says which clock the times are on, not a state the operator must look at
        return [str(flag.name) for flag in Flag if flag is not Flag.SIM_CLOCK and self.table is not None and self.table.flags & flag]

    def stalled_since(self) -> dict[str, float]:
        return {name: stall.since for name, stall in self.stall_watch.open.items()}

    def restarts(self) -> list[dict[str, Any]]:
        return [restart.to_json() for restart in self.result.restarts]

    def signal_task(self, task: str, op: str, states: set[str]) -> str:
        """Send on, off or clear to a task; its state once it is one of `states` (a refusal raises PboError)."""
        before = self.task_states.get(task)
        signal: messages.TaskSignal
        if op == "on":  # a critical task learns who writes its inputs in the running configuration
            signal = messages.TurnOn(task, None, self.reconfiguration.index(self.configuration))
        else:
            signal = messages.TurnOff(task) if op == "off" else messages.Clear(task)
        self._signal(signal)
        state = self._await_change(task, before, states)
        self._count_errors()
        return state

    def send_event(self, task: str, values: Any) -> None:
        self._signal(messages.OperatorEvent(task, values))
