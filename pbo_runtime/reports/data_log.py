"""Reading a run's data logs back: MCAP or .npy, whole or cut short by a crash, as one numpy array.

The data logger (modules/data_logger.py) writes either format; `open_log` reads both into a
`DataLog`: a structured array (a row per cycle: `time`, the cycle's release time on the run's
clock, then one field per variable, shaped (rows, *its shape)), each variable's unit and doc,
and the run's metadata. `read_log` gives the array alone.

An MCAP log is read record by record (the `mcap` library's stream reader), so a log whose run
was killed, which has no summary or footer, reads up to its last whole chunk. An .npy log's
complete rows are read past the count in its header, which a killed process may not have
updated. Anything else is a `LogError` naming the file and what it is not.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pbo_runtime.errors import PboError

LOG_SUFFIXES = (".mcap", ".npy")
MCAP_MAGIC = b"\x89MCAP0\r\n"


class LogError(PboError):
    """A path that is not a data log this runtime can read: the message names it and what it is."""


@dataclass(frozen=True)
class DataLog:
    """A data log read back: its rows, each variable's unit and doc, and the run's metadata."""

    path: Path
    format: str  # "mcap" or "npy"
    rows: np.ndarray  # structured: time, then one field per variable
    units: dict[str, str] = field(default_factory=dict)
    docs: dict[str, str] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)  # the run's (MCAP's pbo-run record); {} for .npy
    complete: bool = True  # False: the writer did not finish it (a killed run): read up to its last chunk

    @property
    def variables(self) -> list[str]:
        return [name for name in self.rows.dtype.names or () if name != "time"]


def read_log(path: str | Path) -> np.ndarray:
    """The whole log at `path` (.mcap or .npy) as a structured array: every complete row, a crash's included."""
    return open_log(path).rows


def open_log(path: str | Path) -> DataLog:
    """The log at `path` with its units, docs and metadata; LogError if it is missing or not a log."""
    path = Path(path)
    if not path.is_file():
        raise LogError(f"no log {path}: " + ("it is a directory" if path.is_dir() else "no such file"))
    with open(path, "rb") as file:
        start = file.read(8)
    if start == MCAP_MAGIC:
        return _open_mcap(path)
    if start[:6] == b"\x93NUMPY":
        return _open_npy(path)
    raise LogError(f"{path}: not a data log (neither MCAP nor .npy)")


def _open_npy(path: Path) -> DataLog:
    with open(path, "rb") as file:
        try:
            version = np.lib.format.read_magic(file)
            if version == (1, 0):
                shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(file)
            else:
                shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(file)
        except ValueError as exc:
            raise LogError(f"{path}: not a data log (a broken .npy header: {exc})") from None
        if fortran_order or len(shape) != 1 or dtype.names is None or "time" not in dtype.names:
            raise LogError(f"{path}: not a data log (a 1-D structured array with a time field), got shape {shape} of {dtype}")
        start = file.tell()
        rows = max(shape[0], (os.fstat(file.fileno()).st_size - start) // dtype.itemsize)
        data = np.fromfile(file, dtype=dtype, count=rows)
    return DataLog(path, "npy", data, complete=len(data) == shape[0])


def _open_mcap(path: Path) -> DataLog:
    from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    channels: dict[int, str] = {}
    schemas: dict[int, str] = {}
    cdr: dict[int, Callable[[bytes], Any]] = {}  # channel -> its ROS 2 decoder (encoding: ros2)
    channel_meta: dict[str, dict[str, str]] = {}
    metadata: dict[str, dict[str, str]] = {}
    values: dict[str, list[Any]] = {}
    times: dict[str, list[float]] = {}
    complete = False
    with open(path, "rb") as file:
        try:
            for record in StreamReader(file, skip_magic=False).records:
                if isinstance(record, Message):
                    name = channels.get(record.channel_id)
                    if name is not None and record.channel_id in cdr:
                        values[name].append(cdr[record.channel_id](record.data))
                        offset = int(metadata.get("pbo-run", {}).get("unix_offset_ns", 0))
                        times[name].append((record.log_time - offset) / 1e9)
                    elif name is not None:
                        body = json.loads(record.data)
                        values[name].append(body["value"])
                        times[name].append(body.get("time", record.log_time / 1e9))
                elif isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    channels[record.id] = record.topic
                    if record.message_encoding == "cdr":
                        cdr[record.id] = _ros2_decoder(schemas.get(record.schema_id, ""))
                    channel_meta[record.topic] = dict(record.metadata)
                    values.setdefault(record.topic, [])
                    times.setdefault(record.topic, [])
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
                elif isinstance(record, (DataEnd, Footer)):
                    complete = True
        except LogError:
            raise
        except Exception:  # a record cut short by a kill (or the end of a file never finished): keep what came before
            pass
    columns = _columns(path, metadata.get("pbo-log"), channel_meta)
    dtype = np.dtype([("time", np.float64)] + [(c["name"], np.dtype(c["dtype"]), tuple(c["shape"])) for c in columns])
    count = min((len(values.get(c["name"], [])) for c in columns), default=0)
    rows = np.zeros(count, dtype=dtype)
    if columns and count:
        rows["time"] = times[columns[0]["name"]][:count]
        for c in columns:
            # a non-finite value was written as null: back to NaN
            column = np.array(values[c["name"]][:count], dtype=object)
            if np.dtype(c["dtype"]).kind == "f":
                column = np.where(column == None, np.nan, column)  # noqa: E711 (an element-wise comparison)
            rows[c["name"]] = column.astype(np.dtype(c["dtype"])).reshape((count, *c["shape"]))
    return DataLog(path, "mcap", rows, units={c["name"]: c.get("unit", "") for c in columns},
                   docs={c["name"]: c.get("doc", "") for c in columns}, metadata=metadata.get("pbo-run", {}),
                   complete=complete)


def _columns(path: Path, log: dict[str, str] | None, channels: dict[str, dict[str, str]]) -> list[dict[str, Any]]:
    """The logged variables, in order: from the pbo-log record, or else from the channels' metadata."""
    if log is not None and "columns" in log:
        columns: list[dict[str, Any]] = json.loads(log["columns"])
        return columns
    if not channels:
        raise LogError(f"{path}: an MCAP file, but not a pbo data log (no pbo-log record and no channels)")
    try:
        return [{"name": topic, "dtype": meta["dtype"], "shape": json.loads(meta["shape"]), "unit": meta.get("unit", ""),
                 "doc": meta.get("doc", "")} for topic, meta in channels.items()]
    except (KeyError, ValueError):
        raise LogError(f"{path}: an MCAP file, but not a pbo data log (its channels carry no dtype and shape)") from None


def log_rows(path: str | Path) -> int:
    """How many rows the log at `path` holds (the summary's count where the log was finished)."""
    path = Path(path)
    with open(path, "rb") as file:
        start = file.read(8)
    if start == MCAP_MAGIC:
        from mcap.reader import make_reader

        try:
            with open(path, "rb") as file:
                summary = make_reader(file).get_summary()
            if summary is not None and summary.statistics is not None and summary.channels:
                first = min(summary.channels)
                return int(summary.statistics.channel_message_counts.get(first, 0))
        except Exception:  # no summary: a killed run's log, counted by reading it
            pass
    return len(open_log(path).rows)


def _ros2_decoder(typename: str) -> Callable[[bytes], Any]:
    """A `std_msgs/msg/*MultiArray` message (a log written with `encoding: ros2`) to its values."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise LogError(f"this log's messages are ROS 2 ({typename}): reading them needs the 'ros2' extra: "
                       "pip install 'pbo-runtime[ros2]'") from None
    store = get_typestore(Stores.ROS2_HUMBLE)
    return lambda data: store.deserialize_cdr(data, typename).data.tolist()  # type: ignore[attr-defined]


def find_logs(directory: str | Path) -> list[Path]:
    """The data logs in a run's directory (and below it), sorted."""
    return sorted(p for p in Path(directory).rglob("*") if p.suffix in LOG_SUFFIXES and p.is_file())
