"""Finding this user's live runs: what `pbo runs` lists and how every operator verb picks its run.

A run is its state table, `/dev/shm/pbo.<subsystem>.<pid>-<nonce>.table`, and it is live while its
supervisor (the pid in the run id, started before the table was made: not a reused pid) is. Only
tables this process may trust count (`shm.distrust`: owned by its effective uid, mode 0600): a table
another user planted, however it is named, is neither listed, nor talked to, nor in the way of a
run.

Several runs may be alive at once, of one subsystem too (one without exclusive devices); an
operator names one with `--subsystem NAME` or `--run ID` (a unique prefix of its run id).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pbo_runtime.errors import PboError
from pbo_runtime.ipc import shm

HINT = "pass --run ID (pbo runs lists them)"


class SeveralRuns(PboError):
    """More than one live run could be the one meant (none named, or a subsystem with several runs)."""
REUSE_SLACK = 2.0  # seconds: /proc gives the boot time in whole seconds; a reused pid starts long after


@dataclass(frozen=True)
class LiveRun:
    """One live run of this user, as its table's name and its supervisor's process tell it."""

    subsystem: str
    run_id: str
    pid: int  # the supervisor's
    table: str  # the table segment's POSIX name
    started_at: float | None  # Unix time the supervisor started; None if /proc does not say

    def brief(self) -> str:
        """`run 1234-a1b2c3 (pid 1234, started 10:41:07)`, for messages."""
        started = f", started {time.strftime('%H:%M:%S', time.localtime(self.started_at))}" if self.started_at else ""
        return f"run {self.run_id} (pid {self.pid}{started})"

    def describe(self) -> str:
        """`'puma' run 1234-a1b2c3 (pid 1234, started 10:41:07)`, for messages."""
        return f"'{self.subsystem}' {self.brief()}"

    def to_json(self) -> dict[str, Any]:
        return {"subsystem": self.subsystem, "run_id": self.run_id, "pid": self.pid, "started_at": self.started_at,
                "table": str(shm.SHM_DIR / self.table.lstrip("/"))}


def live_runs(subsystem: str | None = None) -> list[LiveRun]:
    """The live runs of this user (of `subsystem` when given), oldest first."""
    runs = []
    for listed in shm.list_objects(subsystem):
        if listed.kind != "shm" or listed.part != "table" or listed.distrust is not None:
            continue
        if supervisor_alive(listed.pid, listed.name):
            runs.append(LiveRun(listed.subsystem, listed.run_id, listed.pid, listed.name, process_start_time(listed.pid)))
    return sorted(runs, key=lambda r: (r.started_at or 0.0, r.run_id))


def find_run(subsystem: str | None = None, run: str | None = None) -> LiveRun:
    """The one live run meant by `subsystem` and/or `run` (a prefix of a run id); PboError unless exactly one."""
    everything = live_runs()
    listing = "; ".join(r.describe() for r in everything)
    chosen = [r for r in everything if subsystem is None or r.subsystem == subsystem]
    if run is not None:
        chosen = [r for r in chosen if r.run_id.startswith(run)]
    if len(chosen) == 1:
        return chosen[0]
    if not chosen:
        running = f" (running: {listing})" if everything else " (no subsystem is running)"
        if run is not None:
            which = f"run id '{run}'" + (f" of subsystem '{subsystem}'" if subsystem else "")
            raise PboError(f"no live run has {which}{running}")
        if subsystem is not None:
            raise PboError(f"subsystem '{subsystem}' is not running{running}")
        raise PboError("no subsystem is running (no live state variable table of yours in /dev/shm): "
                       "start one with `pbo run FILE`")
    ids = "; ".join(r.describe() for r in chosen)
    if run is not None:
        raise PboError(f"run id '{run}' matches {len(chosen)} live runs: {ids}; give more of the id")
    if len({r.subsystem for r in chosen}) == 1:  # named, or the only subsystem running: only --run can tell them apart
        raise SeveralRuns(f"{len(chosen)} runs of subsystem '{chosen[0].subsystem}' are alive: {ids}; {HINT}")
    raise SeveralRuns(f"{len(chosen)} runs are alive: {ids}; pass --subsystem NAME or --run ID")


def supervisor_alive(pid: int, table: str) -> bool:
    """True while the supervisor that made `table` runs: process `pid` is alive and started before the table was made.

    A dead run's pid may be reused by another process, which started after the table existed:
    that run is dead. (Nothing rewrites a table's ctime after its creation: it is written
    through its mapping only.)
    """
    if not shm.pid_alive(pid):
        return False
    started = process_start_time(pid)
    try:
        made = os.lstat(shm.SHM_DIR / table.lstrip("/")).st_ctime
    except OSError:
        return False  # removed meanwhile: the run ended
    return started is None or started <= made + REUSE_SLACK


def process_start_time(pid: int) -> float | None:
    """When process `pid` started (Unix time), from /proc; None where /proc does not say."""
    try:
        fields = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[-1].split()
        ticks = int(fields[19])  # starttime, the 22nd field; the list starts at the 3rd (state)
        boot = next(int(line.split()[1]) for line in (Path("/proc") / "stat").read_text().splitlines()
                    if line.startswith("btime "))
    except (OSError, ValueError, IndexError, StopIteration):
        return None
    return boot + ticks / os.sysconf("SC_CLK_TCK")
