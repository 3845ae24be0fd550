"""`pbo log info RUN|LOG`: what a data log holds, in the words `ros2 bag info` uses.

An MCAP log is read record by record (a killed run's log has no summary to read instead): each
channel's messages counted, the first and last log times. On the real clock those are Unix time
(the logger adds the run's `unix_offset_ns`), so the dates line up with a rosbag2 recording; on the
simulated clock they are the simulated seconds. An `.npy` log has rows, times on the run's clock.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from pbo_runtime.reports.data_log import LogError, find_logs, open_log


@dataclass
class TopicInfo:
    topic: str
    type: str
    count: int
    serialization: str


@dataclass
class LogInfo:
    path: Path
    size: int  # bytes
    storage: str  # "mcap" or "npy"
    start_ns: int
    end_ns: int
    unix_time: bool  # the times are Unix time (a real-clock MCAP log), else the run's clock
    messages: int
    complete: bool
    topics: list[TopicInfo] = field(default_factory=list)


def infos(target: Path) -> list[LogInfo]:
    """The info of a log, or of every log of a run's directory; LogError if there is none."""
    if target.is_dir():
        logs = find_logs(target)
        if not logs:
            raise LogError(f"{target}: no data log in this directory (no *.mcap or *.npy file)")
        return [info(log) for log in logs]
    return [info(target)]


def info(path: Path) -> LogInfo:
    log = open_log(path)  # (refuses what is not a log, in the words every log verb uses)
    if log.format == "npy":
        times = log.rows["time"]
        start, end = (round(times[0] * 1e9), round(times[-1] * 1e9)) if len(times) else (0, 0)
        topics = [TopicInfo(name, str(log.rows.dtype[name]), len(log.rows), "npy") for name in log.variables]
        return LogInfo(path, path.stat().st_size, "npy", start, end, False, len(log.rows), log.complete, topics)
    return _mcap_info(path, log.metadata.get("unix_offset_ns") is not None)


def _mcap_info(path: Path, unix_time: bool) -> LogInfo:
    from mcap.records import Channel, DataEnd, Footer, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    channels: dict[int, Channel] = {}
    counts: dict[int, int] = {}
    start = end = None
    complete = False
    with open(path, "rb") as file:
        try:
            for record in StreamReader(file, skip_magic=False).records:
                if isinstance(record, Message):
                    counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
                    start = record.log_time if start is None else min(start, record.log_time)
                    end = record.log_time if end is None else max(end, record.log_time)
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Schema):
                    schemas[record.id] = f"{record.name} ({record.encoding})"
                elif isinstance(record, (DataEnd, Footer)):
                    complete = True
        except Exception:  # a record cut short by a kill: what came before counts
            pass
    topics = [TopicInfo(c.topic, schemas.get(c.schema_id, "?"), counts.get(c.id, 0), c.message_encoding)
              for c in channels.values()]
    return LogInfo(path, path.stat().st_size, "mcap", start or 0, end or 0, unix_time, sum(counts.values()), complete, topics)


def text(found: LogInfo) -> str:
    """As `ros2 bag info` prints it."""
    width = max((len(t.topic) for t in found.topics), default=0)
    lines = [
        f"Files:             {found.path}" + ("" if found.complete else "  (not finished: the run was killed)"),
        f"Bag size:          {_size(found.size)}",
        f"Storage id:        {found.storage}",
        f"Duration:          {(found.end_ns - found.start_ns) / 1e9:.9f}s",
        f"Start:             {_when(found.start_ns, found.unix_time)}",
        f"End:               {_when(found.end_ns, found.unix_time)}",
        f"Messages:          {found.messages}",
    ]
    for i, topic in enumerate(found.topics):
        lines.append(("Topic information: " if i == 0 else " " * 19) + f"Topic: {topic.topic:<{width}} | Type: {topic.type} | "
                     f"Count: {topic.count} | Serialization Format: {topic.serialization}")
    return "\n".join(lines)


def _when(ns: int, unix_time: bool) -> str:
    seconds = f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"
    if not unix_time:
        return f"{seconds} s on the run's clock"
    stamp = time.strftime("%b %d %Y %H:%M:%S", time.localtime(ns // 1_000_000_000))
    return f"{stamp}.{ns % 1_000_000_000:09d} ({seconds})"


def _size(size: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.1f} {unit}" if unit != "B" else f"{size} B"
        size /= 1024  # type: ignore[assignment]
    return f"{size} B"
