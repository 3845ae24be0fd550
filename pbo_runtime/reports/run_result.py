"""What a run did: `RunResult`, the summary's data and the JSON report's content (report.json), and
each task's entry in it (`TaskReport`). The supervisor fills it (supervisor/run_report.py)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from pbo_runtime.ipc.task_statistics import TaskStatistics
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.reports.run_records import DecisionTaken, LockEvent, Mark, StableEpisode

# A task whose RTPU was killed before it reported has only what its status block holds
_TABLE_FIGURES = ("cycles", "overruns", "missed", "jitter_max", "jitter_p50", "jitter_p99", "exec_p50", "exec_p99",
                  "exec_max", "last_overruns")


@dataclass(frozen=True)
class TaskReport:
    """A task's entry in the run's report: where it ran, how it ended, its figures."""

    rtpu: str
    critical: bool
    state: str  # at the stop ("?" when unknown)
    error: str  # its last error, "" if none
    statistics: TaskStatistics
    from_table: bool = False  # its RTPU never reported (killed): the figures are its status block's last

    def to_json(self) -> dict[str, Any]:
        figures = self.statistics.to_json()
        if self.from_table:
            figures = {key: figures[key] for key in _TABLE_FIGURES}
        return {"rtpu": self.rtpu, "critical": self.critical, "state": self.state, "error": self.error,
                **({"from_table": True} if self.from_table else {}), **figures}

    @classmethod
    def from_json(cls, entry: Mapping[str, Any]) -> TaskReport:
        return cls(str(entry.get("rtpu", "")), bool(entry.get("critical", False)), str(entry.get("state", "?")),
                   str(entry.get("error", "")), TaskStatistics.from_json(entry), bool(entry.get("from_table", False)))


@dataclass(frozen=True)
class Stall:
    """A task ON that finished no cycle for a while (seconds since the configuration came on)."""

    task: str
    rtpu: str
    since: float
    until: float | None  # None: until the stop
    rtpu_killed: bool  # its RTPU did not stop by itself

    def to_json(self) -> dict[str, Any]:
        return {"task": self.task, "rtpu": self.rtpu, "from": self.since, "to": self.until, "rtpu_killed": self.rtpu_killed}


@dataclass(frozen=True)
class FinalValue:
    """A variable's last value at the run's end: who wrote it, in which unit; `torn` if a writer left
    the table mid-write and it was copied as it was."""

    value: float | int | bool | list[Any]
    sequence: int
    writer: str  # a task's name, or "job control"
    unit: str
    torn: bool = False

    def to_json(self) -> dict[str, Any]:
        return {"value": self.value, "sequence": self.sequence, "writer": self.writer, "unit": self.unit,
                **({"torn": True} if self.torn else {})}

    @classmethod
    def from_json(cls, entry: Mapping[str, Any]) -> FinalValue:
        return cls(entry["value"], int(entry.get("sequence", 0)), str(entry["writer"]), str(entry.get("unit", "")),
                   bool(entry.get("torn", False)))


@dataclass(frozen=True)
class SwitchReport:
    """One switch in the run's report (`supervisor.job_control.SwitchRecord.report`), times in seconds."""

    sequence: int
    before: str  # "from"
    after: str  # "to"
    latency: float  # from the request to the first cycle of the new configuration
    skew: float  # between the RTPUs
    longest: float  # the longest switch on one RTPU
    off: tuple[str, ...]
    on: tuple[str, ...]
    cycles_lost: Mapping[str, int]  # per critical task: cycles that read a switched-out writer
    stale_reads: Mapping[str, int]
    lead: float
    read_delay: float
    grid_wait: float
    work: float
    posted: float
    read_delays: Mapping[str, float]  # per RTPU: from the request to its first read of the plan
    change: str = ""  # a live change applied by this plan, "" for a switch
    restarted: tuple[str, ...] = ()  # RTPUs that died during the switch and came back

    def to_json(self) -> dict[str, Any]:
        return {"sequence": self.sequence, "from": self.before, "to": self.after, "latency": self.latency,
                "skew": self.skew, "longest": self.longest, "off": list(self.off), "on": list(self.on),
                "cycles_lost": dict(self.cycles_lost), "stale_reads": dict(self.stale_reads), "lead": self.lead,
                "read_delay": self.read_delay, "grid_wait": self.grid_wait, "work": self.work, "posted": self.posted,
                "read_delays": dict(self.read_delays), **({"change": self.change} if self.change else {}),
                **({"restarted": list(self.restarted)} if self.restarted else {})}


@dataclass(frozen=True)
class SwitchFigures:
    """What the summary tells of a switch, times in seconds."""

    sequence: int
    latency: float  # from the request to the first cycle of the new configuration
    skew: float  # between the RTPUs
    longest: float  # the longest switch on one RTPU
    restarted: tuple[str, ...]  # RTPUs restarted through it
    lost_a_cycle: bool  # a critical task lost a cycle after it

    @classmethod
    def of(cls, report: SwitchReport) -> SwitchFigures:
        return cls(report.sequence, report.latency, report.skew, report.longest, report.restarted,
                   any(report.cycles_lost.values()))


@dataclass(frozen=True)
class PlantFigures:
    """The plant's figures at its end (messages.PlantStats), as the plant host sent them."""

    steps: int
    late: int
    stalls: int = 0
    stalled_for: float = 0.0  # seconds of wall time it did not integrate (its stalls)
    watchdog_trips: int = 0  # times the arm's drive watchdog held the arm
    left_fifo_behind: float = 0.0  # seconds behind real time when it left SCHED_FIFO (0: it did not)

    def to_json(self) -> dict[str, Any]:
        return {"steps": self.steps, "late": self.late, "stalls": self.stalls, "stalled_for": self.stalled_for,
                "watchdog_trips": self.watchdog_trips, "left_fifo_behind": self.left_fifo_behind}

    @classmethod
    def from_json(cls, figures: Mapping[str, Any]) -> PlantFigures:
        return cls(figures.get("steps", 0), figures.get("late", 0), figures.get("stalls", 0),
                   figures.get("stalled_for", 0.0), figures.get("watchdog_trips", 0),
                   figures.get("left_fifo_behind") or 0.0)


@dataclass(frozen=True)
class RtpuSettings:
    """What an RTPU reported it runs under (rtpu/_realtime.apply): `clock` on the simulated clock
    (then nothing else: no scheduler), else its timer slack, CPU, scheduler and spin."""

    clock: str | None = None
    timer_slack: str | None = None
    cpu: str | None = None
    scheduler: str | None = None
    spin: str | None = None

    @property
    def simulated(self) -> bool:
        return self.clock is not None

    def to_json(self) -> dict[str, str]:
        given = {"clock": self.clock, "timer_slack": self.timer_slack, "cpu": self.cpu, "scheduler": self.scheduler,
                 "spin": self.spin}
        return {key: value for key, value in given.items() if value is not None}

    @classmethod
    def from_json(cls, settings: Mapping[str, str]) -> RtpuSettings:
        return cls(settings.get("clock"), settings.get("timer_slack"), settings.get("cpu"), settings.get("scheduler"),
                   settings.get("spin"))


class RestartRecord(Protocol):
    """An RTPU's restart as the report keeps it (`supervisor.restarts.Restart`)."""

    def to_json(self) -> dict[str, Any]: ...


@dataclass
class RunResult:
    """What a run did: the summary's data and the JSON report's content."""

    subsystem: str
    configuration: str
    duration: float = 0.0
    stopped_by: str = "duration"
    failure: str = ""
    tasks: dict[str, TaskReport] = field(default_factory=dict)
    variables: dict[str, FinalValue] = field(default_factory=dict)
    plant: PlantFigures | None = None  # None: the run had no plant, or it never reported
    lock_recoveries: int = 0
    run_id: str = ""
    objects: list[str] = field(default_factory=list)  # every shared object the run made ("kind /name")
    states_at_stop: dict[str, str] = field(default_factory=dict)
    application: str = ""
    jobs_done: list[str] = field(default_factory=list)
    switches: list[SwitchReport] = field(default_factory=list)
    stable_episodes: list[StableEpisode] = field(default_factory=list)
    realtime: dict[str, RtpuSettings] = field(default_factory=dict)  # per RTPU: cpu, scheduler, timer slack
    clock: str = "real"
    tick: float = 0.0  # seconds per tick of the simulated clock
    pace: float | None = None  # simulated seconds per wall second at most (`pbo run --pace`); None: unpaced
    wall_seconds: float = 0.0  # how long the run took on the wall clock (a sim run's speed: duration / this)
    # of which from the configuration on to the stop: start-up and stop left out (a sim run's ticks: duration / this)
    running_wall_seconds: float = 0.0
    links: dict[str, RunLink] = field(default_factory=dict)  # an application's links this run was handed
    # CLOCK_MONOTONIC second the configuration came on (real clock; 0 on the simulated one): the
    # origin of each task's last_overruns times, to match them with a trace of the machine (tools/cpu_trace.py)
    started_monotonic: float = 0.0
    # tasks ON that finished no cycle for a while: task, rtpu, from and to (seconds since the
    # configuration came on; to None: until the stop), rtpu_killed (its RTPU did not stop by itself)
    stalls: list[Stall] = field(default_factory=list)
    unstopped: list[str] = field(default_factory=list)  # RTPUs that did not stop within STOP_TIMEOUT and were killed
    # What went wrong without stopping the run, one line each (a critical task held stable by
    # stale inputs, ...): the run ends with exit status 2 and the summary lists them
    faults: list[str] = field(default_factory=list)
    # brief holds of critical tasks on late inputs (BRIEF_HOLD_PERIODS), one line per task and cause: timing, not faults
    timing_holds: list[str] = field(default_factory=list)
    lock_events: list[LockEvent] = field(default_factory=list)  # holdings of the table lock past its bound
    # what the run's queues take of RLIMIT_MSGQUEUE (depth x (message size + the kernel's 96 B)), as made
    queue_bytes: int = 0
    # the run's clock (what a data log's time is: CLOCK_MONOTONIC, or simulated seconds) when the
    # configuration came on, and what happened when on it: switches and jobs (JobControl.marks)
    started_at: float = 0.0
    marks: list[Mark] = field(default_factory=list)
    decisions: list[DecisionTaken] = field(default_factory=list)  # an application's decisions, with their values
    # RTPUs restarted by their restart policy (supervisor.restarts.Restart), in the order they died
    restarts: list[RestartRecord] = field(default_factory=list)
    # the start-up's time line, phase -> CLOCK_MONOTONIC second it ended (wall time, on either run
    # clock): from the process's start ("process", to the kernel's 10 ms) to "on", the moment every
    # task of the first configuration was ON (docs/running.md: where start-up time goes)
    startup: dict[str, float] = field(default_factory=dict)
    gains: list[str] = field(default_factory=list)  # the gains each controller given a bandwidth made (the check's notes)

    def to_json(self) -> dict[str, Any]:
        return {
            "subsystem": self.subsystem, "configuration": self.configuration, "duration": self.duration,
            "stopped_by": self.stopped_by, "failure": self.failure,
            "tasks": {name: task.to_json() for name, task in self.tasks.items()},
            "variables": {name: final.to_json() for name, final in self.variables.items()},
            "plant": self.plant.to_json() if self.plant is not None else {},
            "lock_recoveries": self.lock_recoveries,
            "run_id": self.run_id, "objects": self.objects, "states_at_stop": self.states_at_stop,
            "application": self.application, "jobs_done": self.jobs_done,
            "switches": [switch.to_json() for switch in self.switches],
            "stable_episodes": [episode.to_json() for episode in self.stable_episodes],
            "realtime": {rtpu: settings.to_json() for rtpu, settings in self.realtime.items()},
            "clock": self.clock, "tick": self.tick, "pace": self.pace, "wall_seconds": self.wall_seconds,
            "running_wall_seconds": self.running_wall_seconds,
            "links": {name: link.to_json() for name, link in self.links.items()},
            "started_monotonic": self.started_monotonic, "stalls": [stall.to_json() for stall in self.stalls],
            "unstopped": self.unstopped,
            "faults": self.faults, "timing_holds": self.timing_holds, "queue_bytes": self.queue_bytes,
            "lock_events": [event.to_json() for event in self.lock_events], "started_at": self.started_at,
            "marks": [mark.to_json() for mark in self.marks],
            "decisions": [decision.to_json() for decision in self.decisions],
            "restarts": [restart.to_json() for restart in self.restarts],
            "startup": self.startup, "gains": self.gains,
        }
