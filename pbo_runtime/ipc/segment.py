"""A POSIX shared-memory segment with its process-shared lock: what the state table and a periodic link are made of.

The segment `<name>` and its lock `<name>.lock` (a semaphore of initial value 1) are created
together, both 0600 and both new, and the creator unlinks both when it closes. A few int64 words
of the segment's header belong to the lock (the lock record): `holder_word`, the pid of its last
holder; `recoveries_word`, how many times a lock whose holder died was released; and, for a
segment read by observers that never take the lock, `sequence_word`, a seqlock: a writer makes
it odd before it writes under the lock and even after, so a reader that copies without the lock
knows whether its copy is whole (`table.snapshot`). The odd value is the writer's tag, 2 pid + 1,
and the even value after is the one before plus 2: so a write signs the lock with the sequence
alone (two integer stores), and every other acquire signs the holder word. The lock's holder is
the tag's pid while the sequence is odd, else the holder word's. Where the words lie is the
user's layout (`table.table`, `links.triple_buffer`); what they mean is here.

A holder that dies holding the lock must not wedge the others: `recover_lock_from`
releases it when the lock record still names the dead pid (and makes an odd sequence even: the
dead writer's half-written values are what the table holds now), and `wait_for_lock` does that
by itself for a waiter that finds the holder dead. The per-cycle paths take `lock` and their
header words directly; nothing here stands between them and the semaphore.
"""

from __future__ import annotations

import contextlib
import mmap
import os
import time
from collections.abc import Callable

import posix_ipc

from pbo_runtime.ipc import process, shm

Check = Callable[[mmap.mmap | memoryview], None]  # raises when a mapped segment is not what its user expects


class MissingLockError(posix_ipc.ExistentialError):  # type: ignore[misc]  # posix_ipc ships no types
    """The segment is there, its lock is not: it is half removed (its run is ending or crashed)."""


class LockedSegment:
    """One mapping of a segment and its lock. `create` makes both; `attach` opens them."""

    def __init__(self, name: str, mapping: mmap.mmap, lock: posix_ipc.Semaphore, owner: bool, *,
                 holder_word: int, recoveries_word: int, sequence_word: int | None = None) -> None:
        self.name = name
        self.lock_name = name + ".lock"
        self.mapping = mapping
        self.lock = lock
        self.owner = owner  # the creator: its close unlinks the segment and the lock
        self.holder_word = holder_word
        self.recoveries_word = recoveries_word
        self.sequence_word = sequence_word
        last = max(holder_word, recoveries_word, -1 if sequence_word is None else sequence_word)
        # a memoryview: its item stores cost about half a numpy scalar store, on the per-cycle path
        self.words = memoryview(mapping)[: (last + 1) * 8].cast("q")
        self._pid = os.getpid()

    @classmethod
    def create(cls, name: str, size: int, *, holder_word: int, recoveries_word: int,
               sequence_word: int | None = None) -> LockedSegment:
        """Create the segment (zeroed) and its lock, both 0600 and both new."""
        shm_object, mapping = shm.create_segment(name, size)
        try:
            lock = posix_ipc.Semaphore(name + ".lock", posix_ipc.O_CREX, mode=0o600, initial_value=1)
        except BaseException:
            mapping.close()
            shm_object.unlink()
            raise
        return cls(name, mapping, lock, owner=True, holder_word=holder_word, recoveries_word=recoveries_word,
                   sequence_word=sequence_word)

    @classmethod
    def attach(cls, name: str, *, holder_word: int, recoveries_word: int, sequence_word: int | None = None,
               check: Check | None = None, read_only: bool = False) -> LockedSegment:
        """Map an existing segment, let `check` refuse it, then open its lock.

        posix_ipc.ExistentialError if there is no segment `name`, MissingLockError if it has no
        lock; whatever `check` raises if the mapping (empty for a segment being created) is not
        what the caller expects. A read-only mapping serves tools that never write.
        """
        try:
            mapping = shm.attach_segment(name, read_only=read_only)
        except ValueError:  # an empty segment cannot be mapped: its creator has not sized it yet
            if check is not None:
                check(memoryview(b""))
            raise
        try:
            if check is not None:
                check(mapping)
            try:
                lock = posix_ipc.Semaphore(name + ".lock")
            except posix_ipc.ExistentialError:
                raise MissingLockError(f"segment '{name}' has no lock '{name}.lock'") from None
        except BaseException:
            mapping.close()
            raise
        return cls(name, mapping, lock, owner=False, holder_word=holder_word, recoveries_word=recoveries_word,
                   sequence_word=sequence_word)

    # --- the lock -----------------------------------------------------------------------------

    def acquire(self) -> None:
        """Take the lock, waiting as long as it takes, and sign the holder word."""
        self.lock.acquire()
        self.words[self.holder_word] = self._pid

    def release(self) -> None:
        self.lock.release()

    def acquire_watching(self, slice_seconds: float, while_waiting: Callable[[], None]) -> None:
        """Take the lock and sign it, calling `while_waiting` after every `slice_seconds` of the wait.

        For a process that must never block for good on another's lock (job control): its
        `while_waiting` looks after the holder and may raise to give up. A signal (Ctrl-C) ends
        a slice early instead of surfacing as posix_ipc.SignalError.
        """
        lock = self.lock
        while True:
            try:
                lock.acquire(slice_seconds)
                break
            except (posix_ipc.BusyError, posix_ipc.SignalError):
                while_waiting()
        self.words[self.holder_word] = self._pid

    @property
    def holder(self) -> int:
        """The pid of the lock's last holder (0: none yet, or its lock was recovered): a writer's while the sequence is odd."""
        if self.sequence_word is not None:
            sequence = self.words[self.sequence_word]
            if sequence & 1:
                return sequence >> 1
        return self.words[self.holder_word]

    @property
    def recoveries(self) -> int:
        return self.words[self.recoveries_word]

    @property
    def held(self) -> bool:
        """Whether someone holds the lock now (a look, not a wait)."""
        value: int = self.lock.value
        return value == 0

    @property
    def writer_tag(self) -> int:
        """What this process's writes make the sequence while they write: odd, and naming it."""
        return 2 * self._pid + 1

    def begin_write(self) -> int:
        """Under the lock, before writing what observers read: the sequence odd; pass the result to `end_write`."""
        assert self.sequence_word is not None
        before = self.words[self.sequence_word]  # even: a writer that died mid-write left it odd, and its recovery evened it
        self.words[self.sequence_word] = self.writer_tag
        return before

    def end_write(self, before: int) -> None:
        """Under the lock, after writing: the sequence even again, 2 past what it was before."""
        assert self.sequence_word is not None
        self.words[self.sequence_word] = before + 2

    @property
    def sequence(self) -> int:
        """The seqlock's value: odd while a writer writes (0 for a segment without one)."""
        return 0 if self.sequence_word is None else self.words[self.sequence_word]

    def wait_for_lock(self, patience: float) -> None:
        """Take the lock, which another process holds or held when it died; the caller signs it.

        Every `patience` seconds of the wait the holder is looked at: a dead one's lock is
        released (`recover_lock_from`) and taken. A stop requested meanwhile is raised.
        """
        lock = self.lock
        while True:
            try:
                lock.acquire(patience)
                return
            except posix_ipc.BusyError:
                holder = self.holder
                if holder not in (0, self._pid) and not shm.pid_alive(holder):
                    self.recover_lock_from(holder)
            except posix_ipc.SignalError:
                process.raise_if_stopping()

    def recover_lock_from(self, dead_pid: int, settle: float = 0.05) -> bool:
        """Release the lock if `dead_pid` died holding it; True if it was released.

        The lock record is signed right after each acquire, so a live process that took the
        lock after the dead one would have overwritten it within microseconds: it is checked
        over `settle` seconds before the lock is released. A write sequence left odd by the
        dead process needs no settling: only the holder makes it odd, and evens it before it
        releases, so the dead process died holding the lock.
        """
        lock, words = self.lock, self.words
        died_writing = self.sequence_word is not None and words[self.sequence_word] == 2 * dead_pid + 1
        for _ in range(1 if died_writing else 5):
            if lock.value > 0 or self.holder != dead_pid:
                return False
            if not died_writing:
                time.sleep(settle / 5)
        words[self.holder_word] = 0
        words[self.recoveries_word] += 1
        if self.sequence_word is not None and words[self.sequence_word] & 1:
            # It died mid-write: observers read what it left rather than give up for good. The
            # even value before its write is lost; twice the monotonic clock in ns is above any
            # value writes (2 per write) reached, so no reader takes it for the one it saw before.
            words[self.sequence_word] = 2 * time.monotonic_ns()
        lock.release()
        return True

    # --- life ---------------------------------------------------------------------------------

    def close(self) -> None:
        """Unmap and close the lock (and, for the creator, unlink both). Twice is harmless.

        The user drops its own views first; one still alive elsewhere keeps the mapping until
        it goes, and the unlink still frees the names.
        """
        if self.mapping is None:
            return
        self.words.release()
        with contextlib.suppress(BufferError):
            self.mapping.close()
        self.mapping = None  # type: ignore[assignment]
        with contextlib.suppress(posix_ipc.ExistentialError):
            self.lock.close()
        if self.owner:
            self.unlink()

    def unlink(self) -> None:
        """Remove the names of the segment and the lock (whoever still maps them keeps them)."""
        shm.unlink_quietly("shm", self.name)
        shm.unlink_quietly("sem", self.lock_name)
