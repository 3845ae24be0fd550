"""Stalled tasks: a task that is ON but finishes no cycle for a while.

The executive counts an overrun when a late cycle ends. A cycle that never ends (a module stuck
in a loop, an RTPU that gets no CPU) is never counted there, and its RTPU cannot report anything:
job control sees it from outside, as a cycle count in the table that stops moving. Periodic tasks
only: an aperiodic task waits for events by design.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from pbo_runtime.config.model import TaskSpec

STALL_PERIODS = 10  # a task is stalled after this many periods without a cycle ...
STALL_FLOOR = 0.5  # ... and never sooner than this (seconds): a slow start-up or a VM stall is not one


@dataclass
class Stall:
    """One episode, in run time (the supervisor's clock): `until` is None while it lasts."""

    task: str
    rtpu: str
    since: float  # when its cycle count last moved
    until: float | None = None


class StallWatch:
    """Looks at each ON periodic task's cycle count; opens a Stall when it stops, closes it when it moves."""

    def __init__(self, tasks: Iterable[TaskSpec], cycles_of: Callable[[int], float],
                 say: Callable[[str], None] = lambda text: None) -> None:
        self.watch_tasks(tasks)
        self._cycles_of = cycles_of  # task index -> its cycle count in the table
        self._say = say
        self._seen: dict[str, tuple[float, float]] = {}  # task -> (cycle count, when it was first seen)
        self.open: dict[str, Stall] = {}
        self.episodes: list[Stall] = []

    def stalled_since(self) -> dict[str, float]:
        """Each task stalled now, and since when (run time)."""
        return {name: stall.since for name, stall in self.open.items()}

    def watch_tasks(self, tasks: Iterable[TaskSpec]) -> None:
        """Watch these tasks from now on (a live change added or removed some); episodes are kept."""
        self._watched = [(t.name, t.rtpu, t.index, t.period, max(STALL_PERIODS * t.period, STALL_FLOOR))
                         for t in tasks if not t.aperiodic]

    def check(self, now: float, states: dict[str, str]) -> None:
        for name, rtpu, index, period, limit in self._watched:
            if states.get(name) != "ON":
                self._seen.pop(name, None)  # its count may rest: watched afresh once it is ON again
                stall = self.open.pop(name, None)
                if stall is not None:  # its RTPU reported the change of state: the cycle had returned
                    stall.until = now
                continue
            cycles = self._cycles_of(index)
            seen = self._seen.get(name)
            if seen is None or seen[0] != cycles:
                self._seen[name] = (cycles, now)
                stall = self.open.pop(name, None)
                if stall is not None:
                    stall.until = now
                    self._say(f"task '{name}' ({rtpu}) finishes cycles again, after {now - stall.since:.2f} s without one")
                continue
            if name not in self.open and now - seen[1] > limit:
                stall = self.open[name] = Stall(name, rtpu, seen[1])
                self.episodes.append(stall)
                self._say(f"task '{name}' ({rtpu}, {period * 1e3:g} ms period) has finished no cycle for "
                          f"{now - seen[1]:.2f} s: its module's cycle has not returned, or {rtpu} gets no CPU")
