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
fills one of two chunk buffers preallocated in `init` (it allocates nothing, encodes nothing and
does no I/O); the cycle that fills it hands it to a writer thread (an eventfd write) and goes on
in the other. The writer encodes the chunk (MCAP: JSON and zstd, in slices of at most
ENCODE_SLICE seconds with a pause between, so the cycle's thread never waits long for the GIL)
and appends it to the file in one write; an `.npy` log then rewrites the row count in its header
(fixed size: numpy leaves room for the count to grow), so the file is a valid array after every
chunk; an MCAP log is readable up to its last chunk, and gets its summary and footer when the
task is killed. A write takes microseconds into the page cache, but milliseconds at times when
the kernel throttles write-back: that is why it is not the cycle's. `off` and `kill` write the
chunk begun. A write that fails (disk full, file or directory removed) makes the next cycle
raise `OutputError`: the task goes to ERROR with the OS error, the run's exit status says so, and
the file keeps every row of the chunks written before (an MCAP log keeps the failed chunk's bytes
and writes them first when the task is cleared).
"""

from __future__ import annotations

import io
import json
import os
import threading
import time
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from pbo_runtime import ANY_DTYPE, InVar, OutputError, PortBasedObject, PortSpec, Status, read_log

__all__ = ["DataLogger", "DataLoggerParams", "read_log"]

CHUNK_BYTES = 256 * 1024  # the most one cycle writes at once (tens of microseconds into the page cache)
FORMATS = (".mcap", ".npy")
ENCODE_SLICE = 50e-6  # seconds the writer encodes before it lets the GIL go (a thread of the RTPU may want it)
ENCODE_PAUSE = 50e-6  # seconds it then sleeps: long enough for a thread waiting on the GIL to take it


@dataclass(frozen=True)
class DataLoggerParams:
    variables: tuple[str, ...]
    path: str = "log.mcap"  # relative: under the run's output directory
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
        if not self.path.endswith(FORMATS):
            raise ValueError(f"path must end in .mcap (Foxglove, PlotJuggler) or .npy (one numpy structured array), "
                             f"got: {self.path!r}")


class DataLogger(PortBasedObject):
    """Logs chosen variables every cycle; appends them to `path` (.mcap or .npy) a chunk at a time."""

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
            self._buffers.append((chunk, chunk["time"], pairs))
        self._current = 0
        self._chunk, self._times, self._pairs = self._buffers[0]
        self.path = self.output_path(params.path)
        self.logged = 0  # rows taken, the chunk begun included
        self.dropped = 0  # rows taken while both buffers were full (the disk took longer than a chunk to write one)
        self._filled = 0  # rows of the chunk begun
        self._queued = -1  # the buffer the writer is to write (-1: none), and its rows
        self._queued_rows = 0
        self._failure = ""  # the writer's OutputError, raised by the next cycle
        self._fd = -1
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
            if self.path.suffix == ".mcap":
                columns = {name: self.variable_note(name) for name in params.variables}
                self._file: _LogFile = _McapFile(self._fd, self._dtype, columns, self.run_metadata, self.task_name, self.period)
            else:
                self._file = _NpyFile(self._fd, self._dtype)
        except OSError as exc:
            self._close()
            raise OutputError(f"cannot create log {self.path}: {_os_error(exc)}") from None
        self._wake = os.eventfd(0, os.EFD_CLOEXEC)
        self._stopping = False
        self._writer = threading.Thread(target=self._write_queued, name=f"log-{self.task_name}", daemon=True)
        self._writer.start()

    @property
    def written(self) -> int:
        """Rows in the file (an .npy header's count; an MCAP log's rows of the chunks written)."""
        return self._file.rows

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
        self._chunk, self._times, self._pairs = self._buffers[self._current]
        self._filled = 0
        os.eventfd_write(self._wake, 1)

    def _write_queued(self) -> None:
        """The writer thread: encode and append each buffer handed over; a failure is the next cycle's to raise.

        It holds the GIL while it encodes, in slices (ENCODE_SLICE) with a pause between, and
        not during its system calls, so the executive's thread waits a slice at most. The pause
        also gives up the CPU: the thread inherits the RTPU's SCHED_FIFO priority, and on an RTPU
        pinned to one CPU a thread of equal priority that never blocked would hold the executive
        off until it did. The write's own time (the disk, the kernel's write-back throttling:
        milliseconds at times) is spent off the cycle."""
        while True:
            os.eventfd_read(self._wake)
            if self._stopping:
                return
            index = self._queued
            if index < 0:
                continue
            try:
                self._append(self._buffers[index][0], self._queued_rows, pause=True)
            except OutputError as exc:
                self._failure = str(exc)
            except Exception as exc:  # a bug in encoding: said by the next cycle, never a writer gone silent
                self._failure = f"cannot write log {self.path}: its writer failed: {type(exc).__name__}: {exc}"
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
            self._file.finish()
        except OSError as exc:
            raise OutputError(f"cannot finish log {self.path}: {_os_error(exc)}") from None
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
        self._append(self._chunk, rows)
        if self.dropped:
            dropped, self.dropped = self.dropped, 0
            raise OutputError(f"log {self.path}: {dropped} rows dropped: writing a chunk of {self._rows} rows took "
                              "longer than filling one (the disk is too slow for this period)")

    def _append(self, chunk: np.ndarray, rows: int, pause: bool = False) -> None:
        """Append `rows` rows of `chunk` to the file; OutputError if it fails (the file keeps the chunks before)."""
        if self._fd < 0:
            return
        written = self._file.rows
        try:
            if os.fstat(self._fd).st_nlink == 0:
                raise FileNotFoundError(2, "the file was removed while the run wrote it (its directory deleted?)")
            self._file.append(chunk, rows, pause)
        except OSError as exc:
            raise OutputError(f"cannot write log {self.path} ({rows} rows after the {written} "
                              f"written): {_os_error(exc)}") from None

    def _close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


class _LogFile:
    """A log's format: appends chunks of rows to the file's descriptor; `rows` counts those in the file."""

    rows = 0

    def append(self, chunk: np.ndarray, rows: int, pause: bool) -> None:
        raise NotImplementedError

    def finish(self) -> None:
        """At the task's kill: what the format writes after the last row."""


class _NpyFile(_LogFile):
    """One structured array: each chunk appended, then the row count in the header rewritten."""

    def __init__(self, fd: int, dtype: np.dtype) -> None:
        self.fd, self.dtype, self.rows = fd, dtype, 0
        self.header_bytes = len(self.header(0))
        _write_all(fd, self.header(0))

    def append(self, chunk: np.ndarray, rows: int, pause: bool) -> None:
        if rows == 0:
            return
        committed = self.header_bytes + self.rows * self.dtype.itemsize
        try:
            os.lseek(self.fd, committed, os.SEEK_SET)
            _write_all(self.fd, memoryview(chunk).cast("B")[: rows * self.dtype.itemsize])
            os.pwrite(self.fd, self.header(self.rows + rows), 0)
        except OSError:
            try:
                os.ftruncate(self.fd, committed)  # no partial chunk after the rows the header counts
            except OSError:
                pass
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


class _PendingBytes:
    """What the MCAP writer writes to: its bytes held until `commit` appends them to the file whole.

    `tell` counts the held bytes after those in the file, so the writer's chunk indexes point
    where the chunks land. A commit that fails leaves the file as it was and keeps the bytes,
    for the next commit to write first: the writer's indexes stay true."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.committed = 0
        self.held = bytearray()

    def write(self, data: bytes) -> int:
        self.held += data
        return len(data)

    def tell(self) -> int:
        return self.committed + len(self.held)

    def flush(self) -> None:
        pass

    def commit(self) -> None:
        if not self.held:
            return
        try:
            os.lseek(self.fd, self.committed, os.SEEK_SET)
            _write_all(self.fd, self.held)
        except OSError:
            try:
                os.ftruncate(self.fd, self.committed)
            except OSError:
                pass
            raise
        self.committed += len(self.held)
        self.held.clear()


class _McapFile(_LogFile):
    """MCAP: a channel per variable, JSON messages, one zstd chunk per chunk of rows."""

    def __init__(self, fd: int, dtype: np.dtype, columns: Mapping[str, tuple[str, str]], run: Mapping[str, str],
                 task: str, period: float) -> None:
        from mcap.writer import CompressionType, Writer

        self.rows = 0
        self.pending = 0  # rows encoded into bytes not yet in the file
        self.stream = _PendingBytes(fd)
        # never a chunk by size: one per chunk of rows (`flush`), so each is on disk whole as it ends
        self.writer = Writer(self.stream, chunk_size=1 << 62, compression=CompressionType.ZSTD)  # type: ignore[arg-type]
        self.writer.start(profile="", library=f"pbo-runtime {run.get('pbo-runtime', '')}".strip())
        self.names = [name for name in dtype.names or () if name != "time"]
        described = []
        self.channels = []
        self.floats = []
        for name in self.names:
            field_dtype, shape = dtype[name].base, dtype[name].shape
            doc, unit = columns.get(name, ("", ""))
            described.append({"name": name, "dtype": str(field_dtype), "shape": list(shape), "unit": unit, "doc": doc})
            schema = self.writer.register_schema(name, "jsonschema", json.dumps(_json_schema(name, field_dtype, shape, unit, doc)).encode())
            self.channels.append(self.writer.register_channel(name, "json", schema, {
                "unit": unit, "doc": doc, "dtype": str(field_dtype), "shape": json.dumps(list(shape))}))
            self.floats.append(field_dtype.kind == "f")
        self.writer.add_metadata("pbo-run", {str(k): str(v) for k, v in run.items()})
        self.writer.add_metadata("pbo-log", {"task": task, "period": repr(period), "columns": json.dumps(described)})
        self.stream.commit()

    def append(self, chunk: np.ndarray, rows: int, pause: bool) -> None:
        if rows:
            self.encode(chunk[:rows], pause)
            self.pending += rows
            self.writer.flush()  # the chunk ends here: compressed, written to the stream with its index
        self.stream.commit()
        self.rows += self.pending
        self.pending = 0

    def encode(self, chunk: np.ndarray, pause: bool) -> None:
        times = chunk["time"].tolist()
        stamps = np.rint(chunk["time"] * 1e9).astype(np.int64).tolist()
        columns = [(channel, _json_values(chunk[name], floating))
                   for channel, name, floating in zip(self.channels, self.names, self.floats)]
        add, dumps = self.writer.add_message, json.dumps
        slice_ends = time.perf_counter() + ENCODE_SLICE
        for row, (at, stamp) in enumerate(zip(times, stamps)):
            for channel, values in columns:
                data = f'{{"time":{at!r},"value":{dumps(values[row])}}}'.encode()
                add(channel, log_time=stamp, data=data, publish_time=stamp, sequence=row)
                if pause and time.perf_counter() > slice_ends:
                    time.sleep(ENCODE_PAUSE)
                    slice_ends = time.perf_counter() + ENCODE_SLICE

    def finish(self) -> None:
        """The summary and footer: the log then opens indexed (a killed run's log is read chunk by chunk)."""
        self.writer.finish()
        self.stream.commit()


def _json_values(column: np.ndarray, floating: bool) -> list[Any]:
    """A column's rows as JSON-ready lists; a non-finite float becomes null (JSON has no NaN)."""
    if floating and not np.isfinite(column).all():
        column = column.astype(object)
        column[~np.isfinite(column.astype(np.float64))] = None
    return column.tolist()


def _json_schema(name: str, dtype: np.dtype, shape: tuple[int, ...], unit: str, doc: str) -> dict[str, Any]:
    """The JSON schema of a variable's messages: its time and its value (a number or nested arrays)."""
    value: dict[str, Any] = {"type": "integer" if dtype.kind in "iub" else "number"}
    if dtype.kind == "b":
        value = {"type": "boolean"}
    for size in reversed(shape):
        value = {"type": "array", "items": value, "minItems": size, "maxItems": size}
    description = ", ".join(part for part in (doc, unit) if part)
    return {"title": name, "type": "object", "description": description,
            "properties": {"time": {"type": "number", "description": "the cycle's release time on the run's clock, s"},
                           "value": {**value, "description": description}}}


def _flat_rows(field: np.ndarray) -> np.ndarray:
    """A field of the chunk as (rows, values) without a copy: the cycle writes through it."""
    flat = field.reshape(field.shape[0], -1)
    assert np.shares_memory(flat, field), "a field of a structured array reshapes to a view"
    return flat


def _write_all(fd: int, data: bytes | bytearray | memoryview) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _os_error(exc: OSError) -> str:
    return f"[Errno {exc.errno}] {exc.strerror}" if exc.errno is not None and exc.strerror else str(exc)
