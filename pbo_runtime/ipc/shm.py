"""Naming, creating and removing the run's POSIX shared-memory objects and queues.

Every object of a run is named `/pbo.<subsystem>.<run id>.<part>`, created 0600, and removed on
every exit path. The run id embeds the supervisor's pid, so objects whose pid is gone are a dead
run's leftovers (`stale_objects`); the supervisor removes them, queues included, through the
manifest the dead run's table keeps (`supervisor.children.remove_dead_runs`).
"""

from __future__ import annotations

import mmap
import os
import re
from pathlib import Path

import posix_ipc

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
    """Create a 0600 segment that must not exist yet, mapped and zeroed."""
    shm = posix_ipc.SharedMemory(name, posix_ipc.O_CREX, mode=0o600, size=size)
    try:
        mapping = mmap.mmap(shm.fd, shm.size)
    finally:
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


def stale_objects(subsystem: str | None = None) -> list[tuple[str, str]]:
    """(kind, name) of objects whose creating run is dead.

    Segments and semaphores are listed in /dev/shm, queues in /dev/mqueue where it is mounted;
    where it is not, a run's queues are found through its table's manifest (`remove_dead_runs`).
    """
    found: list[tuple[str, str]] = []
    listed = [("sem", e[4:]) if e.startswith("sem.") else ("shm", e) for e in _entries(SHM_DIR)]
    listed += [("mq", e) for e in _entries(MQUEUE_DIR)]  # where mounted: queues that no table's manifest lists
    for kind, base in listed:
        match = NAME.match(base)
        if not match or (subsystem and match["sub"] != subsystem):
            continue
        if not pid_alive(int(match["pid"])):
            found.append((kind, "/" + base))
    return found


def _entries(directory: Path) -> list[str]:
    try:
        return sorted(os.listdir(directory))
    except OSError:  # not there, or not mounted
        return []
