"""`pbo svar`: read a running subsystem's state variables from its table, without the YAML file.

The table describes itself (`table.table`): its header gives the offsets, and the variable directory
one 128-byte record per variable (name, dtype, shape, metadata word, data offset, size), so an
operator's tool needs only the live run's name (`ipc.control.find_live_run`). It maps the segment
read-only and never takes the table lock: it copies under the table's seqlock (`table.snapshot`),
so a reader stopped or killed by the operator cannot wedge the run, and a table whose writer
stopped mid-write is reported as busy instead of hanging the reader.

The layout hash cannot be checked without the YAML file; the magic, the version and the
directory's own consistency (offsets inside the segment, sizes matching shapes) are.
"""

from __future__ import annotations

import math
import mmap
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import posix_ipc
from rich.table import Table

from pbo_runtime.errors import TableLayoutError
from pbo_runtime.ipc.control import find_live_run
from pbo_runtime.ipc.segment import LockedSegment, MissingLockError
from pbo_runtime.table.directory import Entry, read_directory
from pbo_runtime.table.snapshot import Seqlock
from pbo_runtime.table.table import (
    HEADER_WORDS,
    LOCK_WORDS,
    MAGIC,
    STATUS_WORDS,
    VERSION,
    Flag,
    Header,
    StatusWord,
    TaskState,
    copy_variable,
)


class TableView:
    """A read-only mapping of a live run's table, described by its own header and directory."""

    def __init__(self, subsystem: str, run_id: str, segment: LockedSegment) -> None:
        self.subsystem = subsystem
        self.run_id = run_id
        self.name = name = segment.name
        self._segment = segment
        self._seqlock = Seqlock(segment.words, int(Header.LOCK_SEQUENCE), name)
        mapping = segment.mapping
        header = np.frombuffer(mapping, dtype=np.int64, count=HEADER_WORDS)
        self.supervisor_pid = int(header[Header.SUPERVISOR_PID])
        self.n_tasks = int(header[Header.N_TASKS])
        self._entries = read_directory(name, mapping, int(header[Header.N_VARIABLES]), int(header[Header.DIRECTORY_OFFSET]),
                                       int(header[Header.TOTAL_BYTES]), HEADER_WORDS * 8)
        status_offset = int(header[Header.STATUS_OFFSET])
        total = int(header[Header.TOTAL_BYTES])
        del header
        blocks = max(self.n_tasks, 1)
        if self.n_tasks < 0 or status_offset < HEADER_WORDS * 8 or status_offset + blocks * STATUS_WORDS * 8 > total:
            raise TableLayoutError(f"table '{name}': its {self.n_tasks} task status blocks at byte {status_offset} "
                                   f"lie outside the segment")
        self._words = np.frombuffer(mapping, dtype=np.float64, count=total // 8)
        self._status = self._words[status_offset // 8 : status_offset // 8 + blocks * STATUS_WORDS].reshape(blocks, STATUS_WORDS)
        self._values = {
            e.name: np.frombuffer(mapping, dtype=e.dtype, count=e.nbytes // e.dtype.itemsize, offset=e.data_byte).reshape(e.shape)
            for e in self._entries.values()
        }

    def variables(self) -> list[str]:
        """The variables' names, in table order."""
        return list(self._entries)

    def entry(self, name: str) -> Entry:
        try:
            return self._entries[name]
        except KeyError:
            raise KeyError(f"no variable '{name}' in the table of '{self.subsystem}' "
                           f"(variables: {', '.join(self._entries)})") from None

    def read(self, name: str) -> tuple[np.ndarray, int, float, int]:
        """(copy of the value, sequence, write time, writer task index; -1: job control), lock-free.

        TableBusy if a writer keeps the table mid-write through every try (`table.snapshot`).
        """
        e = self.entry(name)
        view, words, status = self._values[name], self._words, self._status
        return self._seqlock.read(lambda: copy_variable(view, words, e.meta_word, status))

    def now(self) -> float:
        """The run's clock now, in the seconds its write times are in: the current tick of a
        `--clock sim` run (0 before its first), else CLOCK_MONOTONIC."""
        header = self._words[:HEADER_WORDS].view(np.int64)
        if int(header[Header.FLAGS]) & Flag.SIM_CLOCK or int(header[Header.SIM_TICK]) > 0:
            return int(header[Header.SIM_TIME_NS]) / 1e9
        return time.monotonic()

    def age(self, name: str, now: float | None = None) -> float:
        """Seconds since the variable was last written, on the run's clock (`now`); inf if it never was."""
        _value, seq, when, writer = self.read(name)
        stamp = _write_time(seq, when, writer)
        if stamp is None:
            return math.inf
        return (self.now() if now is None else now) - stamp

    def task_status(self) -> list[dict[str, Any]]:
        """Each task's status block by table index: state, cycles, overruns, timings in seconds."""
        blocks = self._seqlock.read(self._status[: self.n_tasks].copy)
        rows = []
        for index, words in enumerate(blocks):
            state = int(words[StatusWord.STATE])
            rows.append({
                "index": index,
                "state": TaskState(state).name if state in TaskState._value2member_map_ else str(state),
                "cycles": int(words[StatusWord.CYCLES]), "overruns": int(words[StatusWord.OVERRUNS]),
                "exec_last": float(words[StatusWord.EXEC_LAST]), "exec_max": float(words[StatusWord.EXEC_MAX]),
                "jitter_last": float(words[StatusWord.JITTER_LAST]), "jitter_max": float(words[StatusWord.JITTER_MAX]),
                "release": float(words[StatusWord.RELEASE]), "errors": int(words[StatusWord.ERRORS]),
            })
        return rows

    def close(self) -> None:
        self._values = {}
        self._words = self._status = None  # type: ignore[assignment]
        self._segment.close()  # an array a caller kept still points into the mapping: it goes with it

    def __enter__(self) -> TableView:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def open_table(subsystem: str | None = None, run: str | None = None) -> TableView:
    """Attach read-only to the table of the live run meant by `subsystem` and `run` (or of the only live run)."""
    sub, run_id, name = find_live_run(subsystem, run)
    return attach(name, sub, run_id)


def attach(name: str, subsystem: str = "", run_id: str = "") -> TableView:
    """Attach read-only to the table segment `name`, checking that it is a table this code can read."""

    def check(mapping: mmap.mmap | memoryview) -> None:
        if len(mapping) < HEADER_WORDS * 8:
            raise TableLayoutError(f"'{name}' ({len(mapping)} bytes) is too small to be a pbo state variable table")
        header = np.frombuffer(mapping, dtype=np.int64, count=HEADER_WORDS)
        magic, version, total = int(header[Header.MAGIC]), int(header[Header.VERSION]), int(header[Header.TOTAL_BYTES])
        del header  # no view may outlive a mapping the segment closes
        if magic != MAGIC:
            raise TableLayoutError(f"'{name}' is not a pbo state variable table (magic {magic:#x}, expected {MAGIC:#x}); "
                                   f"if its run is starting, try again in a moment")
        if version != VERSION:
            raise TableLayoutError(f"table '{name}' has layout version {version}, this pbo reads version {VERSION}: "
                                   f"use the pbo that started the run")
        if not 0 < total <= len(mapping):
            raise TableLayoutError(f"table '{name}' says it has {total} bytes, its segment has {len(mapping)}")

    try:
        segment = LockedSegment.attach(name, check=check, read_only=True, **LOCK_WORDS)
    except MissingLockError:
        raise TableLayoutError(f"table '{name}' has no lock '{name}.lock': the run has ended") from None
    except posix_ipc.ExistentialError:
        raise TableLayoutError(f"no state variable table '{name}': the run has ended") from None
    try:
        return TableView(subsystem or _part(name, 1), run_id or _part(name, 2), segment)
    except BaseException:
        segment.close()
        raise


def _write_time(seq: int, when: float, writer: int) -> float | None:
    """When the value was written; None if it never was (job control's sequence 0) or a task has no release yet."""
    if writer < 0:
        return when if seq > 0 else None
    return when if when > 0 else None  # a task's `on` transfer precedes its first release


def _part(name: str, index: int) -> str:
    parts = name.lstrip("/").split(".")
    return parts[index] if len(parts) > index else ""


# --- what `pbo svar` shows ------------------------------------------------------------------


def format_value(value: np.ndarray) -> str:
    """A value as text: floats with 4 decimals, integers as they are, long arrays summarised."""
    array = np.asarray(value)
    formatter: Any = {"float_kind": lambda x: f"{x:+.4f}"} if array.dtype.kind == "f" else None
    if array.ndim == 0:
        return formatter["float_kind"](array.item()) if formatter else str(array.item())
    return np.array2string(array, separator=", ", formatter=formatter, max_line_width=10**6, threshold=24, edgeitems=4)


def svar_rows(view: TableView, names: Sequence[str] | None = None, writers: Mapping[int, str] | None = None,
              now: float | None = None) -> list[dict[str, Any]]:
    """One row per variable: name, value (text), sequence, age in ms, writer, written.

    `writers` maps task indexes to names (from the supervisor's `status` reply); without it a
    task shows as "task #3". Job control's writes show as "job control". `written` is False for
    a variable nobody wrote yet (writer "—"); `age_ms` is None when no write time is known.
    """
    rows = []
    for name in names if names else view.variables():
        value, seq, when, writer = view.read(name)
        stamp = _write_time(seq, when, writer)
        age_ms = None if stamp is None else ((view.now() if now is None else now) - stamp) * 1e3
        written = writer >= 0 or seq > 0
        if not written:
            who = "—"
        elif writer < 0:
            who = "job control"
        else:
            who = (writers or {}).get(writer, f"task #{writer}")
        rows.append({"name": name, "value": format_value(value), "sequence": seq, "age_ms": age_ms, "writer": who,
                     "written": written})
    return rows


def svar_table(rows: Sequence[Mapping[str, Any]], title: str | None = None) -> Table:
    table = Table(title=title, title_justify="left")
    table.add_column("variable")
    table.add_column("value")
    table.add_column("seq", justify="right")
    table.add_column("age ms", justify="right")
    table.add_column("writer")
    for row in rows:
        if row["age_ms"] is not None:
            age = f"{row['age_ms']:.1f}"
        elif row.get("written", True):
            age = "—"
        else:
            age = "never"
        table.add_row(row["name"], row["value"], str(row["sequence"]), age, row["writer"])
    return table
