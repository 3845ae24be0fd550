"""Data logger (TR §4.1: a task that only gathers data): chosen variables, every cycle, to a file.

Its inputs are the variables named in `params.variables` (one in-var each, of the variable's
own dtype and shape). The file is one structured numpy array in `.npy` format: a row per cycle,
a `time` field (the cycle's release time, s) and one field per variable, so `np.load(path)["q_m"]`
is the `q_m` column, shaped (rows, *its shape). `read_log` gives the whole log back, a log cut
short by a crash included.

The file is written in chunks as the run goes, so a run of any length keeps every row with
bounded memory, and a killed RTPU loses only the rows since the last chunk written. The cycle
fills one of two chunk buffers preallocated in `init` (it allocates nothing and does no I/O);
the cycle that fills it hands it to a writer thread (an eventfd write) and goes on in the other.
The writer appends the chunk to the file (one write of at most CHUNK_BYTES) and then rewrites
the row count in the file's header (fixed size: numpy leaves room for the count to grow), so the
file is a valid array after every chunk. A write takes microseconds into the page cache, but
milliseconds at times when the kernel throttles write-back: that is why it is not the cycle's.
`off` and `kill` write the chunk begun. A write that fails (disk full, file or directory removed)
makes the next cycle raise `OutputError`: the task goes to ERROR with the OS error, the run's exit
status says so, and the file keeps every row of the chunks written before.
"""

from __future__ import annotations

import io
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbo_runtime import ANY_DTYPE, InVar, OutputError, PortBasedObject, PortSpec, Status

CHUNK_BYTES = 256 * 1024  # the most one cycle writes at once (tens of microseconds into the page cache)


@dataclass(frozen=True)
class DataLoggerParams:
    variables: tuple[str, ...]
    path: str = "runs/log.npy"
    chunk: float = 1.0  # seconds of rows written to the file at a time (at most CHUNK_BYTES)

    def __post_init__(self) -> None:
        if not self.variables:
            raise ValueError("variables must name at least one variable to log")
        if len(set(self.variables)) != len(self.variables):
            raise ValueError(f"variables must not repeat, got: {list(self.variables)}")
        if "time" in self.variables:
            raise ValueError("variables must not include 'time': the log's time field is the cycle's release time")
        if not self.chunk > 0:
            raise ValueError(f"chunk must be > 0 s, got: {self.chunk}")
        if not self.path.endswith(".npy"):
            raise ValueError(f"path must end in .npy (one structured array, appended as the run goes), got: {self.path!r}")


class DataLogger(PortBasedObject):
    """Logs chosen variables every cycle; appends them to `path` a chunk at a time."""

    Params = DataLoggerParams

    @classmethod
    def ports_for(cls, params: DataLoggerParams) -> tuple[PortSpec, ...]:
        extra = tuple(InVar(name, dtype=ANY_DTYPE, shape=None, doc=f"logged variable {name}").spec for name in params.variables)
        named = tuple(PortSpec(name, p.kind, p.variable, p.dtype, p.shape, p.doc) for name, p in zip(params.variables, extra))
        return cls.ports() + named

    def init(self, params: DataLoggerParams) -> None:
        arrays = self.bound_arrays[-len(params.variables):]
        self._dtype = np.dtype([("time", np.float64)] + [(name, a.dtype, a.shape) for name, a in zip(params.variables, arrays)])
        self._rows = max(1, min(int(round(params.chunk / self.period)), CHUNK_BYTES // self._dtype.itemsize))
        # Two chunk buffers: the cycle fills one while the writer writes the other. Written now
        # (np.full, not the lazily mapped np.zeros): a row in a page never touched would be
        # faulted in by the cycle that writes it. Each buffer's views are made once.
        sources = [a.reshape(-1) for a in arrays]
        self._buffers = []
        for _ in range(2):
            chunk = np.full(self._rows, 0, dtype=self._dtype)
            pairs = [(_flat_rows(chunk[name]), source) for name, source in zip(params.variables, sources)]
            self._buffers.append((memoryview(chunk).cast("B"), chunk["time"], pairs))
        self._current = 0
        self._bytes, self._times, self._pairs = self._buffers[0]
        self.path = self.output_path(params.path)
        self.logged = 0  # rows taken, the chunk begun included
        self.written = 0  # rows in the file (its header's count)
        self.dropped = 0  # rows taken while both buffers were full (the disk took longer than a chunk to write one)
        self._filled = 0  # rows of the chunk begun
        self._queued = -1  # the buffer the writer is to write (-1: none), and its rows
        self._queued_rows = 0
        self._failure = ""  # the writer's OutputError, raised by the next cycle
        self._fd = -1
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
            self._header_bytes = len(self._header(0))
            _write_all(self._fd, self._header(0))
        except OSError as exc:
            self._close()
            raise OutputError(f"cannot create log {self.path}: {_os_error(exc)}") from None
        self._wake = os.eventfd(0, os.EFD_CLOEXEC)
        self._stopping = False
        self._writer = threading.Thread(target=self._write_queued, name=f"log-{self.task_name}", daemon=True)
        self._writer.start()

    def cycle(self) -> Status:
        if self._failure:
            raise OutputError(self._failure)
        row = self._filled
        if row == self._rows:  # full, and the writer still has the other buffer
            if self._queued >= 0:
                self.dropped += 1
                return Status.CONTINUE
            self._hand_over()
            row = 0
        self._times[row] = self.time
        for column, source in self._pairs:
            column[row] = source
        self._filled = row + 1
        self.logged += 1
        if self._filled == self._rows and self._queued < 0:
            self._hand_over()
        return Status.CONTINUE

    def _hand_over(self) -> None:
        """Give the full buffer to the writer and go on in the other: a few stores and one eventfd write."""
        self._queued_rows = self._filled
        self._queued = self._current
        self._current ^= 1
        self._bytes, self._times, self._pairs = self._buffers[self._current]
        self._filled = 0
        os.eventfd_write(self._wake, 1)

    def _write_queued(self) -> None:
        """The writer thread: append each buffer handed over; a failure is the next cycle's to raise.

        It holds the GIL only between its system calls (which release it), so the executive's
        thread waits microseconds for it at most; the write's own time (the disk, the kernel's
        write-back throttling: milliseconds at times) is spent off the cycle."""
        while True:
            os.eventfd_read(self._wake)
            if self._stopping:
                return
            index = self._queued
            if index < 0:
                continue
            try:
                self._append(self._buffers[index][0], self._queued_rows)
            except OutputError as exc:
                self._failure = str(exc)
            self._queued = -1

    def wait_for_writer(self, patience: float = 30.0) -> None:
        """Until the writer has written what it was handed (off, kill and clear write after it)."""
        give_up = time.monotonic() + patience
        while self._queued >= 0:
            if time.monotonic() > give_up:
                raise OutputError(f"cannot write log {self.path}: a chunk's write has not returned for {patience:g} s")
            time.sleep(0.001)

    def off(self) -> None:
        self.write_chunk()

    def kill(self) -> None:
        if getattr(self, "_fd", -1) < 0:
            return
        try:
            self.write_chunk()
        finally:
            self._stopping = True
            os.eventfd_write(self._wake, 1)
            self._writer.join(timeout=5.0)
            os.close(self._wake)
            self._close()

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
        self._append(self._bytes, rows)
        if self.dropped:
            dropped, self.dropped = self.dropped, 0
            raise OutputError(f"log {self.path}: {dropped} rows dropped: writing a chunk of {self._rows} rows took "
                              "longer than filling one (the disk is too slow for this period)")

    def _append(self, data: memoryview, rows: int) -> None:
        """Append `rows` rows of `data` to the file, then count them in its header; OutputError if either fails."""
        if rows == 0 or self._fd < 0:
            return
        committed = self._header_bytes + self.written * self._dtype.itemsize
        try:
            if os.fstat(self._fd).st_nlink == 0:
                raise FileNotFoundError(2, "the file was removed while the run wrote it (its directory deleted?)")
            os.lseek(self._fd, committed, os.SEEK_SET)
            _write_all(self._fd, data[: rows * self._dtype.itemsize])
            os.pwrite(self._fd, self._header(self.written + rows), 0)
        except OSError as exc:
            try:
                os.ftruncate(self._fd, committed)  # no partial chunk after the rows the header counts
            except OSError:
                pass
            raise OutputError(f"cannot write log {self.path} ({rows} rows after the {self.written} "
                              f"written): {_os_error(exc)}") from None
        self.written += rows

    def _header(self, rows: int) -> bytes:
        header = {"descr": np.lib.format.dtype_to_descr(self._dtype), "fortran_order": False, "shape": (rows,)}
        out = io.BytesIO()
        try:
            np.lib.format.write_array_header_1_0(out, header)
        except ValueError:  # more than 64 KiB of field names: the 2.0 format's longer header
            out = io.BytesIO()
            np.lib.format.write_array_header_2_0(out, header)
        return out.getvalue()

    def _close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def read_log(path: str | Path) -> np.ndarray:
    """The whole log at `path`: every complete row in the file, those a crash left uncounted included.

    `np.load(path)` gives the rows the header counts (every chunk written whole); this also
    gives the complete rows of a chunk whose count a killed process did not get to write.
    """
    with open(path, "rb") as file:
        version = np.lib.format.read_magic(file)
        if version == (1, 0):
            shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(file)
        else:
            shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(file)
        if fortran_order or len(shape) != 1 or dtype.names is None:
            raise ValueError(f"{path}: not a data log (a 1-D structured array), got shape {shape} of {dtype}")
        start = file.tell()
        rows = max(shape[0], (os.fstat(file.fileno()).st_size - start) // dtype.itemsize)
        return np.fromfile(file, dtype=dtype, count=rows)


def _flat_rows(field: np.ndarray) -> np.ndarray:
    """A field of the chunk as (rows, values) without a copy: the cycle writes through it."""
    flat = field.reshape(field.shape[0], -1)
    assert np.shares_memory(flat, field), "a field of a structured array reshapes to a view"
    return flat


def _write_all(fd: int, data: bytes | memoryview) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _os_error(exc: OSError) -> str:
    return f"[Errno {exc.errno}] {exc.strerror}" if exc.errno is not None and exc.strerror else str(exc)
