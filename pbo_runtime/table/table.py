"""The global state variable table in POSIX shared memory, behind one lock (TR §4.2).

Layout of the segment, all offsets multiples of 8 bytes:

    header        HEADER_WORDS int64: magic, version, layout hash, flags, the lock record, ...
    directory     one DIRECTORY_RECORD per variable: name, dtype, shape, offsets (for tools: `table.directory`)
    manifest      names of every object of the run and the pids of its processes (`pid <pid> <role>`), so a
                  later run can clean up after a crash, and leaves a run alone while any of them lives
    variables     per variable: 3 float64 metadata words (writer, sequence, write time) + data
    task status   STATUS_WORDS float64 per task: state, cycles, overruns, timing counters
    devices       DEVICE_HOLDERS records of HOLDER_WORDS uint64 per device: who holds which channels
                  (the device database, TR §4.6.1: see `table.devices`; read and written under the lock)

A variable's metadata says who wrote it last. When the writer is a task (index >= 0), the
value's sequence number and write time are that task's cycle count and release time in its
status block, which the task writes in the same locked scatter as the value itself, so the
three always agree and a cycle stamps nothing extra. When the writer is job control (-1), the
variable's own sequence and time words hold them.

A task never touches the table directly: `TransferPlan` (built once at spawn) gathers its
inputs into its local table with one `take` per dtype and scatters its outputs with one
fancy assignment per dtype, each under the single lock, so a cycle costs two lock pairs and a
handful of C calls whatever the table's size.

Only RTPUs and job control's writes take the lock. Observers (`pbo svar`, `pbo status`, job
control's reads) copy without it under the seqlock of the lock record (`table.snapshot`): every
write under the lock makes `Header.LOCK_SEQUENCE` odd first and even after.
"""

from __future__ import annotations

import contextlib
import enum
import hashlib
import mmap
import os
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import posix_ipc
from numpy.typing import ArrayLike

from pbo_runtime.config.model import Subsystem, VariableSpec
from pbo_runtime.errors import InternalError, TableLayoutError
from pbo_runtime.ipc.segment import LockedSegment, MissingLockError
from pbo_runtime.table.directory import DIRECTORY_RECORD, DTYPE_CODES, META_WORDS, Entry, write_directory
from pbo_runtime.table.snapshot import Seqlock

MAGIC = 0x5042_4F5F_5441_424C  # "PBO_TABL"
VERSION = 2  # 2: the lock record's sequence word (observers read without the lock)
HEADER_WORDS = 64
MANIFEST_BYTES = 8192  # names of up to 32 RTPUs with the simulated clock's semaphores, and the pids of the run's processes
# META_WORDS (`table.directory`): writer task index (-1: job control), then job control's sequence and write time
STATUS_WORDS = 16  # per task in the table (room to grow without a layout change)
# Status blocks reserved beyond the file's tasks for tasks spawned while the subsystem runs (`pbo
# spawn`, `pbo replace`): the layout is fixed when the run starts, so a live change takes a free
# block, and one past them is refused (docs/live.md). A killed task's block is free again.
SPARE_TASK_SLOTS = 8
DEVICE_HOLDERS = 8  # per device: how many opens of it (by tasks, or through a sensor's io:) may be held at once
HOLDER_WORDS = 5  # per holder record, uint64: see `Holder`


class Holder(enum.IntEnum):
    """Word indices in a holder record of the device region; a record with TASK 0 is free."""

    TASK = 0  # the holding task's index + 1
    PID = 1  # the process (RTPU) that opened it: a dead one's records are recovered
    MASK = 2  # the channels held, bit c for channel c (0: no channel locked, a device that is not port-based)
    EXCLUSIVE = 3  # 1: the device is exclusive, nobody else may hold it
    OPENED = 4  # index + 1 of the device the task opened (differs for a claim through a sensor's io:)


class Header(enum.IntEnum):
    """Word indices in the int64 header."""

    MAGIC = 0
    VERSION = 1
    LAYOUT_HASH = 2
    FLAGS = 3
    LOCK_HOLDER = 4  # the lock record: the pid of the lock's last holder, written after every acquire
    N_VARIABLES = 5
    N_TASKS = 6
    SUPERVISOR_PID = 7
    RELEASE_EPOCH_NS = 8  # real clock: the CLOCK_MONOTONIC ns RTPU i releases at, plus i x stagger + k x period
    DIRECTORY_OFFSET = 9
    MANIFEST_OFFSET = 10
    DATA_OFFSET = 11
    STATUS_OFFSET = 12
    TOTAL_BYTES = 13
    LOCK_RECOVERIES = 14  # times job control released a lock whose holder died
    LOCK_SEQUENCE = 15  # the seqlock: odd while a writer holding the lock writes (`table.snapshot`)
    # Dynamic reconfiguration (TR 4.4): job control posts a plan, every executive applies it at
    # its first cycle boundary at or after the activation time.
    PLAN_SEQUENCE = 16  # incremented for each new plan
    PLAN_TIME_NS = 17  # activation time, CLOCK_MONOTONIC nanoseconds
    PLAN_CONFIGURATION = 18  # index of the configuration to switch to (file order)
    TASKS_IN_ERROR = 19  # set by job control: critical tasks run locally stable while > 0
    # Simulated clock (--clock sim): the supervisor advances time in ticks; every participant reads it here.
    SIM_TIME_NS = 20  # the current tick's time, nanoseconds from the run's start
    SIM_TICK = 21  # ticks released so far: a participant stepped with no new tick only serves its signals
    SIM_TICK_NS = 22  # the tick's length, nanoseconds: the participant that ends a tick may begin the next
    SIM_RING_END = 23  # the last tick of the turns the participants pass among themselves (0: each returns to job control)
    SWITCHING_SINCE_NS = 24  # one word per RTPU (up to MAX_RTPUS): when its switch began, 0 if none
    SIM_TURN = 24 + 32  # (after the switching words) the place in the tick of the participant running, for a slow tick's report
    TASKS_NOT_FRESH = 57  # set by job control: tasks whose cycle says their inputs are not fresh (a link's item
    # past its bound); critical tasks run locally stable while > 0, as for TASKS_IN_ERROR, and resume by themselves


MAX_RTPUS = 32


class Flag(enum.IntFlag):
    ILLEGAL_CONFIGURATION = 1  # a task of the configuration is in ERROR, or a task's stable episode is open (job control)
    STOPPING = 2  # job control is stopping the run: RTPUs run no more cycles
    STATIC_SWITCH = 4  # job control is killing and spawning tasks: critical tasks hold until it is done
    SIM_CLOCK = 8  # the run's clock is simulated (--clock sim): its times are SIM_TIME_NS, from the first tick on


class StatusWord(enum.IntEnum):
    """Word indices in a task's float64 status block."""

    STATE = 0
    CYCLES = 1
    OVERRUNS = 2
    EXEC_LAST = 3  # seconds
    EXEC_MAX = 4
    JITTER_LAST = 5  # release lateness, seconds
    JITTER_MAX = 6
    RELEASE = 7  # the release time of the last cycle, clock seconds: its outputs' write time
    ERRORS = 8
    USED = 9  # words in use: only these travel with each cycle's outputs
    # Written by the executive straight into the table (one writer, aligned words), never with
    # the outputs: the count of missed releases as it changes, the rest every RECENT cycles (what
    # `pbo status` shows of the recent cycles).
    MISSED = 10  # releases skipped: after overruns, or while the table lock was held past the cycle's wait
    JITTER_P50 = 11  # over the last RECENT cycles, seconds
    JITTER_P99 = 12
    EXEC_P50 = 13
    EXEC_P99 = 14
    # Lock acquisitions (2 per cycle) and bytes moved (cycles x the task's bytes per cycle) are
    # exact functions of CYCLES: the bus report derives them instead of counting every cycle.


class TaskState(enum.IntEnum):
    """Figure 11's states; the number is what the status block holds."""

    NOT_CREATED = 0
    CREATED = 1
    OFF = 2
    ON = 3
    ERROR = 4
    KILLED = 5


@dataclass(frozen=True)
class VariableSlot:
    """Where one variable lives in the segment."""

    name: str
    index: int
    dtype: np.dtype
    shape: tuple[int, ...]
    meta_word: int  # float64 word index of its 3 metadata words
    data_byte: int  # byte offset of its data (8-byte aligned)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    @property
    def data_index(self) -> int:
        """Index of its first element in a whole-segment view of its dtype."""
        return self.data_byte // self.dtype.itemsize


@dataclass(frozen=True)
class TableLayout:
    """Byte layout of a subsystem's table: a pure function of its variables and tasks."""

    slots: tuple[VariableSlot, ...]
    n_tasks: int
    directory_offset: int
    manifest_offset: int
    data_offset: int
    status_offset: int
    total_bytes: int
    layout_hash: int
    devices_offset: int = 0  # the device database's region, after the task status blocks
    n_devices: int = 0

    @classmethod
    def of(cls, subsystem: Subsystem) -> TableLayout:
        """The run's layout: the file's tasks and SPARE_TASK_SLOTS more status blocks for live spawns."""
        return cls.build(subsystem.variables.values(), task_slots(subsystem), len(subsystem.devices))

    @classmethod
    def build(cls, variables: Iterable[VariableSpec], n_tasks: int, n_devices: int = 0) -> TableLayout:
        variables = list(variables)
        directory = HEADER_WORDS * 8
        manifest = directory + DIRECTORY_RECORD * len(variables)
        cursor = manifest + MANIFEST_BYTES
        data = cursor
        slots = []
        for index, var in enumerate(variables):
            dtype = np.dtype(var.dtype)
            if dtype.name not in DTYPE_CODES:
                raise TableLayoutError(f"variable '{var.name}': dtype {dtype.name} cannot live in the table")
            meta_word = cursor // 8
            cursor += META_WORDS * 8
            data_byte = cursor
            nbytes = int(np.prod(var.shape, dtype=np.int64)) * dtype.itemsize
            cursor += -(-nbytes // 8) * 8
            slots.append(VariableSlot(var.name, index, dtype, tuple(var.shape), meta_word, data_byte))
        status = cursor
        devices = status + STATUS_WORDS * 8 * max(n_tasks, 1)
        total = devices + DEVICE_HOLDERS * HOLDER_WORDS * 8 * n_devices
        digest = hashlib.blake2b(digest_size=8)
        for s in slots:
            digest.update(f"{s.name}|{s.dtype.name}|{s.shape}|{s.meta_word}|{s.data_byte};".encode())
        digest.update(f"tasks={n_tasks}".encode())
        if n_devices:
            digest.update(f"devices={n_devices}x{DEVICE_HOLDERS}x{HOLDER_WORDS}".encode())
        layout_hash = int.from_bytes(digest.digest(), "little", signed=True)
        return cls(tuple(slots), n_tasks, directory, manifest, data, status, total, layout_hash, devices, n_devices)

    def slot(self, name: str) -> VariableSlot:
        for s in self.slots:
            if s.name == name:
                return s
        raise KeyError(name)


def task_slots(subsystem: Subsystem) -> int:
    """Status blocks a run of `subsystem` has: its file's tasks (a live subsystem's highest index + 1) and the spares."""
    return max((task.index for task in subsystem.tasks.values()), default=-1) + 1 + SPARE_TASK_SLOTS


LOCK_WORDS: dict[str, Any] = {"holder_word": int(Header.LOCK_HOLDER), "recoveries_word": int(Header.LOCK_RECOVERIES),
                              "sequence_word": int(Header.LOCK_SEQUENCE)}  # the segment's lock record


def copy_variable(value: np.ndarray, words: np.ndarray, meta_word: int, status: np.ndarray) -> tuple[np.ndarray, int, float, int]:
    """(copy of `value`, sequence, write time, writer task index) from the table's words, unchecked.

    A task writer's sequence and write time are its status block's cycle count and release
    (see the module's docstring). Read it inside `Seqlock.read`; a torn copy raises nothing.
    """
    copy = value.copy()
    writer, seq, when = (float(w) for w in words[meta_word : meta_word + META_WORDS])
    if 0 <= writer < len(status):
        seq = float(status[int(writer)][StatusWord.CYCLES])
        when = float(status[int(writer)][StatusWord.RELEASE])
    return copy, int(seq), when, int(writer)


class StateTable:
    """One mapping of the table. The supervisor creates it; RTPUs and tools attach to it."""

    def __init__(self, layout: TableLayout, segment: LockedSegment) -> None:
        self.layout = layout
        self.name = segment.name
        self.lock_name = segment.lock_name
        self._segment = segment
        self._mapping = mapping = segment.mapping
        self.lock = segment.lock  # the transfers bind its acquire and release once (`task.transfer`)
        self.lock_words = segment.words  # the lock record (int64 memoryview): holder, recoveries, sequence
        self.seqlock = Seqlock(segment.words, int(Header.LOCK_SEQUENCE), segment.name)
        # How this process waits for the lock: None blocks (an RTPU); job control sets a bounded
        # wait that looks after the holder meanwhile (`supervisor.lock_watch`).
        self.lock_wait: Callable[[], None] | None = None
        # A process at SCHED_OTHER that takes the lock (job control) holds it at this SCHED_FIFO
        # priority (a priority ceiling): no ordinary process preempts it while the RTPUs wait. None: as it runs.
        self.lock_ceiling: int | None = None
        self._raised: int | None = None  # the thread raised to the ceiling for this hold (native id)
        # How long a task's per-cycle transfer waits for the lock, in seconds (None: as long as it
        # takes). An RTPU hosting a critical task on the real clock bounds it, so that a lock a
        # dying process holds costs a cycle's stable behaviour, not missed releases (the executive
        # sets it; the transfers read it through this one-element list, set once per turn-on).
        self.cycle_lock_wait: list[float | None] = [None]
        self.header = np.frombuffer(mapping, dtype=np.int64, count=HEADER_WORDS)
        self._views = {
            code: np.frombuffer(mapping, dtype=code, count=layout.total_bytes // np.dtype(code).itemsize) for code in DTYPE_CODES
        }
        self.words = self._views["float64"]
        status = layout.status_offset // 8
        self.status = self.words[status : status + STATUS_WORDS * max(layout.n_tasks, 1)].reshape(-1, STATUS_WORDS)
        first = layout.devices_offset // 8
        self.devices = self._views["uint64"][first : first + layout.n_devices * DEVICE_HOLDERS * HOLDER_WORDS].reshape(
            layout.n_devices, DEVICE_HOLDERS, HOLDER_WORDS)
        self._pid = os.getpid()

    # --- life -------------------------------------------------------------------------------

    @property
    def owner(self) -> bool:
        """True for the creator, whose close unlinks the segment and the lock."""
        return self._segment.owner

    @owner.setter
    def owner(self, owner: bool) -> None:
        self._segment.owner = owner

    @classmethod
    def create(cls, layout: TableLayout, name: str, manifest: Iterable[str] = ()) -> StateTable:
        """Create the segment and its lock (both 0600, both new) and fill the header."""
        table = cls(layout, LockedSegment.create(name, layout.total_bytes, **LOCK_WORDS))
        h = table.header
        h[Header.VERSION] = VERSION
        h[Header.LAYOUT_HASH] = layout.layout_hash
        h[Header.N_VARIABLES] = len(layout.slots)
        h[Header.N_TASKS] = layout.n_tasks
        h[Header.SUPERVISOR_PID] = os.getpid()
        h[Header.RELEASE_EPOCH_NS] = 0
        h[Header.DIRECTORY_OFFSET] = layout.directory_offset
        h[Header.MANIFEST_OFFSET] = layout.manifest_offset
        h[Header.DATA_OFFSET] = layout.data_offset
        h[Header.STATUS_OFFSET] = layout.status_offset
        h[Header.TOTAL_BYTES] = layout.total_bytes
        table._write_directory()
        table.set_manifest(manifest)
        for s in layout.slots:
            table.words[s.meta_word] = -1.0  # no writer yet: job control's, sequence 0
        h[Header.MAGIC] = MAGIC  # last: a reader that sees the magic sees a complete header
        return table

    @classmethod
    def attach(cls, layout: TableLayout, name: str) -> StateTable:
        """Attach to a running table; a different layout fails clearly instead of corrupting it."""

        def check(mapping: mmap.mmap | memoryview) -> None:
            header = np.frombuffer(mapping, dtype=np.int64, count=HEADER_WORDS)
            magic, version, found_hash, total = (
                int(header[i]) for i in (Header.MAGIC, Header.VERSION, Header.LAYOUT_HASH, Header.TOTAL_BYTES)
            )
            del header  # no view may outlive a mapping the segment closes
            if magic != MAGIC or version != VERSION:
                raise TableLayoutError(f"'{name}' is not a pbo state variable table of version {VERSION}")
            if found_hash != layout.layout_hash or total != layout.total_bytes:
                raise TableLayoutError(
                    f"table '{name}' has another variable layout (hash {found_hash:#x}, this process expects "
                    f"{layout.layout_hash:#x}): was the YAML file changed after the run started?"
                )

        try:
            segment = LockedSegment.attach(name, check=check, **LOCK_WORDS)
        except MissingLockError:
            raise  # the segment is there: say so, not that the run is missing
        except posix_ipc.ExistentialError:
            raise TableLayoutError(f"no state variable table '{name}': is the subsystem running?") from None
        return cls(layout, segment)

    def close(self) -> None:
        """Unmap (and, for the creator, unlink the segment and the lock)."""
        self.header = self.words = self.status = self.devices = self.lock_words = None  # type: ignore[assignment]
        self._views = {}
        self._segment.close()

    def unlink(self) -> None:
        self._segment.unlink()

    # --- directory and manifest -------------------------------------------------------------

    def _write_directory(self) -> None:
        entries = (Entry(s.name, s.dtype, s.shape, s.meta_word, s.data_byte, s.nbytes) for s in self.layout.slots)
        write_directory(self._mapping, self.layout.directory_offset, entries)

    def set_manifest(self, names: Iterable[str]) -> None:
        text = "\n".join(names).encode()
        if len(text) >= MANIFEST_BYTES:
            raise InternalError(f"run manifest of {len(text)} bytes does not fit {MANIFEST_BYTES}")
        raw = np.frombuffer(self._mapping, dtype=np.uint8, count=self.layout.total_bytes)
        start = self.layout.manifest_offset
        raw[start : start + MANIFEST_BYTES] = 0
        raw[start : start + len(text)] = np.frombuffer(text, dtype=np.uint8)

    def manifest(self) -> list[str]:
        return read_manifest(self._mapping, self.layout.manifest_offset)

    # --- the lock ---------------------------------------------------------------------------

    def acquire(self) -> None:
        """Take the lock (as `lock_wait` says) and sign the holder word; a write must also `begin_write`."""
        raised = _raise_to(self.lock_ceiling) if self.lock_ceiling is not None else None
        try:
            if self.lock_wait is None:
                self.lock.acquire()
            else:
                self.lock_wait()
        except BaseException:
            _lower(raised)
            raise
        self._raised = raised  # (under the lock: one holder at a time)
        self.lock_words[Header.LOCK_HOLDER] = self._pid

    def release(self) -> None:
        raised, self._raised = self._raised, None
        self.lock.release()
        _lower(raised)

    def begin_write(self) -> int:
        """Under the lock, before a write observers may read: the sequence odd (`LockedSegment.begin_write`)."""
        return self._segment.begin_write()

    def end_write(self, before: int) -> None:
        self._segment.end_write(before)

    @property
    def writer_tag(self) -> int:
        """The odd sequence this process's writes show while they write (2 pid + 1)."""
        return self._segment.writer_tag

    @property
    def lock_held(self) -> bool:
        return self._segment.held

    @property
    def lock_holder(self) -> int:
        """The pid holding the lock, or that last held it (a writer's while the sequence is odd)."""
        return self._segment.holder

    @property
    def lock_sequence(self) -> int:
        return self._segment.sequence

    def acquire_watching(self, slice_seconds: float, while_waiting: Callable[[], None]) -> None:
        """Job control's wait for the lock: see `LockedSegment.acquire_watching`."""
        self._segment.acquire_watching(slice_seconds, while_waiting)

    def recover_lock_from(self, dead_pid: int, settle: float = 0.05) -> bool:
        """Release the lock if `dead_pid` died holding it; True if it was released."""
        return self._segment.recover_lock_from(dead_pid, settle)

    @property
    def flags(self) -> Flag:
        return Flag(int(self.header[Header.FLAGS]))

    def set_flag(self, flag: Flag, on: bool = True) -> None:
        """Job control is the only writer of the flags, one aligned word: it takes no lock (see `announce_stop`)."""
        value = int(self.header[Header.FLAGS])
        self.header[Header.FLAGS] = (value | flag) if on else (value & ~flag)

    def announce_stop(self) -> None:
        """Tell every RTPU at once that the run is over, before any is sent its stop signal.

        Job control is the only writer of the flags, so this takes no lock: a wedged lock cannot
        hold up a stop. Otherwise RTPUs stopped first would do their stop work (killing tasks,
        percentiles) while the others still run cycles, which would overrun for want of a CPU:
        overruns of the shutdown, counted as the run's.
        """
        self.header[Header.FLAGS] = int(self.header[Header.FLAGS]) | Flag.STOPPING

    # --- whole-variable access (job control and tools; never per cycle) ---------------------

    def view(self, name: str) -> np.ndarray:
        """A live view of a variable's data in the table (copy it inside `seqlock.read`, or under the lock)."""
        s = self.layout.slot(name)
        return self._views[s.dtype.name][s.data_index : s.data_index + s.size].reshape(s.shape)

    def read(self, name: str) -> tuple[np.ndarray, int, float, int]:
        """(copy of the value, sequence, write time, writer task index), lock-free (TableBusy if it stays busy)."""
        s = self.layout.slot(name)
        view, words, status = self.view(name), self.words, self.status
        return self.seqlock.read(lambda: copy_variable(view, words, s.meta_word, status))

    def status_blocks(self) -> np.ndarray:
        """A lock-free copy of every task's status block (TableBusy if the table stays busy)."""
        return self.seqlock.read(self.status.copy)

    def write(self, name: str, value: ArrayLike, when: float, writer: int = -1) -> None:
        """Write a whole variable as job control (writer -1) would: under the lock, stamped."""
        s = self.layout.slot(name)
        view = self.view(name)
        source = np.asarray(value, dtype=s.dtype)
        if source.shape != s.shape and source.size != s.size:
            raise ValueError(f"variable '{name}' has shape {s.shape}, got a value of shape {source.shape}")
        self.acquire()
        try:
            before = self.begin_write()
            try:
                view[...] = source.reshape(s.shape)
                self.words[s.meta_word] = writer
                self.words[s.meta_word + 1] += 1
                self.words[s.meta_word + 2] = when
            finally:
                self.end_write(before)
        finally:
            self.release()

    def dtype_view(self, dtype: np.dtype) -> np.ndarray:
        return self._views[np.dtype(dtype).name]


def _raise_to(priority: int) -> int | None:
    """This thread to SCHED_FIFO `priority` if it runs SCHED_OTHER; its native id if it was raised."""
    thread = threading.get_native_id()
    try:
        if os.sched_getscheduler(thread) & ~os.SCHED_RESET_ON_FORK != os.SCHED_OTHER:
            return None  # (already real time: an executive, a helper)
        os.sched_setscheduler(thread, os.SCHED_FIFO, os.sched_param(priority))
    except OSError:
        return None  # SCHED_FIFO refused: it holds the lock as it runs
    return thread


def _lower(thread: int | None) -> None:
    if thread is not None:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(thread, os.SCHED_OTHER, os.sched_param(0))


def read_manifest(mapping: mmap.mmap, offset: int) -> list[str]:
    raw = bytes(mapping[offset : offset + MANIFEST_BYTES]).split(b"\0", 1)[0]
    return [line for line in raw.decode(errors="replace").split("\n") if line]
