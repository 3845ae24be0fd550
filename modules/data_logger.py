"""Data logger (TR §4.1: a task that only gathers data): chosen variables, every cycle, to a file.

Its inputs are the variables named in `params.variables` (one in-var each, of the variable's
own dtype and shape). The path's extension picks the format:

- `.mcap` (the default): the format Foxglove and PlotJuggler open. One channel per variable
  (its topic the variable's name), each message one cycle's value as JSON
  (`{"time": 1.25, "value": [..]}`, a JSON schema per channel), at log time the cycle's release
  time on the run's clock; each channel's metadata carries the variable's unit, doc, dtype and
  shape from the YAML, and the file a `pbo-run` metadata record (subsystem, configuration, clock,
  versions, the YAML file) and a `pbo-log` one (the columns, so a log cut short before its first
  chunk still says what it holds). One MCAP chunk (zstd) per chunk of rows.
- `.npy`: one structured numpy array: a row per cycle, a `time` field and one field per
  variable, so `np.load(path)["q_m"]` is the `q_m` column, shaped (rows, *its shape).

`pbo_runtime.read_log(path)` reads either back as that structured array, a log cut short by a
crash included (`pbo_runtime.open_log` adds the units, docs and the run's metadata).

The file is written in chunks as the run goes, so a run of any length keeps every row with
bounded memory, and a killed RTPU loses only the rows since the last chunk written. The cycle
fills one of its chunk buffers preallocated in `init` (it allocates nothing, encodes nothing and
does no I/O); the cycle that fills it hands it to a writer thread (an eventfd write) and goes on
in the other. An `.npy` log's writer appends the chunk in one write, then rewrites the row count
in the header (fixed size: numpy leaves room for the count to grow), so the file is a valid array
after every chunk. An MCAP log's chunks are encoded (JSON, zstd) by a process of its own
(modules/_mcap_encoder.py), which reads the buffers from shared memory: the encoding never holds
the RTPU's GIL, and the writer thread only waits for it with the GIL released. The log is
readable up to its last chunk, and gets its summary and footer when the task is killed. A logger
restarted with its RTPU (a restart policy) continues the run's log: new chunks after the last one
written, the rows of the chunk begun at the death lost. A write
takes microseconds into the page cache, but milliseconds at times when the kernel throttles
write-back: that is why it is not the cycle's, nor `off`'s and `kill`'s, which run between two
cycles of the RTPU's other tasks: `off` hands the chunk begun to the writer, and `kill` hands the
rest (the chunk begun, the MCAP summary and footer, the writer and encoder ended, the file closed)
to the RTPU's background thread (`hand_off`), which the RTPU waits for before it exits.

When both buffers are full (the writer still writes one), a cycle on the real clock drops its
row, counted and reported; on the simulated clock it waits for the writer instead, as the
simulated time does: a log of a simulated run has every row, however slow the disk. There the
cycle has more buffers to fill (`SIM_AHEAD` simulated seconds of rows, within `SIM_BUFFER_BYTES` and
`SIM_BUFFERS`), written in turn: ticks that run faster than real time do not wait for the encoder's start.

A write that fails (disk full, file or directory removed) makes the next cycle raise
`OutputError`: the task goes to ERROR with the OS error, the run's exit status says so, and the
file keeps every row of the chunks written before (an MCAP log keeps the failed chunk's bytes and
writes them first when the task is cleared).
"""

from __future__ import annotations

import _thread
import contextlib
import errno
import importlib.util
import io
import math
import mmap
import os
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from modules._mcap_encoder import McapEncoder, resume_point, write_all
from pbo_runtime import (
    ANY_DTYPE,
    InVar,
    OutputError,
    PortBasedObject,
    PortSpec,
    Status,
    below_the_cycle,
    param,
    read_log,
    sleep_while_cycling,
)

__all__ = ["DataLogger", "DataLoggerParams", "read_log"]

CHUNK_BYTES = 256 * 1024  # the most one cycle writes at once (tens of microseconds into the page cache)
FORMATS = (".mcap", ".npy")
ENCODINGS = ("json", "ros2")
FINISH_PATIENCE = 60.0  # s a logger spawned at a path waits for the one killed before it to end that file
SIM_AHEAD = 16.0  # simulated seconds of rows the cycle may fill ahead of the writer on the simulated clock ...
SIM_BUFFER_BYTES = 4 * 1024 * 1024  # ... in chunk buffers of at most this many bytes in all ...
SIM_BUFFERS = 32  # ... and at most this many (two at least)
# Logs being finished in the background, by path: a logger spawned again at the same path (kill,
# then spawn) waits for the file's end before it replaces it.
_FINISHING: dict[str, threading.Event] = {}


@dataclass(frozen=True)
class DataLoggerParams:
    variables: tuple[str, ...]
    path: str = "log.mcap"  # relative: under the run's output directory
    chunk: float = param(1.0, above=0, at_most=86400)  # seconds of rows written to the file at a time (at most CHUNK_BYTES)
    encoding: str = "json"  # an MCAP log's messages: json (pbo's), or ros2 (CDR, std_msgs MultiArrays, as rosbag2 writes)

    def __post_init__(self) -> None:
        if not self.variables:
            raise ValueError("variables must name at least one variable to log")
        if len(set(self.variables)) != len(self.variables):
            raise ValueError(f"variables must not repeat, got: {list(self.variables)}")
        if "time" in self.variables:
            raise ValueError("variables must not include 'time': the log's time field is the cycle's release time")
        if not self.chunk > 0:
            raise ValueError(f"chunk must be > 0 s, got: {self.chunk}")
        if self.encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {', '.join(ENCODINGS)}, got: {self.encoding!r}")
        if self.encoding == "ros2" and not self.path.endswith(".mcap"):
            raise ValueError(f"encoding ros2 writes an MCAP log: path must end in .mcap, got: {self.path!r}")
        if self.encoding == "ros2" and importlib.util.find_spec("rosbags") is None:
            raise ValueError("encoding ros2 needs the 'ros2' extra (rosbags is not installed): pip install 'pbo-runtime[ros2]'")
        if not self.path.endswith(FORMATS):
            raise ValueError(f"path must end in .mcap (Foxglove, PlotJuggler) or .npy (one numpy structured array), "
                             f"got: {self.path!r}")


class DataLogger(PortBasedObject):
    """Logs chosen variables every cycle; appends them to `path` (.mcap or .npy) a chunk at a time."""

    Params = DataLoggerParams

    @classmethod
    def ports_for(cls, params: DataLoggerParams) -> tuple[PortSpec, ...]:
        extra = tuple(InVar(name, dtype=ANY_DTYPE, shape=None, doc=f"logged variable {name}").spec for name in params.variables)
        named = tuple(
            PortSpec(name, p.kind, p.variable, p.dtype, p.shape, p.doc) for name, p in zip(params.variables, extra, strict=True)
        )
        return cls.ports() + named

    def init(self, params: DataLoggerParams) -> None:
        arrays = self.bound_arrays[-len(params.variables):]
        self._dtype = np.dtype(
            [("time", np.float64)] + [(name, a.dtype, a.shape) for name, a in zip(params.variables, arrays, strict=True)]
        )
        self._rows = max(1, min(round(params.chunk / self.period), CHUNK_BYTES // self._dtype.itemsize))
        # Chunk buffers (two; more on the simulated clock): the cycle fills one while the writer writes
        # the others. An MCAP log's
        # are shared with its encoder process (a memfd: nothing to clean up in /dev/shm). Written
        # now: a row in a page never touched would be faulted in by the cycle that writes it.
        # Each buffer's views are made once.
        mcap = params.path.endswith(".mcap")
        self._wait_when_full = self.run_metadata.get("clock") == "sim"
        chunk_bytes = self._rows * self._dtype.itemsize
        ahead = math.ceil(SIM_AHEAD / (self._rows * self.period)) + 1
        self._count = max(2, min(ahead, SIM_BUFFER_BYTES // chunk_bytes, SIM_BUFFERS)) if self._wait_when_full else 2
        self._shared_fd, self._shared = -1, None
        if mcap:
            size = self._count * chunk_bytes
            self._shared_fd = os.memfd_create(f"pbo-log-{self.task_name}", os.MFD_CLOEXEC)
            os.ftruncate(self._shared_fd, size)
            self._shared = mmap.mmap(self._shared_fd, size)
        sources = [a.reshape(-1) for a in arrays]
        self._buffers = []
        for index in range(self._count):
            if self._shared is not None:
                chunk = np.frombuffer(
                    self._shared, self._dtype, count=self._rows, offset=index * self._rows * self._dtype.itemsize
                )
                chunk.fill(0)
            else:
                chunk = np.full(self._rows, 0, dtype=self._dtype)
            pairs = [(_flat_rows(chunk[name]), source) for name, source in zip(params.variables, sources, strict=True)]
            self._buffers.append((chunk, chunk["time"], pairs))
            sleep_while_cycling(0)  # in a live spawn, the RTPU's due cycles run between the buffers written
        self._current = 0
        self._chunk, self._times, self._pairs = self._buffers[0]
        self.path = self.output_path(params.path)
        before = _FINISHING.get(str(self.path))
        if before is not None and not _ended_within(before, FINISH_PATIENCE):
            raise OutputError(f"cannot create log {self.path}: the logger killed before is still finishing it")
        self.logged = 0  # rows taken, the chunk begun included
        self.dropped = 0  # rows taken while both buffers were full (the disk took longer than a chunk to write one)
        self._filled = 0  # rows of the chunk begun
        # Buffers handed to the writer, and written by it: the writer writes them in the order they
        # were filled, the difference is in its hands; each buffer's rows as handed over
        self._handed = self._written = 0
        self._handed_rows = [0] * self._count
        self._failure = ""  # the writer's OutputError, raised by the next cycle
        self._fd = -1
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # restarted after its RTPU died: the log of the run goes on where it was cut
            resume = self.restarted and self.path.exists()
            self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | (0 if resume else os.O_TRUNC), 0o644)
            if mcap:
                columns = {name: self.variable_note(name) for name in params.variables}
                resume_at = resume_point(self._fd) if resume else None
                if resume_at is not None:
                    os.ftruncate(self._fd, resume_at[0])  # a chunk cut short by the death, and any end of data
                setup = {"columns": columns, "run": _with_unix_offset(self.run_metadata), "task": self.task_name,
                         "period": self.period, "encoding": params.encoding,
                         "resume_at": resume_at, "buffers": self._count}
                self._file: _LogFile = _McapProcess(self._fd, self._shared_fd, self._dtype, self._rows, setup)
            else:
                self._file = _NpyFile(self._fd, self._dtype, [chunk for chunk, _, _ in self._buffers], resume)
        except OSError as exc:
            self._close()
            raise OutputError(f"cannot create log {self.path}: {_os_error(exc)}") from None
        self._wake = os.eventfd(0, os.EFD_CLOEXEC)
        self._stopping = False
        self._ready = threading.Event()  # the writer has set the file up (an MCAP log's preamble and encoder)
        self._writer_done = threading.Event()
        self.writer_id = 0  # the writer thread's (threading.get_ident), once it runs
        # Not threading.Thread.start, which waits for the new thread to run: at SCHED_OTHER on a busy
        # machine that can take milliseconds, between two cycles of the RTPU's other tasks. What the
        # cycle hands over before the writer runs waits in the eventfd's count.
        _thread.start_new_thread(self._write_queued, ())

    @property
    def written(self) -> int:
        """Rows in the file (an .npy header's count; an MCAP log's rows of the chunks written)."""
        return self._file.rows

    def cycle(self) -> Status:
        if self._failure:
            raise OutputError(self._failure)
        row = self._filled
        if row == self._rows:  # full, and the writer still has every other buffer
            if self._handed - self._written == self._count - 1:
                if not self._wait_when_full:
                    self.dropped += 1
                    return Status.CONTINUE
                self.wait_for_writer(self._count - 2)
            self._hand_over()
            row = 0
        self._times[row] = self.time
        for column, source in self._pairs:
            column[row] = source
        self._filled = row + 1
        self.logged += 1
        if self._filled == self._rows and self._handed - self._written < self._count - 1:
            self._hand_over()
        return Status.CONTINUE

    def _hand_over(self) -> None:
        """Give the full buffer to the writer and go on in the next: a few stores and one eventfd write."""
        current = self._current
        self._handed_rows[current] = self._filled
        self._handed += 1
        self._current = current = current + 1 if current + 1 < self._count else 0
        self._chunk, self._times, self._pairs = self._buffers[current]
        self._filled = 0
        os.eventfd_write(self._wake, 1)

    def _write_queued(self) -> None:
        """The writer thread: set the file up, then append each buffer handed over; a failure is
        the next cycle's to raise.

        Its time is in system calls (the write; for MCAP, the wait for the encoder process), with
        the GIL released: the executive's thread never waits for it. The write's own time (the
        disk, the kernel's write-back throttling: milliseconds at times) is spent off the cycle.
        An MCAP log's preamble and its encoder process's start are the writer's too."""
        self.writer_id = threading.get_ident()
        below_the_cycle()  # it shares the executive's GIL: never preempted by the machine while it holds it
        try:
            try:
                self._file.start()
            except Exception as exc:
                self._failure = f"cannot create log {self.path}: {_os_error(exc) if isinstance(exc, OSError) else exc}"
            finally:
                self._ready.set()
            self._serve()
        finally:
            self._writer_done.set()

    def _serve(self) -> None:
        while True:
            os.eventfd_read(self._wake)
            if self._stopping:
                return
            while self._written < self._handed:  # (one wake-up may stand for several buffers handed over)
                index = self._written % self._count
                try:
                    self._append(index, self._handed_rows[index])
                except OutputError as exc:
                    self._failure = str(exc)
                except Exception as exc:  # a bug in writing or encoding: said by the next cycle, never a writer gone silent
                    self._failure = f"cannot write log {self.path}: its writer failed: {type(exc).__name__}: {exc}"
                self._written += 1

    def wait_for_writer(self, in_hand: int = 0, patience: float = 30.0) -> None:
        """Until the writer has set the file up and written what it was handed but `in_hand` buffers
        (off, kill and clear write after it: none)."""
        give_up = time.monotonic() + patience
        if not self._ready.wait(patience):
            raise OutputError(f"cannot write log {self.path}: its writer has not set the file up in {patience:g} s")
        while self._handed - self._written > in_hand:
            if time.monotonic() > give_up:
                raise OutputError(f"cannot write log {self.path}: a chunk's write has not returned for {patience:g} s")
            time.sleep(0.001)

    def off(self) -> None:
        """Hand the chunk begun to the writer if it is free (else it goes with the next chunk or at
        kill); never waits for the disk or the encoder: the RTPU's other tasks run on."""
        if self._failure:
            raise OutputError(self._failure)
        if self._filled:
            in_hand = self._handed - self._written
            if in_hand == self._count - 1 and self._wait_when_full:  # the simulated clock waits, as the cycle does
                self.wait_for_writer(self._count - 2)
            if self._handed - self._written < self._count - 1:
                self._hand_over()
        self._raise_if_dropped()

    def kill(self) -> None:
        """The chunk begun, the MCAP summary and footer, the writer and the encoder ended, the file
        closed: handed off to the RTPU's background thread (`hand_off`), so kill returns at once."""
        if getattr(self, "_fd", -1) < 0:
            return
        if not hasattr(self, "_wake"):  # init failed after the file was opened: no writer to end
            self._close()
            return
        rows, self._filled = self._filled, 0
        index = self._current
        path = str(self.path)
        finished = _FINISHING[path] = threading.Event()
        self.hand_off(lambda: self._finish(index, rows, finished), f"finishing log {path}")

    def _finish(self, index: int, rows: int, finished: threading.Event) -> None:
        """In the background thread: write what is left, end the file and let go of everything."""
        try:
            self.wait_for_writer()
            if self._failure:
                raise OutputError(self._failure)
            self._append(index, rows)
            try:
                self._file.finish()
            except OSError as exc:
                raise OutputError(f"cannot finish log {self.path}: {_os_error(exc)}") from None
            self._raise_if_dropped()
        finally:
            self._stopping = True
            os.eventfd_write(self._wake, 1)
            self._writer_done.wait(timeout=5.0)
            os.close(self._wake)
            self._close()
            finished.set()
            if _FINISHING.get(str(self.path)) is finished:
                del _FINISHING[str(self.path)]

    def clear(self) -> bool:
        """After a failed write: back to OFF once the rows kept can be written (space was freed)."""
        self._failure = ""
        try:
            self.write_chunk()
        except OutputError as exc:
            self._failure = str(exc)
            return False
        return True

    def write_chunk(self) -> None:
        """Write the chunk begun now, in this thread, after what the writer had; OutputError if it fails."""
        self.wait_for_writer()
        if self._failure:
            raise OutputError(self._failure)
        rows, self._filled = self._filled, 0
        self._append(self._current, rows)
        self._raise_if_dropped()

    def _raise_if_dropped(self) -> None:
        if self.dropped:
            dropped, self.dropped = self.dropped, 0
            raise OutputError(f"log {self.path}: {dropped} rows dropped: writing a chunk of {self._rows} rows took "
                              "longer than filling one (the disk is too slow for this period)")

    def _append(self, index: int, rows: int) -> None:
        """Append `rows` rows of buffer `index` to the file; OutputError if it fails (the file keeps the chunks before)."""
        if self._fd < 0:
            return
        written = self._file.rows
        try:
            if os.fstat(self._fd).st_nlink == 0:
                raise FileNotFoundError(2, "the file was removed while the run wrote it (its directory deleted?)")
            self._file.append(index, rows)
        except OSError as exc:
            raise OutputError(f"cannot write log {self.path} ({rows} rows after the {written} "
                              f"written): {_os_error(exc)}") from None

    def _close(self) -> None:
        if hasattr(self, "_file"):
            self._file.stop()
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        if self._shared_fd >= 0:
            os.close(self._shared_fd)
            self._shared_fd = -1


def _with_unix_offset(run: Mapping[str, str]) -> dict[str, str]:
    """The run's metadata, on the real clock with `unix_offset_ns`: Unix time minus the run's clock
    (CLOCK_MONOTONIC), which the MCAP log times add, so that ROS tools and Foxglove line the log up with
    other recordings; the messages keep the run's own clock. The simulated clock adds nothing (its
    logs stay the same, byte for byte, from run to run)."""
    found = dict(run)
    if run.get("clock") != "sim":
        found["unix_offset_ns"] = str(time.time_ns() - time.monotonic_ns())
    return found


class _LogFile:
    """A log's format: appends a chunk buffer's rows to the file; `rows` counts those in the file."""

    rows = 0

    def append(self, index: int, rows: int) -> None:
        raise NotImplementedError

    def start(self) -> None:
        """In the writer thread, before the first chunk: what the format sets up."""

    def finish(self) -> None:
        """At the task's kill: what the format writes after the last row."""

    def stop(self) -> None:
        """At the task's kill or a failed init: let go of what the format holds."""


class _NpyFile(_LogFile):
    """One structured array: each chunk appended, then the row count in the header rewritten."""

    def __init__(self, fd: int, dtype: np.dtype, buffers: list[np.ndarray], resume: bool = False) -> None:
        self.fd, self.dtype, self.buffers, self.rows = fd, dtype, buffers, 0
        self.header_bytes = len(self.header(0))
        if resume and self._resume():
            return
        os.ftruncate(fd, 0)
        write_all(fd, self.header(0))

    def _resume(self) -> bool:
        """Go on after the rows the header counts (False: not a log of these columns; it is replaced)."""
        with os.fdopen(os.dup(self.fd), "rb") as file:
            try:
                version = np.lib.format.read_magic(file)
                shape, _, dtype = (np.lib.format.read_array_header_1_0(file) if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0(file))
            except ValueError:
                return False
            if dtype != self.dtype or file.tell() != self.header_bytes or len(shape) != 1:
                return False
        self.rows = int(shape[0])
        os.ftruncate(self.fd, self.header_bytes + self.rows * self.dtype.itemsize)  # no row of a chunk cut short
        return True

    def append(self, index: int, rows: int) -> None:
        if rows == 0:
            return
        committed = self.header_bytes + self.rows * self.dtype.itemsize
        try:
            os.lseek(self.fd, committed, os.SEEK_SET)
            write_all(self.fd, self.buffers[index].data.cast("B")[: rows * self.dtype.itemsize])
            os.pwrite(self.fd, self.header(self.rows + rows), 0)
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(self.fd, committed)  # no partial chunk after the rows the header counts
            raise
        self.rows += rows

    def header(self, rows: int) -> bytes:
        header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False, "shape": (rows,)}
        out = io.BytesIO()
        try:
            np.lib.format.write_array_header_1_0(out, header)
        except ValueError:  # more than 64 KiB of field names: the 2.0 format's longer header
            out = io.BytesIO()
            np.lib.format.write_array_header_2_0(out, header)
        return out.getvalue()


class _McapProcess(_LogFile):
    """MCAP, encoded and written by the log's encoder process (modules/_mcap_encoder.py).

    The encoder is started by `start`, in the writer thread, not by the RTPU between two cycles;
    it writes a new log's preamble first, then the chunks as they are handed over."""

    def __init__(self, fd: int, buffers_fd: int, dtype: np.dtype, rows: int, setup: dict[str, Any]) -> None:
        self.fd, self.buffers_fd, self.dtype, self.chunk_rows, self.setup = fd, buffers_fd, dtype, rows, setup
        resume_at = setup["resume_at"]
        self.rows = resume_at[1] if resume_at is not None else 0  # a resumed log's rows so far
        self.encoder: McapEncoder | None = None

    def start(self) -> None:
        self.encoder = McapEncoder(self.fd, self.buffers_fd, self.dtype, self.chunk_rows, self.setup)
        self.encoder.rows = self.rows
        self.encoder.begin()  # the child writes the preamble now: a log cut short before its first chunk still says what it holds

    def append(self, index: int, rows: int) -> None:
        encoder = self._started()
        try:
            encoder.append(index, rows)
        finally:
            self.rows = encoder.rows

    def finish(self) -> None:
        encoder = self._started()
        try:
            encoder.finish()
        finally:
            self.rows = encoder.rows

    def stop(self) -> None:
        if self.encoder is not None:
            self.encoder.stop()

    def _started(self) -> McapEncoder:
        if self.encoder is None:
            raise OSError(errno.ENOENT, "the log's encoder process was not started (its start failed)")
        return self.encoder


def _ended_within(finished: threading.Event, patience: float) -> bool:
    """Wait for the logger killed before to end its file: in a live spawn's init, the RTPU's other
    tasks go on cycling meanwhile (`sleep_while_cycling`)."""
    give_up = time.monotonic() + patience
    while not finished.is_set():
        if time.monotonic() > give_up:
            return False
        sleep_while_cycling(0.001)
    return True


def _flat_rows(field: np.ndarray) -> np.ndarray:
    """A field of the chunk as (rows, values) without a copy: the cycle writes through it."""
    flat = field.reshape(field.shape[0], -1)
    assert np.shares_memory(flat, field), "a field of a structured array reshapes to a view"
    return flat


def _os_error(exc: OSError) -> str:
    return f"[Errno {exc.errno}] {exc.strerror}" if exc.errno is not None and exc.strerror else str(exc)
