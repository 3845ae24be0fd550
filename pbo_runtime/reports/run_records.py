"""What happened when during a run, as `RunResult` keeps it: marks on the run's clock, an
application's decisions, critical tasks' stable episodes and holdings of the table lock.

Each record is made where it happens (job control, the event ledger, the lock watch) and read as
it is by the summary; `to_json` gives its entry in report.json, keys in the order they always had.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

# a variable's value as a decision read it: a number, or nested lists of numbers (numpy's tolist)
Numbers = float | int | bool | list["Numbers"]


def _number(value: object, default: float = 0.0) -> float:
    return float(value) if isinstance(value, int | float) else default


@dataclass(frozen=True, slots=True)
class Mark:
    """A moment a plot of the run's logs marks (a switch, a job, a decision), on the run's clock."""

    time: float
    kind: str
    label: str

    def to_json(self) -> dict[str, object]:
        return {"time": self.time, "kind": self.kind, "label": self.label}

    @classmethod
    def from_json(cls, entry: Mapping[str, object]) -> Mark:
        return cls(_number(entry.get("time")), str(entry.get("kind", "")), str(entry.get("label", "")))


@dataclass(frozen=True, slots=True)
class DecisionTaken:
    """A decision an application took at a step (`if`, `try`, `repeat`, `wait`), with the values it read.

    Which fields a kind has: if (condition, values, taken), try (taken, failure, values), repeat
    (turn, of; with a condition also condition, values, taken), wait (condition, values, taken, waited).
    """

    time: float  # on the run's clock
    path: str  # where the application was: "pick > try"
    kind: str
    taken: str = ""  # "then", "else", "fallback", "done", "again", "failed", "holds"
    condition: str | None = None
    values: Mapping[str, Numbers] | None = None
    failure: str = ""  # try: why the try row failed
    turn: int = 0  # repeat: this turn, of `of`
    of: int = 0
    waited: float = 0.0  # wait: seconds until the condition held

    def to_json(self) -> dict[str, object]:
        head: dict[str, object] = {"time": self.time, "path": self.path, "kind": self.kind}
        values = dict(self.values or {})
        if self.kind == "try":
            return {**head, "taken": self.taken, "failure": self.failure, "values": values}
        if self.kind == "repeat":
            head.update(turn=self.turn, of=self.of)
            if self.condition is None:
                return head
        head.update(condition=self.condition, values=values, taken=self.taken)
        if self.kind == "wait":
            head["waited"] = self.waited
        return head


@dataclass(frozen=True, slots=True)
class StableEpisode:
    """A task that ran its locally stable behaviour from `since` to `until` (None: until the stop),
    run-clock seconds. `while_starting` and `brief` are set when the run is reported (None before):
    it held while the configuration came on; it ended by itself within a few of its periods."""

    task: str
    since: float
    until: float | None
    reason: str
    cause: str  # "stale", "module", "upstream", "lock", "illegal"
    while_starting: bool | None = None
    brief: bool | None = None

    @property
    def seconds(self) -> float | None:
        return None if self.until is None else self.until - self.since

    def to_json(self) -> dict[str, object]:
        entry: dict[str, object] = {"task": self.task, "from": self.since, "to": self.until, "seconds": self.seconds,
                                    "reason": self.reason, "cause": self.cause}
        if self.while_starting is not None:
            entry["while_starting"] = self.while_starting
        if self.brief is not None:
            entry["brief"] = self.brief
        return entry


@dataclass(frozen=True, slots=True)
class LockEvent:
    """A holding of the table lock past its bound, and what the supervisor did about it (supervisor.lock_watch)."""

    pid: int
    holder: str  # who, in words
    role: str  # the holder's role in the run, "" if not a process of it
    state: str  # dead, stopped, running
    held_ms: float
    bound_ms: float
    action: str  # killed, released, left
    at: float  # run seconds

    def to_json(self) -> dict[str, object]:
        return {"pid": self.pid, "holder": self.holder, "role": self.role, "state": self.state, "held_ms": self.held_ms,
                "bound_ms": self.bound_ms, "action": self.action, "at": self.at}
