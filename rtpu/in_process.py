"""An RTPU hosted in the supervisor's own process (`pbo run --clock sim --one-process`).

The same executive and tasks as `python -m rtpu` builds (`host_tasks`), on the same table, each
turn the same code (`Executive.step_lockstep`): only who gives the turn differs. The supervisor's
ring calls `step` where a process would have been woken by its semaphore, so a run replays the
run of processes bit for bit, without a process hand-over per tick.
"""

from __future__ import annotations

import traceback

from pbo_runtime.config.model import Subsystem
from pbo_runtime.ipc import limits, messages
from pbo_runtime.supervisor.launch import RtpuLaunch
from pbo_runtime.table.table import StateTable, TableLayout
from rtpu.__main__ import Hosting, host_tasks, pump


class HostedRtpu:
    """One RTPU as a participant of the one process's ring: `step` is its turn, `poll` its exit status."""

    def __init__(self, launch: RtpuLaunch, hosting: Hosting, table: StateTable, signals: messages.Queue,
                 events: messages.Queue) -> None:
        self.name = launch.rtpu
        self.hosting = hosting
        self.executive = hosting.executive
        self._pumped = hosting.pumped
        self._step_lockstep = hosting.executive.step_lockstep  # bound once: called every tick
        self.table = table
        self.signals = signals
        self.events = events
        self.returncode: int | None = None

    def step(self, new_tick: bool) -> None:
        """Its turn: the relays, then the signals queued for it and, on a new tick, its due cycles."""
        if self.returncode is not None:
            return
        try:
            if self._pumped:
                pump(self._pumped)
            self._step_lockstep(new_tick)
        except Exception as exc:  # what would have ended its process ends it here: reported as a crash
            self._crashed(exc)
            return
        if not self.executive.running:  # it served its stop
            self._end(0)

    def poll(self) -> int | None:
        return self.returncode

    def terminate(self) -> None:
        """Stop now, as its process does on SIGTERM: every task off and killed, statistics reported."""
        if self.returncode is not None:
            return
        try:
            if self.executive.running:
                self.executive.stop()
        except Exception as exc:
            self._crashed(exc)
            return
        self._end(0)

    def _crashed(self, exc: Exception) -> None:
        limit = limits.explain(exc, self.name)
        self.events.report(self.name, messages.Crashed(str(limit), "") if limit is not None
                           else messages.Crashed(f"{type(exc).__name__}: {exc}", traceback.format_exc()))
        self._end(1)

    def _end(self, code: int) -> None:
        self.returncode = code
        self.signals.close()
        self.table.close()


def start(argv: list[str], subsystem: Subsystem, events: messages.Queue,
          job_control_end: messages.Queue | None = None) -> HostedRtpu:
    """Host the RTPU `python -m rtpu ARGV` would run, in this process; it reports Ready as that process does.
    It reads its signals from another end of `job_control_end` (its signal queue) where given, else opens the queue."""
    launch = RtpuLaunch.parse(argv)
    name = subsystem.name

    def report(event: messages.Event) -> None:
        events.report(launch.rtpu, event)

    table = StateTable.attach(TableLayout.of(subsystem), messages.table_name(name, launch.run_id))
    try:
        signals = (job_control_end.another_end() if job_control_end is not None
                   else messages.Queue(messages.signal_queue_name(name, launch.run_id, launch.rtpu)))
        try:
            hosting = host_tasks(launch, subsystem, table, signals, report, report, in_process=True)
        except BaseException:
            signals.close()
            raise
    except BaseException:
        table.close()
        raise
    report(messages.Ready(hosting.realtime))
    return HostedRtpu(launch, hosting, table, signals, events)
