"""Data logger (TR §4.1: a task that only gathers data): chosen variables, every cycle, to a file.

Its inputs are the variables named in `params.variables` (one in-var each, of the variable's
own dtype and shape). The file is one structured numpy array in `.npy` format: a row per cycle,
a `time` field (the cycle's release time, s) and one field per variable, so `np.load(path)["q_m"]`
is the `q_m` column, shaped (rows, *its shape). `read_log` gives the whole log back, a log cut
short by a crash included.

The file is written in chunks as the run goes, so a run of any length keeps every row with
bounded memory, and a killed RTPU loses at most the chunk it was filling. Rows go into a chunk
buffer preallocated in `init` (the cycle allocates nothing); the cycle that fills it appends the
chunk to the file (one write of at most CHUNK_BYTES) and then rewrites the row count in the
file's header (fixed size: numpy leaves room for the count to grow), so the file is a valid
array after every chunk. `off` and `kill` write the rows of the chunk begun. A write that fails
(disk full, file or directory removed) raises `OutputError` at that write: the task goes to
ERROR with the OS error, the run's exit status says so, and the file keeps every row of the
chunks written before.
"""

from __future__ import annotations

import io
import os
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
        # Written now (np.full, not the lazily mapped np.zeros): a row in a page never touched
        # would be faulted in by the cycle that writes it.
        self._chunk = np.full(self._rows, 0, dtype=self._dtype)
        self._bytes = memoryview(self._chunk).cast("B")
        self._times = self._chunk["time"]
        # flat views of each field (made once), and of each port's array
        self._pairs = [(_flat_rows(self._chunk[name]), a.reshape(-1)) for name, a in zip(params.variables, arrays)]
        self.path = self.output_path(params.path)
        self.logged = 0  # rows taken, the chunk begun included
        self.written = 0  # rows in the file (its header's count)
        self._filled = 0  # rows of the chunk begun
        self._fd = -1
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
            self._header_bytes = len(self._header(0))
            _write_all(self._fd, self._header(0))
        except OSError as exc:
            self._close()
            raise OutputError(f"cannot create log {self.path}: {_os_error(exc)}") from None

    def cycle(self) -> Status:
        row = self._filled
        self._times[row] = self.time
        for column, source in self._pairs:
            column[row] = source
        self._filled = row + 1
        self.logged += 1
        if self._filled == self._rows:
            self.write_chunk()
        return Status.CONTINUE

    def off(self) -> None:
        self.write_chunk()

    def kill(self) -> None:
        if self._fd >= 0:
            try:
                self.write_chunk()
            finally:
                self._close()

    def clear(self) -> bool:
        """After a failed write: back to OFF once the rows kept can be written (space was freed)."""
        try:
            self.write_chunk()
        except OutputError:
            return False
        return True

    def write_chunk(self) -> None:
        """Append the rows of the chunk begun, then count them in the header; OutputError if either fails."""
        if self._filled == 0 or self._fd < 0:
            return
        committed = self._header_bytes + self.written * self._dtype.itemsize
        try:
            if os.fstat(self._fd).st_nlink == 0:
                raise FileNotFoundError(2, "the file was removed while the run wrote it (its directory deleted?)")
            os.lseek(self._fd, committed, os.SEEK_SET)
            _write_all(self._fd, self._bytes[: self._filled * self._dtype.itemsize])
            os.pwrite(self._fd, self._header(self.written + self._filled), 0)
        except OSError as exc:
            try:
                os.ftruncate(self._fd, committed)  # no partial chunk after the rows the header counts
            except OSError:
                pass
            raise OutputError(f"cannot write log {self.path} ({self._filled} rows after the {self.written} "
                              f"written): {_os_error(exc)}") from None
        self.written += self._filled
        self._filled = 0

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
