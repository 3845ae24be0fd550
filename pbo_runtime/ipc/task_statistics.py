"""A task's figures over a run: what its executive counted, the Stats event that carries them, report.json.

The executive builds one `TaskStatistics` per report (at `pbo stats` and at the stop), never per
cycle. `to_json` gives the keys report.json has always had (docs/data.md), `from_json` reads
them back; the summary and the report read the fields, never the keys.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any


@dataclasses.dataclass(frozen=True, slots=True)
class Overrun:
    """One overrun: when its cycle was released, how late it started, how long it ran (seconds)."""

    release: float
    late: float
    took: float


@dataclasses.dataclass(frozen=True, slots=True)
class ProcessorTiming:
    """A special-purpose processor's own timing (TR 4.6.3), as its driver's figures give it."""

    device: str
    routine: str
    items: int
    service_p50: float
    service_p99: float
    service_max: float
    missed: int
    late_calls: int
    calls: int
    fault: str
    scheduler: str = ""  # its policy at the stop ("SCHED_FIFO 1"); "" where it had ended


@dataclasses.dataclass(frozen=True, slots=True)
class TaskStatistics:
    """What a task did over the run. Times in seconds; percentiles over the last 65,536 cycles."""

    cycles: int = 0
    overruns: int = 0
    missed: int = 0  # releases skipped after overruns, or while the table lock was held too long
    errors: int = 0
    jitter_p50: float = 0.0  # release lateness
    jitter_p99: float = 0.0
    jitter_max: float = 0.0
    exec_p50: float = 0.0  # execution time of a cycle
    exec_p99: float = 0.0
    exec_max: float = 0.0
    bytes_in: int = 0  # the data of the per-cycle ports
    bytes_out: int = 0
    bytes_moved_per_cycle: int = 0  # what the transfer copies, padding and metadata included
    stale_reads: int = 0  # reads older than one writer period
    stale_reads_at_switches: int = 0  # of which within 3 periods of a switch
    last_stale_read: str = ""
    cycles_lost_to_switches: int = 0
    last_cycle_lost: str = ""
    stable_cycles: int = 0
    expired_reads: int = 0  # cycles a critical task ran stable because an input was past its bound
    lock_waits_given_up: int = 0
    dropped_events: int = 0
    overruns_long_cycle: int = 0  # overruns the cycle alone caused (it ran longer than a period)
    last_overruns: tuple[Overrun, ...] = ()  # the last few, oldest first
    outputs: tuple[str, ...] = ()  # the files its module wrote (a data log)
    # its drivers' own figures, by device: each driver says what they are (drivers/*/driver.py `figures`)
    devices: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)

    @property
    def bytes_per_cycle(self) -> int:
        return self.bytes_in + self.bytes_out

    @property
    def overruns_late_release(self) -> int:
        """Overruns of a release that started late (the machine held the RTPU's CPU)."""
        return self.overruns - self.overruns_long_cycle

    def processors(self) -> list[ProcessorTiming]:
        """Its special-purpose processors' timing, from their drivers' figures."""
        return [ProcessorTiming(device, str(f.get("routine") or "none"), int(f["items"]), float(f["service_p50"]),
                                float(f["service_p99"]), float(f["service_max"]), int(f["missed"]),
                                int(f["late_calls"]), int(f["calls"]), str(f.get("fault") or ""),
                                str(f.get("scheduler") or ""))
                for device, f in self.devices.items() if f.get("processor") == "spp"]

    def to_json(self) -> dict[str, Any]:
        """report.json's keys for a task's figures (and the Stats event's, on the wire)."""
        return {
            "cycles": self.cycles, "overruns": self.overruns, "missed": self.missed, "errors": self.errors,
            "jitter_p50": self.jitter_p50, "jitter_p99": self.jitter_p99, "jitter_max": self.jitter_max,
            "exec_p50": self.exec_p50, "exec_p99": self.exec_p99, "exec_max": self.exec_max,
            "bytes_in": self.bytes_in, "bytes_out": self.bytes_out, "bytes_per_cycle": self.bytes_per_cycle,
            "bytes_moved_per_cycle": self.bytes_moved_per_cycle,
            "stale_reads": self.stale_reads, "stale_reads_at_switches": self.stale_reads_at_switches,
            "last_stale_read": self.last_stale_read, "cycles_lost_to_switches": self.cycles_lost_to_switches,
            "last_cycle_lost": self.last_cycle_lost, "stable_cycles": self.stable_cycles,
            "expired_reads": self.expired_reads, "lock_waits_given_up": self.lock_waits_given_up,
            "dropped_events": self.dropped_events, "overruns_long_cycle": self.overruns_long_cycle,
            "overruns_late_release": self.overruns_late_release,
            "last_overruns": [[o.release, o.late, o.took] for o in self.last_overruns],
            **({"outputs": list(self.outputs)} if self.outputs else {}),
            **({"devices": {device: dict(figures) for device, figures in self.devices.items()}} if self.devices else {}),
        }

    @classmethod
    def from_json(cls, figures: Mapping[str, Any]) -> TaskStatistics:
        """Read back what `to_json` wrote; a figure a report does not have (the table's few) is 0."""
        return cls(
            cycles=int(figures.get("cycles", 0)), overruns=int(figures.get("overruns", 0)),
            missed=int(figures.get("missed", 0)), errors=int(figures.get("errors", 0)),
            jitter_p50=float(figures.get("jitter_p50", 0.0)), jitter_p99=float(figures.get("jitter_p99", 0.0)),
            jitter_max=float(figures.get("jitter_max", 0.0)), exec_p50=float(figures.get("exec_p50", 0.0)),
            exec_p99=float(figures.get("exec_p99", 0.0)), exec_max=float(figures.get("exec_max", 0.0)),
            bytes_in=int(figures.get("bytes_in", 0)), bytes_out=int(figures.get("bytes_out", 0)),
            bytes_moved_per_cycle=int(figures.get("bytes_moved_per_cycle", 0)),
            stale_reads=int(figures.get("stale_reads", 0)),
            stale_reads_at_switches=int(figures.get("stale_reads_at_switches", 0)),
            last_stale_read=str(figures.get("last_stale_read", "")),
            cycles_lost_to_switches=int(figures.get("cycles_lost_to_switches", 0)),
            last_cycle_lost=str(figures.get("last_cycle_lost", "")), stable_cycles=int(figures.get("stable_cycles", 0)),
            expired_reads=int(figures.get("expired_reads", 0)),
            lock_waits_given_up=int(figures.get("lock_waits_given_up", 0)),
            dropped_events=int(figures.get("dropped_events", 0)),
            overruns_long_cycle=int(figures.get("overruns_long_cycle", 0)),
            last_overruns=tuple(Overrun(float(r), float(late), float(took))
                                for r, late, took in figures.get("last_overruns", [])),
            outputs=tuple(str(path) for path in figures.get("outputs", [])),
            devices={str(device): dict(f) for device, f in figures.get("devices", {}).items()},
        )
