"""Bus utilisation predicted from a file: TR eq. 1-2, which the checker holds below the bandwidth (E510).

Every task j copies its per-cycle inputs from the global state variable table into its local
table before each cycle and its per-cycle outputs back after it, locking the table once for
each set of transfers (TR §4.2, Figure 11). Its load on the bus, in bytes per second, is

    Z_j = (Σ_i S(x_ij) + Σ_i S(y_ij) + 2Δ) / T_j                                   (eq. 1)

x_ij: the task's per-cycle inputs (in-var and in-both ports); y_ij: its per-cycle outputs
(out-var and out-both); S(v): the bytes one transfer of v moves (elements x itemsize);
Δ: the bus's lock overhead in bytes (locking and releasing the table, counted twice a cycle);
T_j: the task's period, or for an aperiodic task its minimum inter-arrival time (the worst case).
Consts (in-const, out-const) move once around `init`, not per cycle, and do not count. A
configuration loads the bus with

    B = Σ_j Z_j                                                                    (eq. 2)

which must stay below the backplane's bandwidth (`bus: {bandwidth: ...}`). What a run measured
beside it, combined modules' saving and the report's forms are `analysis.bus`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pbo_runtime.config.model import PortBinding, Subsystem, TaskSpec
from pbo_runtime.errors import PboError
from pbo_runtime.objects.ports import PortKind

__all__ = [
    "LOCKS_PER_CYCLE",
    "PER_CYCLE_IN",
    "PER_CYCLE_OUT",
    "BusModelError",
    "BusReport",
    "TaskLoad",
    "bus_report",
    "interval_of",
    "members_of",
    "over_bandwidth",
    "predict",
    "predict_all",
    "task_load",
    "transfer_bytes",
]

PER_CYCLE_IN = (PortKind.IN_VAR, PortKind.IN_BOTH)
PER_CYCLE_OUT = (PortKind.OUT_VAR, PortKind.OUT_BOTH)
LOCKS_PER_CYCLE = 2  # one lock for all inputs, one for all outputs (a single lock for the whole table)


class BusModelError(PboError, ValueError):
    """The bus model cannot be evaluated as asked: the message names the configuration or task."""


@dataclass(frozen=True)
class TaskLoad:
    """One task's term of eq. 1. Sizes are bytes per cycle; `period` is T_j in seconds."""

    task: str
    rtpu: str
    period: float  # T_j: the period, or the minimum inter-arrival time of an aperiodic task
    bytes_in: int | None  # Σ S(x_ij); None when a measured report does not split in from out
    bytes_out: int | None  # Σ S(y_ij)
    per_cycle_bytes: float  # Σ S(x_ij) + Σ S(y_ij) + 2Δ
    rate_bytes_per_s: float  # Z_j
    aperiodic: bool = False
    cycles: int | None = None  # measured reports only

    @property
    def lock_bytes(self) -> float:
        """The 2Δ of this task's cycle (bytes)."""
        known = (self.bytes_in or 0) + (self.bytes_out or 0)
        return self.per_cycle_bytes - known if self.bytes_in is not None else math.nan


@dataclass(frozen=True)
class BusReport:
    """Eq. 2 for one configuration: every task's Z_j, their sum B and B's share of the bandwidth."""

    configuration: str
    tasks: tuple[TaskLoad, ...]
    total: float  # B, bytes per second
    bandwidth: float  # bytes per second
    share: float  # B / bandwidth
    lock_overhead: float = 0.0  # Δ, bytes
    kind: str = "predicted"  # or "measured", "combined"
    duration: float | None = None  # measured reports: the run's duration, seconds

    def task(self, name: str) -> TaskLoad:
        for load in self.tasks:
            if load.task == name:
                return load
        raise KeyError(name)

    @property
    def over(self) -> bool:
        return self.total > self.bandwidth


# --- the model ---------------------------------------------------------------------------------


def transfer_bytes(subsystem: Subsystem, binding: PortBinding) -> int:
    """S(v): the bytes one transfer of the bound variable moves (elements of the bound shape x itemsize)."""
    var = subsystem.variables[binding.variable]
    n = 1
    for d in binding.shape:
        n *= int(d)
    return n * _itemsize(var.dtype)


@functools.cache
def _itemsize(dtype: Any) -> int:
    """Bytes per element of a dtype (np.dtype() costs microseconds: once per dtype, not per binding)."""
    return int(np.dtype(dtype).itemsize)


def interval_of(task: TaskSpec) -> tuple[float, bool]:
    """T_j and whether the task is aperiodic (then T_j is its minimum inter-arrival time)."""
    aperiodic = bool(getattr(task, "aperiodic", False))
    interval = getattr(task, "min_interarrival", None) if aperiodic else task.period
    if aperiodic and interval is None:
        raise BusModelError(
            f"task '{task.name}' is aperiodic without a minimum inter-arrival time: its bus load has no bound "
            "(give it 'min_interarrival')"
        )
    if interval is None or not interval > 0:
        what = "minimum inter-arrival time" if aperiodic else "period"
        raise BusModelError(f"task '{task.name}' has {what} {interval!r}: eq. 1 needs a positive time")
    return float(interval), aperiodic


def task_load(subsystem: Subsystem, task: TaskSpec) -> TaskLoad:
    """Z_j of one task (eq. 1), from its bindings; consts are left out (they move once, at init)."""
    bytes_in, bytes_out, per_cycle, interval, aperiodic = _eq1_terms(subsystem, task)
    return TaskLoad(task.name, task.rtpu, interval, bytes_in, bytes_out, per_cycle, per_cycle / interval, aperiodic)


def _eq1_terms(subsystem: Subsystem, task: TaskSpec) -> tuple[int, int, float, float, bool]:
    """The terms of eq. 1: bytes in, bytes out, bytes per cycle, T_j, and whether the task is aperiodic."""
    bytes_in = sum(transfer_bytes(subsystem, b) for b in task.bindings if b.port.kind in PER_CYCLE_IN)
    bytes_out = sum(transfer_bytes(subsystem, b) for b in task.bindings if b.port.kind in PER_CYCLE_OUT)
    interval, aperiodic = interval_of(task)
    per_cycle = bytes_in + bytes_out + LOCKS_PER_CYCLE * subsystem.bus.lock_overhead
    return bytes_in, bytes_out, per_cycle, interval, aperiodic


def _rate(subsystem: Subsystem, task: TaskSpec) -> float:
    """Z_j alone, as task_load computes it (without making the TaskLoad)."""
    _, _, per_cycle, interval, _ = _eq1_terms(subsystem, task)
    return per_cycle / interval


def bus_report(subsystem: Subsystem, configuration: str, loads: Iterable[TaskLoad], kind: str,
               duration: float | None = None) -> BusReport:
    """Eq. 2 over `loads`: their sum B and its share of the subsystem's bandwidth."""
    loads = tuple(loads)
    total = float(sum(load.rate_bytes_per_s for load in loads))
    bandwidth = float(subsystem.bus.bandwidth)
    share = total / bandwidth if bandwidth > 0 else math.inf
    return BusReport(configuration, loads, total, bandwidth, share, float(subsystem.bus.lock_overhead), kind, duration)


def members_of(subsystem: Subsystem, configuration: str) -> tuple[str, ...]:
    """The tasks of `configuration`; BusModelError names the configurations there are."""
    try:
        return subsystem.configurations[configuration].tasks
    except KeyError:
        known = ", ".join(subsystem.configurations) or "none"
        raise BusModelError(f"no configuration '{configuration}' in {subsystem.file} (configurations: {known})") from None


def predict(subsystem: Subsystem, configuration: str) -> BusReport:
    """B of one configuration (eq. 2), every task's Z_j (eq. 1), and B's share of the bandwidth."""
    names = members_of(subsystem, configuration)
    return bus_report(subsystem, configuration, (task_load(subsystem, subsystem.tasks[n]) for n in names), "predicted")


def predict_all(subsystem: Subsystem) -> dict[str, BusReport]:
    """`predict` for every configuration, in file order."""
    return {name: predict(subsystem, name) for name in subsystem.configurations}


def over_bandwidth(subsystem: Subsystem) -> list[tuple[str, BusReport]]:
    """The configurations whose predicted B exceeds the bus bandwidth, in file order.

    `pbo check` asks this of every file, and most configurations fit: B is summed from the
    tasks' Z_j alone (the same sum as `predict`'s), and the full report is made only for those over.
    """
    bandwidth = float(subsystem.bus.bandwidth)
    over = []
    for name in subsystem.configurations:
        total = float(sum(_rate(subsystem, subsystem.tasks[n]) for n in members_of(subsystem, name)))
        if total > bandwidth:
            over.append((name, predict(subsystem, name)))
    return over
