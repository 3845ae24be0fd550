"""MCAP encoding for the data logger, in a process of its own so that it never holds the RTPU's GIL.

Encoding a chunk is Python work (a JSON text and an MCAP record per variable per row). Done by a
thread of the RTPU it took the GIL from the executive's thread for tens of microseconds at a
time, and every task on that RTPU saw it in its cycle. Here the encoder is a child process
(`python -m modules._mcap_encoder`): the logger's chunk buffers live in a memfd both map,
and the logger's writer thread only says "buffer i holds n rows" down a pipe and waits for the
reply with the GIL released. The child runs at SCHED_OTHER, niced, on the RTPU's CPU: it takes
the time the executive leaves idle.

The file's preamble (header, schemas, channels, the run's metadata) is the child's first write,
before the first chunk, so a log cut short at once still says what it holds (a resumed log's is in
the file already: the child builds the same writer and writes after what is there).

The child ends on `finish` (summary and footer written) or when the pipe closes without one (the
RTPU died): it then leaves the log as a SIGKILL leaves it, readable chunk by chunk up to the last
whole one, and not marked complete.
"""

from __future__ import annotations

import contextlib
import json
import mmap
import os
import struct
import subprocess
import sys
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

FINISH = -1  # the command's buffer index that asks for the summary and footer
NICE = 10  # below the RTPU's other processes: the encoder takes the CPU the executive leaves
_LENGTH = struct.Struct("<I")


class EncoderGone(OSError):
    """The encoder process ended without answering (killed, or a bug): the log cannot go on."""


class McapEncoder:
    """The logger's handle on its encoder process: append a buffer's rows, finish, stop.

    Made by the logger's writer thread as it starts (a fork and exec); the first call sends the
    setup and so waits for the child to have started."""

    def __init__(self, log_fd: int, buffers_fd: int, dtype: np.dtype, rows: int, setup: Mapping[str, Any]) -> None:
        self.rows = 0  # rows in the file, as the child last said
        commands_read, self._commands = os.pipe2(os.O_CLOEXEC)
        self._replies, replies_write = os.pipe2(os.O_CLOEXEC)
        self._setup: dict[str, Any] | None = {
            **setup, "log_fd": log_fd, "buffers_fd": buffers_fd, "descr": np.lib.format.dtype_to_descr(dtype), "rows": rows}
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "modules._mcap_encoder", str(commands_read), str(replies_write)],
                pass_fds=(commands_read, replies_write, log_fd, buffers_fd), stdin=subprocess.DEVNULL)
        finally:
            os.close(commands_read)
            os.close(replies_write)

    def begin(self) -> None:
        """Send the setup now and wait for the child to have written the file's preamble (a new
        log's), without waiting for a first chunk; OSError if it could not."""
        try:
            self._send_setup()
        except BrokenPipeError:
            self._gone()

    def _send_setup(self) -> None:
        if self._setup is None:
            return
        setup, self._setup = self._setup, None
        _send(self._commands, setup)
        self._take(_receive(self._replies))

    def _take(self, reply: dict[str, Any] | None) -> None:
        if reply is None:
            self._gone()
        assert reply is not None
        self.rows = reply["rows"]
        if "errno" in reply:
            raise OSError(reply["errno"], reply["strerror"])
        if "bug" in reply:
            raise RuntimeError(reply["bug"])

    def _gone(self) -> None:
        code = self.process.wait()
        raise EncoderGone(f"the log's encoder process ended ({_exit_cause(code)})")

    def append(self, index: int, rows: int) -> None:
        """Have buffer `index`'s first `rows` rows appended; OSError (with the child's errno) if that failed."""
        self._ask({"buffer": index, "rows": rows})

    def finish(self) -> None:
        self._ask({"buffer": FINISH, "rows": 0})

    def _ask(self, command: dict[str, Any]) -> None:
        try:
            self._send_setup()
            _send(self._commands, command)
        except BrokenPipeError:
            reply = None
        else:
            reply = _receive(self._replies)
        self._take(reply)

    def stop(self, patience: float = 5.0) -> None:
        """Close the pipes; the child ends (having finished or not); killed if it does not within `patience`."""
        for fd in (self._commands, self._replies):
            with contextlib.suppress(OSError):
                os.close(fd)
        try:
            self.process.wait(timeout=patience)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def _exit_cause(code: int) -> str:
    if code < 0:
        import signal

        return f"killed by {signal.Signals(-code).name}"
    return f"exit status {code}"


def _send(fd: int, message: Mapping[str, Any]) -> None:
    data = json.dumps(message).encode()
    write_all(fd, _LENGTH.pack(len(data)) + data)


def _receive(fd: int) -> Any:
    """The next message, or None when the other end closed."""
    head = _read_exactly(fd, _LENGTH.size)
    if head is None:
        return None
    body = _read_exactly(fd, _LENGTH.unpack(head)[0])
    return None if body is None else json.loads(body)


def _read_exactly(fd: int, size: int) -> bytes | None:
    data = bytearray()
    while len(data) < size:
        part = os.read(fd, size - len(data))
        if not part:
            return None
        data += part
    return bytes(data)


def write_all(fd: int, data: bytes | bytearray | memoryview) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


class PendingBytes:
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
            write_all(self.fd, self.held)
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(self.fd, self.committed)
            raise
        self.committed += len(self.held)
        self.held.clear()

    def count_as_committed(self) -> None:
        """The held bytes are in the file already (the logger wrote the same preamble)."""
        self.committed += len(self.held)
        self.held.clear()


_MAGIC_BYTES = 8  # an MCAP file's leading magic
_RECORD_HEAD = 9  # a record's opcode (1 byte) and content length (8)
_MESSAGE_INDEX, _DATA_END, _FOOTER = 0x07, 0x0F, 0x02  # opcodes (mcap.opcode)


def resume_point(fd: int) -> tuple[int, int]:
    """Where a log of this run goes on after its RTPU was restarted: the end of its last whole
    record before any end of data, and the rows before it (counted from the first channel's
    message indexes, which every chunk of ours is followed by)."""
    size = os.fstat(fd).st_size
    if size < _MAGIC_BYTES:
        return 0, 0
    with mmap.mmap(fd, size, prot=mmap.PROT_READ) as data:
        position, rows = _MAGIC_BYTES, 0
        while position + _RECORD_HEAD <= size:
            opcode = data[position]
            end = position + _RECORD_HEAD + int.from_bytes(data[position + 1:position + _RECORD_HEAD], "little")
            if end > size or opcode in (_DATA_END, _FOOTER):
                break
            if opcode == _MESSAGE_INDEX and int.from_bytes(data[position + 9:position + 11], "little") == 1:
                rows += int.from_bytes(data[position + 11:position + 15], "little") // 16  # (time, offset) pairs
            position = end
    return position, rows


class McapLog:
    """MCAP: a channel per variable, JSON messages, one zstd chunk per chunk of rows.

    `resume_at`: the log exists up to that offset (`resume_point`), written by this task before its
    RTPU died; the same channels go on in new chunks there. Its summary then indexes no chunk and
    counts nothing (it would know only the new ones): a reader reads it through, as a killed log."""

    def __init__(self, fd: int, dtype: np.dtype, columns: Mapping[str, tuple[str, str]], run: Mapping[str, str],
                 task: str, period: float, preamble_written: bool = False, resume_at: tuple[int, int] | None = None,
                 encoding: str = "json") -> None:
        from mcap.writer import CompressionType, IndexType, Writer

        self.rows = 0
        self.pending = 0  # rows encoded into bytes not yet in the file
        self.unix_offset_ns = int(run.get("unix_offset_ns", 0))  # log times in Unix ns on the real clock (data_logger)
        self.stream = PendingBytes(fd)
        # never a chunk by size: one per chunk of rows (`flush`), so each is on disk whole as it ends
        resumed: dict[str, Any] = {} if resume_at is None else {"index_types": IndexType.MESSAGE, "use_statistics": False}
        self.writer = Writer(self.stream, chunk_size=1 << 62, compression=CompressionType.ZSTD,  # type: ignore[arg-type]
                             **resumed)
        self.ros2 = Ros2Messages() if encoding == "ros2" else None
        self.writer.start(profile="ros2" if self.ros2 else "", library=f"pbo-runtime {run.get('pbo-runtime', '')}".strip())
        self.names = [name for name in dtype.names or () if name != "time"]
        described = []
        self.channels = []
        self.floats = []
        for name in self.names:
            field_dtype, shape = dtype[name].base, dtype[name].shape
            doc, unit = columns.get(name, ("", ""))
            described.append({"name": name, "dtype": str(field_dtype), "shape": list(shape), "unit": unit, "doc": doc})
            metadata = {"unit": unit, "doc": doc, "dtype": str(field_dtype), "shape": json.dumps(list(shape))}
            if self.ros2 is not None:
                typename, definition = self.ros2.declare(name, field_dtype, shape)
                schema = self.writer.register_schema(typename, "ros2msg", definition.encode())
                self.channels.append(self.writer.register_channel(name, "cdr", schema, metadata))
            else:
                schema = self.writer.register_schema(name, "jsonschema",
                                                     json.dumps(_json_schema(name, field_dtype, shape, unit, doc)).encode())
                self.channels.append(self.writer.register_channel(name, "json", schema, metadata))
            self.floats.append(field_dtype.kind == "f")
        self.writer.add_metadata("pbo-run", {str(k): str(v) for k, v in run.items()})
        self.writer.add_metadata("pbo-log", {"task": task, "period": repr(period), "columns": json.dumps(described)})
        if resume_at is not None:  # the same preamble is in the file already; what follows goes where it ended
            self.stream.held.clear()
            self.stream.committed, self.rows = resume_at
        elif preamble_written:
            self.stream.count_as_committed()
        else:
            self.stream.commit()

    def append(self, chunk: np.ndarray, rows: int) -> None:
        if rows:
            self.encode(chunk[:rows])
            self.pending += rows
            self.writer.flush()  # the chunk ends here: compressed, written to the stream with its index
        self.stream.commit()
        self.rows += self.pending
        self.pending = 0

    def encode(self, chunk: np.ndarray) -> None:
        if self.ros2 is not None:
            self._encode_cdr(chunk)
            return
        times = chunk["time"].tolist()
        stamps = (np.rint(chunk["time"] * 1e9).astype(np.int64) + self.unix_offset_ns).tolist()
        columns = [(channel, _json_values(chunk[name], floating))
                   for channel, name, floating in zip(self.channels, self.names, self.floats, strict=True)]
        add, dumps = self.writer.add_message, json.dumps
        for row, (at, stamp) in enumerate(zip(times, stamps, strict=True)):
            for channel, values in columns:
                data = f'{{"time":{at!r},"value":{dumps(values[row])}}}'.encode()
                add(channel, log_time=stamp, data=data, publish_time=stamp, sequence=row)

    def _encode_cdr(self, chunk: np.ndarray) -> None:
        """Each row of each variable as the ROS 2 message `Ros2Messages` declared for it, CDR as rmw writes it."""
        assert self.ros2 is not None
        stamps = (np.rint(chunk["time"] * 1e9).astype(np.int64) + self.unix_offset_ns).tolist()
        add = self.writer.add_message
        for channel, name in zip(self.channels, self.names, strict=True):
            serialize = self.ros2.serializer(name)
            column = chunk[name].reshape(len(chunk), -1)
            for row, stamp in enumerate(stamps):
                add(channel, log_time=stamp, data=serialize(column[row]), publish_time=stamp, sequence=row)

    def finish(self) -> None:
        """The summary and footer: the log then opens indexed (a killed run's log is read chunk by chunk)."""
        self.writer.finish()
        self.stream.commit()


def _json_values(column: np.ndarray, floating: bool) -> list[Any]:
    """A column's rows as JSON-ready lists; a non-finite float becomes null (JSON has no NaN)."""
    if floating and not np.isfinite(column).all():
        column = column.astype(object)
        column[~np.isfinite(column.astype(np.float64))] = None
    values: list[Any] = column.tolist()
    return values


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


class Ros2Messages:
    """A variable as a ROS 2 `std_msgs/msg/*MultiArray` of its element type, its layout its shape
    (a dimension per axis, ROS's strides): what rosbag2 and the ROS 2 tools read. Built with the
    `rosbags` type store (the `ros2` extra)."""

    TYPES: ClassVar[Mapping[str, str]] = {
        "f4": "Float32", "f8": "Float64", "i1": "Int8", "i2": "Int16", "i4": "Int32", "i8": "Int64",
        "u1": "UInt8", "u2": "UInt16", "u4": "UInt32", "u8": "UInt64", "b1": "UInt8"}

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self._serializers: dict[str, Any] = {}

    def declare(self, name: str, dtype: np.dtype, shape: tuple[int, ...]) -> tuple[str, str]:
        """The variable's message type and its definition as rosbag2 stores it (`ros2msg`)."""
        kind = f"{dtype.kind}{dtype.itemsize}"
        typename = f"std_msgs/msg/{self.TYPES[kind]}MultiArray"
        types = self.store.types
        strides = [int(np.prod(shape[i:], dtype=int)) for i in range(len(shape))]
        layout = types["std_msgs/msg/MultiArrayLayout"](
            dim=[types["std_msgs/msg/MultiArrayDimension"](label=f"dim{i}", size=size, stride=stride)
                 for i, (size, stride) in enumerate(zip(shape, strides, strict=True))], data_offset=0)
        message, serialize, wire = types[typename], self.store.serialize_cdr, np.dtype("u1" if kind == "b1" else kind)
        self._serializers[name] = lambda values: bytes(serialize(message(layout=layout, data=values.astype(wire)), typename))
        return typename, self.store.generate_msgdef(typename, ros_version=2)[0]

    def serializer(self, name: str) -> Any:
        return self._serializers[name]


def _step_aside() -> None:
    """Leave the CPU to the RTPU: SCHED_OTHER (a child inherits the executive's SCHED_FIFO), niced."""
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    with contextlib.suppress(OSError):
        os.nice(NICE)


def _serve(commands: int, replies: int) -> None:
    """The child: set up from the first message, then answer each command until finish or the pipe closes."""
    _step_aside()
    setup = _receive(commands)
    if setup is None:
        return
    dtype = np.lib.format.descr_to_dtype(setup["descr"])
    rows = setup["rows"]
    count = setup.get("buffers", 2)
    shared = mmap.mmap(setup["buffers_fd"], count * rows * dtype.itemsize, prot=mmap.PROT_READ)
    buffers = [np.frombuffer(shared, dtype, count=rows, offset=i * rows * dtype.itemsize) for i in range(count)]
    columns = {name: tuple(note) for name, note in setup["columns"].items()}
    resume_at = tuple(setup["resume_at"]) if setup.get("resume_at") else None
    try:
        log = McapLog(setup["log_fd"], dtype, columns, setup["run"], setup["task"], setup["period"],
                      resume_at=resume_at, encoding=setup.get("encoding", "json"))
    except OSError as exc:  # the preamble could not be written: said to the logger, and the log ends here
        _send(replies, {"rows": 0, "errno": exc.errno, "strerror": exc.strerror or str(exc)})
        return
    _send(replies, {"rows": log.rows})  # the preamble is in the file
    while (command := _receive(commands)) is not None:
        reply: dict[str, Any] = {}
        try:
            if command["buffer"] == FINISH:
                log.finish()
            else:
                log.append(buffers[command["buffer"]], command["rows"])
        except OSError as exc:
            reply = {"errno": exc.errno, "strerror": exc.strerror or str(exc)}
        except Exception as exc:  # a bug in encoding: said to the logger, whose next cycle raises it
            reply = {"bug": f"{type(exc).__name__}: {exc}"}
        try:
            _send(replies, {"rows": log.rows, **reply})
        except BrokenPipeError:
            return  # the logger's process is gone (killed with its RTPU): the log ends at its last chunk
        if command["buffer"] == FINISH:
            return


if __name__ == "__main__":
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a stop signal ends it as SIGTERM does, with no traceback
    with contextlib.suppress(BrokenPipeError):  # the logger's process died (its RTPU killed): the log ends at its last chunk
        _serve(int(sys.argv[1]), int(sys.argv[2]))
