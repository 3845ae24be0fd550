"""Removing what dead runs left: what `pbo run` does before it starts and `pbo clean` does on demand.

The rules, since /dev/shm is writable by every user and root may be the one cleaning:

- only objects this process trusts are touched (`shm.distrust`: owned by its effective uid, mode
  0600); the others are counted, with the reason, and left alone;
- a run is removed only when none of its processes is alive: the pid in its run id (the
  supervisor, unless that pid was reused: `ipc.runs.supervisor_alive`), and every child pid its
  table's manifest records (`pid <pid> <role>` lines: the plant and the RTPUs, which may outlive a
  supervisor killed outright);
- a table's manifest names the run's queues, which cannot be listed where /dev/mqueue is not
  mounted; an entry is followed only when it names an object of that same run (same subsystem
  and run id as the table that holds it), and only if that object, looked at, is trusted too.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import posix_ipc

from pbo_runtime.ipc import runs, shm
from pbo_runtime.table.table import HEADER_WORDS, Header, read_manifest

KINDS = ("shm", "sem", "mq")


@dataclass
class Cleanup:
    """What a cleanup did: the names it removed, the runs it left because they live, what it did not trust."""

    removed: list[str] = field(default_factory=list)
    live: list[str] = field(default_factory=list)  # run ids of runs with a process alive
    ignored: dict[str, str] = field(default_factory=dict)  # name -> why it was not touched

    def ignored_summary(self) -> str:
        """'2 owned by uid 65534, 1 mode 0666, not 0600' (empty when nothing was ignored)."""
        counts = Counter(self.ignored.values())
        return ", ".join(f"{n} {why}" for why, n in sorted(counts.items()))


def remove_dead_runs(subsystem: str | None = None) -> Cleanup:
    """Unlink what dead runs (of `subsystem`, or of every subsystem) left, their queues included."""
    cleanup = Cleanup()
    by_run: dict[tuple[str, str], list[shm.Listed]] = {}
    for listed in shm.list_objects(subsystem):
        if listed.distrust is not None:
            cleanup.ignored[listed.name] = listed.distrust
        else:
            by_run.setdefault((listed.subsystem, listed.run_id), []).append(listed)
    for (sub, run_id), objects in sorted(by_run.items()):
        table = next((o.name for o in objects if o.kind == "shm" and o.part == "table"), None)
        entries, pids = read_run_manifest(table) if table is not None else ([], [])
        supervisor = runs.supervisor_alive(objects[0].pid, table) if table is not None else shm.pid_alive(objects[0].pid)
        if supervisor or any(shm.pid_alive(pid) for pid in pids):
            cleanup.live.append(run_id)
            continue
        _remove(sub, run_id, objects, table, entries, cleanup)
    cleanup.removed.sort()
    return cleanup


def unlink_run(manifest: list[str], subsystem: str, run_id: str) -> None:
    """At a run's end, once every child is gone: what its manifest lists (a backstop: whatever a child
    could not remove), and what a child made under the run's name that the manifest does not list (a
    special-purpose processor's memory, made by its driver in a task)."""
    for entry in manifest:
        kind, _, name = entry.partition(" ")
        shm.unlink_quietly(kind, name)
    for listed in shm.list_objects(subsystem):
        if listed.run_id == run_id and listed.distrust is None:
            shm.unlink_quietly(listed.kind, listed.name)


def remove_run(subsystem: str, run_id: str) -> Cleanup:
    """Unlink every object of one run, alive or not: for the run's last process out (`last_out`), which knows."""
    cleanup = Cleanup()
    objects = []
    for listed in shm.list_objects(subsystem):
        if listed.run_id != run_id:
            continue
        if listed.distrust is not None:
            cleanup.ignored[listed.name] = listed.distrust
        else:
            objects.append(listed)
    table = next((o.name for o in objects if o.kind == "shm" and o.part == "table"), None)
    entries = read_run_manifest(table)[0] if table is not None else []
    _remove(subsystem, run_id, objects, table, entries, cleanup)
    cleanup.removed.sort()
    return cleanup


def _remove(subsystem: str, run_id: str, objects: list[shm.Listed], table: str | None, entries: list[tuple[str, str]],
            cleanup: Cleanup) -> None:
    """Unlink a run's listed objects and those of its manifest's entries that name an object of the run, the table last."""
    names = {(o.kind, o.name) for o in objects}
    names |= {(kind, name) for kind, name in entries if shm.run_of(name) == (subsystem, run_id)}
    for kind, name in sorted(names, key=lambda n: n[0] == "shm" and n[1] == table):  # the table last
        exists, why = shm.look_at(kind, name)
        if not exists:
            continue
        if why is not None:
            cleanup.ignored[name] = why
        elif shm.unlink_quietly(kind, name):
            cleanup.removed.append(name)


def read_run_manifest(table: str) -> tuple[list[tuple[str, str]], list[int]]:
    """((kind, name) of each object, pids of the run's processes) from a table's manifest; empty if unreadable."""
    try:
        mapping = shm.attach_segment(table, read_only=True)
    except (posix_ipc.Error, OSError, ValueError):
        return [], []
    try:
        if len(mapping) < HEADER_WORDS * 8:
            return [], []
        header = np.frombuffer(mapping, dtype=np.int64, count=HEADER_WORDS)
        offset = int(header[Header.MANIFEST_OFFSET])
        del header  # no view may outlive the mapping
        lines = read_manifest(mapping, offset) if 0 < offset < len(mapping) else []
    finally:
        mapping.close()
    entries, pids = [], []
    for line in lines:
        kind, _, rest = line.partition(" ")
        if kind in KINDS:
            entries.append((kind, rest))
        elif kind == "pid" and rest.split(" ", 1)[0].isdigit():
            pids.append(int(rest.split(" ", 1)[0]))
    return entries, pids
