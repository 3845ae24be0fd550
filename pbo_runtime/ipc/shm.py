"""Naming, creating, listing and removing the run's POSIX shared-memory objects and queues.

Every object of a run is named `/pbo.<subsystem>.<run id>.<part>`, created 0600, and removed on
every exit path. The run id is the supervisor's pid and a random nonce (`new_run_id`), so two runs
never share a name and objects whose pid is gone are a dead run's leftovers.

/dev/shm (and /dev/mqueue) are writable by every user, so a name proves nothing: anyone may create
`pbo.puma.1-abcdef.table`. An object is trusted only when it is owned by this process's effective
uid with mode 0600 (`distrust` says why not); everything that finds a run or cleans up lists
objects through `list_objects`, which marks the others, and never acts on them. Cleaning up is
`supervisor.cleanup`'s.
"""

from __future__ import annotations

import mmap
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

import posix_ipc

from pbo_runtime.ipc import limits

PREFIX = "pbo."
SHM_DIR = Path("/dev/shm")
MQUEUE_DIR = Path("/dev/mqueue")
NAME = re.compile(r"^pbo\.(?P<sub>[A-Za-z0-9_-]+)\.(?P<pid>\d+)-(?P<nonce>[0-9a-f]+)\.(?P<part>[A-Za-z0-9_.-]+)$")


def object_name(subsystem: str, run_id: str, part: str) -> str:
    """The POSIX name (with the leading slash) of one object of a run."""
    return f"/{PREFIX}{subsystem}.{run_id}.{part}"


def new_run_id() -> str:
    return f"{os.getpid()}-{os.urandom(3).hex()}"


def create_segment(name: str, size: int) -> tuple[posix_ipc.SharedMemory, mmap.mmap]:
    """Create a 0600 segment that must not exist yet, mapped and zeroed.

    Its pages are allocated now: on a full /dev/shm the creation fails with a ResourceLimitError
    naming the space needed, where a sparse segment would kill the first process to write a page
    the file system cannot give (SIGBUS).
    """
    doing = f"creating shared memory {name}"
    try:
        shm = posix_ipc.SharedMemory(name, posix_ipc.O_CREX, mode=0o600, size=size)
    except (OSError, ValueError, posix_ipc.Error) as exc:
        error = limits.explain(exc, doing, shm_bytes=size)
        if error is None:
            raise
        raise error from None
    try:
        os.posix_fallocate(shm.fd, 0, size)
        mapping = mmap.mmap(shm.fd, shm.size)
    except OSError as exc:
        shm.close_fd()
        shm.unlink()
        error = limits.explain(exc, doing, shm_bytes=size)
        if error is None:
            raise
        raise error from None
    finally:
        if shm.fd >= 0:
            shm.close_fd()
    return shm, mapping


def attach_segment(name: str, read_only: bool = False) -> mmap.mmap:
    """Map an existing segment whole (posix_ipc.ExistentialError if it is not there)."""
    shm = posix_ipc.SharedMemory(name, read_only=read_only)
    try:
        return mmap.mmap(shm.fd, shm.size, access=mmap.ACCESS_READ if read_only else mmap.ACCESS_DEFAULT)
    finally:
        shm.close_fd()


def unlink_quietly(kind: str, name: str) -> bool:
    """Unlink a segment ('shm'), semaphore ('sem') or queue ('mq'); False if it was not there."""
    unlink = {
        "shm": posix_ipc.unlink_shared_memory,
        "sem": posix_ipc.unlink_semaphore,
        "mq": posix_ipc.unlink_message_queue,
    }[kind]
    try:
        unlink(name)
        return True
    except posix_ipc.ExistentialError:
        return False


def pid_alive(pid: int) -> bool:
    """True while process `pid` runs. A zombie (dead, not yet reaped by its parent) is dead.

    The one liveness check of the runtime: a lock, a device or a link role whose holder is a
    zombie is recovered like that of a process that is gone.
    """
    if pid <= 0:
        return False  # 0 and negative pids name process groups, never a holder
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # it exists, under another user
    try:
        stat = (Path("/proc") / str(pid) / "stat").read_text()
    except FileNotFoundError:
        return False  # it was reaped between the two looks
    except OSError:
        return True  # no /proc here: the signal's answer stands
    return stat.rsplit(")", 1)[-1].split()[0] not in ("Z", "X")  # the state follows the command name


def pid_state(pid: int) -> str:
    """The one-letter state of process `pid` from /proc ('R', 'S', 'D', 'T' stopped, 't' traced,
    'Z' zombie, ...), or '' if there is no such process (or no /proc to ask)."""
    if pid <= 0:
        return ""
    try:
        stat = (Path("/proc") / str(pid) / "stat").read_text()
    except OSError:
        return ""
    return stat.rsplit(")", 1)[-1].split()[0]


def children_of(pid: int) -> dict[int, str]:
    """pid -> command line of the live children of `pid` (from /proc; empty where there is none)."""
    found = {}
    for entry in _entries(Path("/proc")):
        if not entry.isdigit():
            continue
        try:
            stat = (Path("/proc") / entry / "stat").read_text()
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found[int(entry)] = (Path("/proc") / entry / "cmdline").read_text().replace("\0", " ")
        except (OSError, IndexError, ValueError):
            continue
    return found


def distrust(status: os.stat_result) -> str | None:
    """Why an object with this status is not to be trusted; None when it is (ours, 0600, a plain file)."""
    if status.st_uid != os.geteuid():
        return f"owned by uid {status.st_uid}"
    if not stat.S_ISREG(status.st_mode):
        return "not a regular file"
    if stat.S_IMODE(status.st_mode) != 0o600:
        return f"mode {stat.S_IMODE(status.st_mode):04o}, not 0600"
    return None


@dataclass(frozen=True)
class Listed:
    """One object named like a run's, as listed: its kind ('shm', 'sem', 'mq'), POSIX name and run."""

    kind: str
    name: str  # with the leading slash
    subsystem: str
    run_id: str
    part: str
    distrust: str | None  # why it is not ours to use or remove; None: it is

    @property
    def pid(self) -> int:
        """The pid in its run id: the supervisor (or application runner) that made it."""
        return int(self.run_id.split("-", 1)[0])


def run_of(name: str) -> tuple[str, str] | None:
    """(subsystem, run id) of an object name (with or without its slash); None if it is not a run's name."""
    match = NAME.match(name.lstrip("/"))
    return (match["sub"], f"{match['pid']}-{match['nonce']}") if match else None


def list_objects(subsystem: str | None = None) -> list[Listed]:
    """Every object named like a run's (of `subsystem`, or of every subsystem), trusted or not.

    Segments and semaphores are listed in /dev/shm, queues in /dev/mqueue where it is mounted;
    where it is not, a run's queues are found through its table's manifest (`supervisor.cleanup`).
    Each is looked at with lstat, never followed or opened.
    """
    found: list[Listed] = []
    places = [(SHM_DIR, "shm"), (MQUEUE_DIR, "mq")]
    for directory, default_kind in places:
        for entry in _entries(directory):
            kind, base = ("sem", entry[4:]) if default_kind == "shm" and entry.startswith("sem.") else (default_kind, entry)
            match = NAME.match(base)
            if not match or (subsystem and match["sub"] != subsystem):
                continue
            try:
                status = os.lstat(directory / entry)
            except OSError:
                continue  # removed while we looked
            found.append(Listed(kind, "/" + base, match["sub"], f"{match['pid']}-{match['nonce']}", match["part"],
                                distrust(status)))
    return found


def look_at(kind: str, name: str) -> tuple[bool, str | None]:
    """(exists, why it is not to be trusted) for one object named by a manifest.

    A segment or semaphore is looked at in /dev/shm; a queue in /dev/mqueue where that is mounted,
    else through the queue's own descriptor (opened, never read or written).
    """
    base = name.lstrip("/")
    if kind == "mq" and not _mounted(MQUEUE_DIR):
        try:
            queue = posix_ipc.MessageQueue(name)
        except posix_ipc.ExistentialError:
            return False, None
        except (posix_ipc.Error, OSError, ValueError) as exc:
            return True, f"cannot be opened ({exc})"
        try:
            return True, distrust(os.fstat(queue.mqd))
        finally:
            queue.close()
    path = {"shm": SHM_DIR / base, "sem": SHM_DIR / f"sem.{base}", "mq": MQUEUE_DIR / base}[kind]
    try:
        return True, distrust(os.lstat(path))
    except FileNotFoundError:
        return False, None


def _mounted(directory: Path) -> bool:
    return directory.is_dir() and os.path.ismount(directory)


def _entries(directory: Path) -> list[str]:
    try:
        return sorted(os.listdir(directory))
    except OSError:  # not there, or not mounted
        return []
