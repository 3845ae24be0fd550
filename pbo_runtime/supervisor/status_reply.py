"""A task's entry in the status reply (`pbo status`, the live view, the API): typed on both ends.

The supervisor reads `TaskRow` from the task's status block; the status verb adds what job control
knows (`TaskStatusEntry`); `to_json` gives the reply's keys (supervisor/commands.py's docstring),
and the operator's terminal reads them back with `from_json`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from pbo_runtime.table.table import StatusWord as W
from pbo_runtime.table.table import TaskState


@dataclasses.dataclass(frozen=True, slots=True)
class TaskRow:
    """A task's counters from its status block. The percentiles are over its last 1,024 cycles,
    published by the executive every 1,024 cycles (0 before); None: a reply that did not have them."""

    task: str
    rtpu: str
    state: str  # TaskState's name
    cycles: int = 0
    overruns: int = 0
    missed: int = 0
    jitter_max: float = 0.0
    jitter_p50: float | None = None
    jitter_p99: float | None = None
    exec_p50: float | None = None
    exec_p99: float | None = None
    exec_last: float = 0.0

    @classmethod
    def from_words(cls, task: str, rtpu: str, words: np.ndarray) -> TaskRow:
        return cls(task, rtpu, TaskState(int(words[W.STATE])).name, int(words[W.CYCLES]), int(words[W.OVERRUNS]),
                   int(words[W.MISSED]), float(words[W.JITTER_MAX]), float(words[W.JITTER_P50]),
                   float(words[W.JITTER_P99]), float(words[W.EXEC_P50]), float(words[W.EXEC_P99]),
                   float(words[W.EXEC_LAST]))

    def to_json(self) -> dict[str, Any]:
        return {"task": self.task, "rtpu": self.rtpu, "state": self.state, "cycles": self.cycles,
                "overruns": self.overruns, "missed": self.missed, "jitter_max": self.jitter_max,
                **{name: value for name, value in (("jitter_p50", self.jitter_p50), ("jitter_p99", self.jitter_p99),
                                                   ("exec_p50", self.exec_p50), ("exec_p99", self.exec_p99))
                   if value is not None},
                "exec_last": self.exec_last}


@dataclasses.dataclass(frozen=True, slots=True)
class TaskStatusEntry:
    """A task of the status reply: its row, where its status block is, its rate, and its error while in ERROR."""

    row: TaskRow  # its state is job control's when job control knows it
    index: int | None = None  # its status block (None: tasks[i] is block i)
    rate: float | None = None  # measured Hz
    error: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {**self.row.to_json(), **({} if self.index is None else {"index": self.index}),
                "rate": self.rate, "error": self.error}

    @classmethod
    def from_json(cls, entry: Mapping[str, Any]) -> TaskStatusEntry:
        def optional(key: str) -> float | None:
            value = entry.get(key)
            return None if value is None else float(value)

        row = TaskRow(str(entry.get("task", "?")), str(entry.get("rtpu", "?")), str(entry.get("state", "?")),
                      int(entry.get("cycles", 0)), int(entry.get("overruns", 0)), int(entry.get("missed", 0)),
                      float(entry.get("jitter_max") or 0.0), optional("jitter_p50"), optional("jitter_p99"),
                      optional("exec_p50"), optional("exec_p99"), float(entry.get("exec_last") or 0.0))
        index = entry.get("index")
        error = entry.get("error")
        return cls(row, None if index is None else int(index), optional("rate"), None if error is None else str(error))
