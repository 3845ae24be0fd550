"""The OS limits a run's shared objects run into, and the one-line errors that name them.

A run makes POSIX message queues (bounded by the per-user queue memory RLIMIT_MSGQUEUE, `ulimit
-q`; by the number of queues, fs.mqueue.queues_max; by each queue's depth and message size,
fs.mqueue.msg_max and msgsize_max), shared-memory segments and semaphores in /dev/shm (bounded by
its size), and file descriptors (RLIMIT_NOFILE, `ulimit -n`; fs.file-max for the whole machine).
`check_queue_room` refuses a run whose queues cannot fit before anything is made; `explain` turns
the error of a creation that failed anyway (other runs took the room meanwhile) into a
`ResourceLimitError`: the limit, its value, what the run needs, and the fix, in one line.

posix_ipc raises these as OSError or ValueError without an errno, so its messages are matched
here, in one place.
"""

from __future__ import annotations

import errno
import os
import resource
from dataclasses import dataclass
from pathlib import Path

import posix_ipc

from pbo_runtime.errors import ResourceLimitError

MQUEUE_SYSCTL = Path("/proc/sys/fs/mqueue")
KERNEL_BYTES_PER_MESSAGE = 96  # what Linux charges per message slot beyond its bytes (two 48 B structs)
CAP_SYS_RESOURCE = 24  # a process holding it is not bound by msg_max, msgsize_max, queues_max

_POSIX_IPC_ERRNO = {  # posix_ipc's messages for mq_open/sem_open/shm_open errors, which carry no errno
    "This process already has the maximum number of files open": errno.EMFILE,
    "The system limit on the total number of open files has been reached": errno.ENFILE,
    "Insufficient space for a new queue": errno.ENOSPC,
    "Invalid parameter(s)": errno.EINVAL,
    "Not enough memory": errno.ENOMEM,
    "Out of memory": errno.ENOMEM,
}


@dataclass(frozen=True)
class QueueSize:
    """One queue a run makes: its name, how many messages it holds and how long each may be."""

    name: str
    depth: int
    message_bytes: int

    @property
    def bytes(self) -> int:
        """What the queue takes of RLIMIT_MSGQUEUE: its messages and the kernel's bookkeeping for each."""
        return self.depth * (self.message_bytes + KERNEL_BYTES_PER_MESSAGE)


def queue_system_limit(name: str, default: int) -> int:
    """fs.mqueue.<name> (msg_max, msgsize_max, queues_max), or `default` where it cannot be read."""
    try:
        return int((MQUEUE_SYSCTL / name).read_text())
    except (OSError, ValueError):
        return default


def queue_memory_limit() -> int:
    """RLIMIT_MSGQUEUE's soft value in bytes (`ulimit -q`); -1 for unlimited."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_MSGQUEUE)
    return -1 if soft == resource.RLIM_INFINITY else soft


def _has_cap_sys_resource() -> bool:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("CapEff:"):
                return bool(int(line.split()[1], 16) >> CAP_SYS_RESOURCE & 1)
    except (OSError, ValueError, IndexError):
        pass
    return False


def _queues_in_use() -> int | None:
    """Queues of the machine now, where /dev/mqueue is mounted (None where it is not)."""
    try:
        return len(os.listdir("/dev/mqueue"))
    except OSError:
        return None


def _kib(size: int) -> str:
    return f"{size / 1024:,.1f} KiB"


def _raise_to(needed: int) -> int:
    """A round value comfortably above `needed` to suggest to an operator."""
    suggestion = 1_000_000
    while suggestion < 2 * needed:
        suggestion *= 2
    return suggestion


def check_queue_room(queues: list[QueueSize]) -> None:
    """ResourceLimitError if these queues cannot all be made whatever else runs: before anything is made."""
    total = sum(q.bytes for q in queues)
    limit = queue_memory_limit()
    if 0 <= limit < total:
        raise ResourceLimitError(
            f"this run needs {_kib(total)} of POSIX message-queue memory ({len(queues)} queues), more than the per-user "
            f"limit RLIMIT_MSGQUEUE of {_kib(limit)}: raise it (ulimit -q {_raise_to(total)}) and run again")
    if _has_cap_sys_resource():
        return
    size_max = queue_system_limit("msgsize_max", 8192)
    too_long = [q for q in queues if q.message_bytes > size_max]
    if too_long:
        longest = max(q.message_bytes for q in too_long)
        raise ResourceLimitError(
            f"queue {too_long[0].name} needs messages of {longest} bytes, more than fs.mqueue.msgsize_max = {size_max}: "
            f"raise it (sysctl fs.mqueue.msgsize_max={max(longest, 8192)}) and run again")
    queues_max = queue_system_limit("queues_max", 256)
    in_use = _queues_in_use()
    if len(queues) > queues_max or (in_use is not None and in_use + len(queues) > queues_max):
        raise ResourceLimitError(_queues_max_message(len(queues), queues_max, in_use))


def _queues_max_message(needed: int, queues_max: int, in_use: int | None) -> str:
    taken = f", {in_use} are in use" if in_use is not None else ""
    return (f"this run needs {needed} POSIX message queues and the system allows fs.mqueue.queues_max = {queues_max}"
            f"{taken}: stop other runs (pbo runs) or raise it (sysctl fs.mqueue.queues_max={max(queues_max * 2, needed + 256)})")


def error_number(exc: BaseException) -> int | None:
    """The errno behind an OSError, or behind posix_ipc's errno-less OSError/ValueError/MemoryError."""
    if isinstance(exc, OSError) and exc.errno is not None:
        return exc.errno
    if isinstance(exc, MemoryError):
        return errno.ENOMEM
    if isinstance(exc, (OSError, ValueError, posix_ipc.Error)) and exc.args:
        return _POSIX_IPC_ERRNO.get(str(exc.args[0]))
    return None


def explain(
    exc: BaseException, doing: str, queues: list[QueueSize] | None = None, shm_bytes: int = 0
) -> ResourceLimitError | None:
    """The OS limit behind `exc`, raised while `doing` (e.g. "creating queue /pbo.x.events"), or None if none is.

    `queues`: the run's queues, when a queue was being made (what the run needs); `shm_bytes`:
    the size of the segment being made in /dev/shm.
    """
    if isinstance(exc, ResourceLimitError):
        return exc  # named already, where it was met
    number = error_number(exc)
    if number == errno.EMFILE:
        if queues is not None and not _files_exhausted():
            return ResourceLimitError(_queue_memory_message(doing, queues))
        return ResourceLimitError(_open_files_message(doing))
    if number == errno.ENFILE:
        return ResourceLimitError(
            f"{doing}: the machine's table of open files is full (fs.file-max = {_read_int('/proc/sys/fs/file-max')}): "
            "close other programs or raise it (sysctl fs.file-max=2000000)")
    if number == errno.ENOSPC and queues is not None:
        return ResourceLimitError(f"{doing}: " + _queues_max_message(len(queues), queue_system_limit("queues_max", 256),
                                                                     _queues_in_use()))
    if number in (errno.ENOSPC, errno.EDQUOT):
        return ResourceLimitError(_shm_full_message(doing, shm_bytes))
    if number == errno.EINVAL and queues is not None and isinstance(exc, ValueError):
        longest = max(q.message_bytes for q in queues)
        deepest = max(q.depth for q in queues)
        return ResourceLimitError(
            f"{doing}: the system refused a queue of {deepest} messages of {longest} bytes (fs.mqueue.msg_max = "
            f"{queue_system_limit('msg_max', 10)}, msgsize_max = {queue_system_limit('msgsize_max', 8192)}): raise them "
            f"(sysctl fs.mqueue.msg_max={max(deepest, 10)} fs.mqueue.msgsize_max={max(longest, 8192)})")
    if number == errno.ENOMEM:
        return ResourceLimitError(f"{doing}: the machine is out of memory: stop other programs or runs (pbo runs)")
    return None


def _files_exhausted() -> bool:
    """True when this process has (nearly) every file descriptor RLIMIT_NOFILE allows open."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return soft != resource.RLIM_INFINITY and _open_files() >= soft - 1


def _open_files() -> int:
    try:
        return len(os.listdir("/proc/self/fd")) - 1  # the listing's own descriptor
    except OSError:
        return -1


def _queue_memory_message(doing: str, queues: list[QueueSize]) -> str:
    total = sum(q.bytes for q in queues)
    limit = queue_memory_limit()
    return (f"{doing}: the per-user POSIX message-queue memory RLIMIT_MSGQUEUE ({_kib(limit)}) is used up: this run needs "
            f"{_kib(total)} and other queues of this user hold the rest; stop other runs (pbo runs) or raise it "
            f"(ulimit -q {_raise_to(limit + total)})")


def _open_files_message(doing: str) -> str:
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return (f"{doing}: too many open files: this process has all that RLIMIT_NOFILE (ulimit -n) allows, {soft}, open; "
            f"raise it (ulimit -n {max(1024, 4 * soft)})")


def _shm_full_message(doing: str, needed: int) -> str:
    facts = [f"this needs {_kib(needed)}"] if needed else []
    try:
        space = os.statvfs("/dev/shm")
        facts.append(f"{_kib(space.f_bavail * space.f_frsize)} free of {_kib(space.f_blocks * space.f_frsize)}")
    except OSError:
        pass
    return (f"{doing}: /dev/shm is full ({'; '.join(facts) or 'no space left'}): remove what dead runs left (pbo clean), "
            "stop other runs (pbo runs), or enlarge it (mount -o remount,size=1G /dev/shm)")


def _read_int(path: str) -> str:
    try:
        return Path(path).read_text().strip()
    except OSError:
        return "?"
