"""Periodic links between subsystems: a triple buffer in POSIX shared memory (TR §5.2, Figure 15).

One sender and one reader, each in its own process, exchange a fixed-size item (a numpy dtype and
shape given at creation). The sender never waits for the reader and the reader always gets the
newest complete item, because of three slots one is always free: the sender fills the slot that
is neither the newest nor the one being read, then publishes it; the reader takes the newest.
Only the index swap is a critical section, under a process-shared semaphore held for a few
Python statements; no copy ever happens under it. docs/subsystems.md draws the protocol.

Layout of the segment `<name>` (0600; its lock is the semaphore `<name>.lock`):

    header     HEADER_BYTES: int64 words (`Word`), then the payload's description as text
    slot 0..2  each SLOT_HEADER_BYTES (int64 counter, int64 CLOCK_MONOTONIC ns time stamp)
               followed by the payload, padded to a multiple of 64 bytes

The header's slot indices change only under the lock: NEWEST (the last published slot, or
NO_SLOT), READING (the slot the reader holds, or NO_SLOT) and WRITING (the sender's next slot,
kept so that a new sender can take over from a dead one). Invariant, held at every release of
the lock: WRITING is neither NEWEST nor READING. Each side writes its pid after every acquire,
so a lock whose holder died is recovered, as the table's is (`recover_lock_from`).
"""

from __future__ import annotations

import enum
import hashlib
import mmap
import os
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import posix_ipc
from numpy.typing import ArrayLike

from pbo_runtime.errors import PboError
from pbo_runtime.ipc import shm as _shm
from pbo_runtime.ipc.segment import LockedSegment, MissingLockError

MAGIC = 0x5042_4F5F_5452_4942  # "PBO_TRIB"
VERSION = 1
SLOTS = 3
NO_SLOT = -1
HEADER_BYTES = 512
HEADER_WORDS = 32  # int64 words; the description text follows them
DESCRIPTION_BYTES = HEADER_BYTES - HEADER_WORDS * 8
SLOT_HEADER_BYTES = 64  # counter and time stamp, padded so that each payload starts on a cache line
ALIGN = 64
LOCK_PATIENCE = 0.02  # seconds a waiter waits before it checks whether the lock's holder is alive


class Word(enum.IntEnum):
    """Word indices in the int64 header."""

    MAGIC = 0
    VERSION = 1
    LAYOUT_HASH = 2
    TOTAL_BYTES = 3
    PAYLOAD_BYTES = 4
    SLOT_BYTES = 5
    CREATOR_PID = 6
    CREATED_NS = 7
    LOCK_HOLDER = 8  # pid of the last process that acquired the lock
    LOCK_RECOVERIES = 9  # times a lock whose holder died was released
    SENDER_PID = 10  # 0: no sender attached
    READER_PID = 11  # 0: no reader attached
    NEWEST = 12
    READING = 13
    WRITING = 14


# The words of the per-item paths as plain ints: an enum member costs a lookup at each use.
_NEWEST, _READING, _WRITING, _LOCK_HOLDER = int(Word.NEWEST), int(Word.READING), int(Word.WRITING), int(Word.LOCK_HOLDER)
_LOCK_WORDS: dict[str, Any] = {"holder_word": _LOCK_HOLDER, "recoveries_word": int(Word.LOCK_RECOVERIES)}


class Role(enum.StrEnum):
    """Which end of a link a process holds; a link has at most one live process in each."""

    SENDER = "sender"
    READER = "reader"


class Freshness(enum.IntEnum):
    """What one read got."""

    NONE = 0  # nothing published yet: the reader's array was left as it was
    REUSED = 1  # the same item as the previous read: the sender is slower than the reader
    NEW = 2  # an item newer than the previous read (`lost_in_last_read` says how many were skipped)


class LinkError(PboError):
    """A link is missing, or a process used it against its role (a second sender, a reader writing)."""


class LinkLayoutError(PboError):
    """A link's payload differs from what this process expects, or cannot live in shared memory."""


def _padded(nbytes: int) -> int:
    return -(-nbytes // ALIGN) * ALIGN


@dataclass(frozen=True)
class LinkLayout:
    """The fixed payload of a link: a numpy dtype (plain or structured) and a shape.

    Raw bytes are `LinkLayout.raw(n)`, i.e. uint8 of shape (n,).
    """

    dtype: np.dtype
    shape: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        try:
            dtype = np.dtype(self.dtype)
        except TypeError as exc:
            raise LinkLayoutError(f"payload dtype {self.dtype!r} is not a numpy dtype: {exc}") from None
        shape = tuple(int(n) for n in (self.shape if isinstance(self.shape, (tuple, list)) else (self.shape,)))
        if dtype.hasobject:
            raise LinkLayoutError(f"payload dtype {dtype} holds Python objects, which cannot live in shared memory")
        if any(n < 0 for n in shape):
            raise LinkLayoutError(f"payload shape must have sizes >= 0, got: {shape}")
        object.__setattr__(self, "dtype", dtype)
        object.__setattr__(self, "shape", shape)
        if self.nbytes == 0:
            raise LinkLayoutError(f"payload must have at least one byte, got: {self.description}")

    @classmethod
    def raw(cls, nbytes: int) -> LinkLayout:
        return cls(np.dtype(np.uint8), (nbytes,))

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    @property
    def slot_bytes(self) -> int:
        return SLOT_HEADER_BYTES + _padded(self.nbytes)

    @property
    def total_bytes(self) -> int:
        return HEADER_BYTES + SLOTS * self.slot_bytes

    @property
    def description(self) -> str:
        """What a person reads in an error: 'float64 (6,)' or a structured dtype's fields and shape."""
        kind = self.dtype.name if self.dtype.fields is None else str(self.dtype.descr)
        return f"{kind} {self.shape}"

    @property
    def layout_hash(self) -> int:
        exact = f"v{VERSION}|{np.lib.format.dtype_to_descr(self.dtype)!r}|{self.shape}|{self.slot_bytes}"
        return int.from_bytes(hashlib.blake2b(exact.encode(), digest_size=8).digest(), "little", signed=True)


@dataclass(frozen=True)
class LinkStatistics:
    """Counts of one end of a link since it was opened.

    For a reader, `new + lost` equals the advance of the counter from the newest item at attach
    (counted) to the last item read.
    """

    writes: int  # items published (sender)
    new: int  # reads that got a newer item (reader)
    reused: int  # reads that got the same item again (reader)
    lost: int  # items published but never read (reader)
    empty: int  # reads before anything was published (reader)
    contended: int  # lock acquisitions that had to wait (either end)
    lock_recoveries: int  # locks released after their holder died (whole link)


class ReaderTally:
    """A reader's account of the items it read: what every periodic link's reader keeps the same way.

    `_tally(counter, stamp_ns)` classifies one read of an item (after its copy) as NEW or REUSED
    and counts what was lost in between; `lost` and `reused` are cheap enough for a cycle.
    """

    name: str  # the link's, for messages
    counter = 0  # of the last item read; 0 until one is read (published counters start at 1)
    stamp_ns = 0  # its time stamp, CLOCK_MONOTONIC ns of the sender's machine
    local_stamp_ns = 0  # the same moment on this process's clock: judge an item's age from this one
    lost_in_last_read = 0
    _before_first = 0  # the counter just before the first item this reader counts
    _new = _reused = _lost = _empty = 0

    def _tally(self, counter: int, stamp_ns: int) -> Freshness:
        if counter == self.counter:
            self._reused += 1
            self.lost_in_last_read = 0
            return Freshness.REUSED
        assert counter > self.counter, f"link '{self.name}': counter went back from {self.counter} to {counter}"
        lost = counter - max(self.counter, self._before_first) - 1
        self.counter = counter
        self.stamp_ns = self.local_stamp_ns = stamp_ns  # one machine, one clock (a zenoh reader moves its own)
        self.lost_in_last_read = lost
        self._lost += lost
        self._new += 1
        return Freshness.NEW

    @property
    def lost(self) -> int:
        """Items published that this reader never read (a cheap read of one count, for a cycle)."""
        return self._lost

    @property
    def reused(self) -> int:
        """Reads that got the same item as the read before."""
        return self._reused


class TripleBuffer(ReaderTally):
    """One process's end of a periodic link. `create` makes the link; `attach` opens it."""

    def __init__(self, layout: LinkLayout, segment: LockedSegment) -> None:
        self.layout = layout
        self.name = segment.name
        self.lock_name = segment.lock_name
        self._set_role(None)
        self._segment = segment
        self._mapping: mmap.mmap | None = segment.mapping
        mapping = segment.mapping
        self._lock = segment.lock
        self._pid = os.getpid()
        # Plain memoryviews for the few words touched per item: indexing one costs a fraction of
        # a numpy scalar access, and the critical section is made of nothing else.
        self._header = memoryview(mapping)[: HEADER_WORDS * 8].cast("q")
        self._slot_words = layout.slot_bytes // 8
        self._meta = memoryview(mapping)[HEADER_BYTES : layout.total_bytes].cast("q")
        self._payloads = tuple(
            np.frombuffer(
                mapping, dtype=layout.dtype, count=layout.size, offset=HEADER_BYTES + i * layout.slot_bytes + SLOT_HEADER_BYTES
            ).reshape(layout.shape)
            for i in range(SLOTS)
        )
        # sender
        self._writing = NO_SLOT
        self._published = 0
        self._writes = 0
        # reader
        self.value = np.zeros(layout.shape, dtype=layout.dtype)  # the reader's copy of the last item read
        self.counter = 0  # of the last item read; 0 until one is read (published counters start at 1)
        self.stamp_ns = 0  # its time stamp, CLOCK_MONOTONIC ns
        self.lost_in_last_read = 0
        self._before_first = 0  # the counter just before the first item this reader counts
        self._new = self._reused = self._lost = self._empty = 0
        self._contended = 0

    # --- life -------------------------------------------------------------------------------

    @property
    def owner(self) -> bool:
        """True for the creator, whose close unlinks the segment and the lock."""
        return self._segment.owner

    @classmethod
    def create(cls, name: str, layout: LinkLayout, role: Role | str | None = None) -> TripleBuffer:
        """Create the segment and its lock (both 0600, both new); optionally take one end of it."""
        role = _role(role)
        link = cls(layout, LockedSegment.create(name, layout.total_bytes, **_LOCK_WORDS))
        mapping, h = link._segment.mapping, link._header
        h[Word.VERSION] = VERSION
        h[Word.LAYOUT_HASH] = layout.layout_hash
        h[Word.TOTAL_BYTES] = layout.total_bytes
        h[Word.PAYLOAD_BYTES] = layout.nbytes
        h[Word.SLOT_BYTES] = layout.slot_bytes
        h[Word.CREATOR_PID] = os.getpid()
        h[Word.CREATED_NS] = time.monotonic_ns()
        h[Word.NEWEST] = NO_SLOT
        h[Word.READING] = NO_SLOT
        h[Word.WRITING] = 0
        text = layout.description.encode()[:DESCRIPTION_BYTES - 1]
        mapping[HEADER_WORDS * 8 : HEADER_WORDS * 8 + len(text)] = text
        h[Word.MAGIC] = MAGIC  # last: whoever sees the magic sees a complete header
        return link._take_role(role)

    def _take_role(self, role: Role | None) -> TripleBuffer:
        """This end, holding `role` (None: none yet); closed again if the role is taken."""
        if role is not None:
            try:
                self._claim(role)
            except BaseException:
                self.close()
                raise
        return self

    @classmethod
    def attach(cls, name: str, layout: LinkLayout, role: Role | str | None = None) -> TripleBuffer:
        """Open an existing link; a different payload fails clearly instead of corrupting it."""
        role = _role(role)

        def check(mapping: mmap.mmap | memoryview) -> None:
            problem = _layout_problem(name, mapping, layout)
            if problem:
                raise LinkLayoutError(problem)

        try:
            segment = LockedSegment.attach(name, check=check, **_LOCK_WORDS)
        except MissingLockError:
            raise LinkError(f"link '{name}' has no lock '{name}.lock': was it half removed?") from None
        except posix_ipc.ExistentialError:
            raise LinkError(f"no link '{name}': has the subsystem that creates it started?") from None
        link = cls(layout, segment)
        return link._take_role(role)

    def close(self) -> None:
        """Give up this end's role, unmap (and, for the creator, unlink the segment and the lock)."""
        if self._mapping is None:
            return
        try:
            if self.role is not None:
                self._release_role()
        finally:
            self._payloads = ()
            self._header.release()
            self._meta.release()
            self._mapping = None
            self._segment.close()  # a view from begin_write() still alive keeps the mapping, not the names

    def unlink(self) -> None:
        self._segment.unlink()

    def __enter__(self) -> TripleBuffer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # --- the sender ---------------------------------------------------------------------------

    def begin_write(self) -> np.ndarray:
        """The slot the next `publish` sends, as a view to fill in place (no copy, no allocation).

        The view stays the sender's until `publish`; do not keep it after.
        """
        if not self._is_sender:
            self._refuse(Role.SENDER, "write")
        return self._payloads[self._writing]

    def publish(self, stamp_ns: int | None = None) -> int:
        """Make the slot filled since `begin_write` the newest item; return its counter.

        `stamp_ns` is when the data was generated (CLOCK_MONOTONIC ns, `time.monotonic_ns()`);
        now if not given.
        """
        if not self._is_sender:
            self._refuse(Role.SENDER, "publish")
        return self._publish(time.monotonic_ns() if stamp_ns is None else stamp_ns)

    def write(self, value: ArrayLike, stamp_ns: int | None = None) -> int:
        """Copy `value` into the free slot and publish it; return its counter.

        `stamp_ns` defaults to the time of the call, before the copy.
        """
        if not self._is_sender:
            self._refuse(Role.SENDER, "write")
        if stamp_ns is None:
            stamp_ns = time.monotonic_ns()
        np.copyto(self._payloads[self._writing], value)
        return self._publish(stamp_ns)

    def _publish(self, stamp_ns: int) -> int:
        written = self._writing
        counter = self._published + 1
        meta, h, lock = self._meta, self._header, self._lock
        base = written * self._slot_words
        meta[base] = counter
        meta[base + 1] = stamp_ns
        try:
            lock.acquire(0)
        except posix_ipc.BusyError:
            self._wait_for_lock()
        h[_LOCK_HOLDER] = self._pid
        try:
            reading = h[_READING]
            following = (written + 1) % SLOTS if reading == NO_SLOT else SLOTS - written - reading
            h[_WRITING] = following
            h[_NEWEST] = written  # one aligned word: a reader sees the item before or this one, both complete
        finally:
            lock.release()
        assert reading != written, f"link '{self.name}': the sender filled the slot being read"
        self._writing = following
        self._published = counter
        self._writes += 1
        return counter

    # --- the reader ---------------------------------------------------------------------------

    def read(self, out: np.ndarray | None = None) -> Freshness:
        """Copy the newest complete item into `out` (default: `self.value`) and say what it was.

        The counter and time stamp of the item are then `self.counter` and `self.stamp_ns`; a
        NEW item's `self.lost_in_last_read` says how many items were published in between and
        never read. Nothing is allocated.
        """
        slot = self._take()
        if slot == NO_SLOT:
            self._empty += 1
            return Freshness.NONE
        return self._copy_out(slot, self.value if out is None else out)

    def _take(self) -> int:
        """The critical section of a read: mark the newest slot as being read (NO_SLOT if none).

        The slot stays marked until the reader's next read or close, so the sender never touches
        it while the copy runs (and the copy needs no lock).
        """
        if not self._is_reader:
            self._refuse(Role.READER, "read")
        h, lock = self._header, self._lock
        try:
            lock.acquire(0)
        except posix_ipc.BusyError:
            self._wait_for_lock()
        h[_LOCK_HOLDER] = self._pid
        try:
            newest = h[_NEWEST]
            if newest != NO_SLOT:
                h[_READING] = newest
        finally:
            lock.release()
        return newest

    def _copy_out(self, slot: int, out: np.ndarray) -> Freshness:
        base = slot * self._slot_words
        counter = self._meta[base]
        stamp_ns = self._meta[base + 1]
        np.copyto(out, self._payloads[slot])
        return self._tally(counter, stamp_ns)

    def statistics(self) -> LinkStatistics:
        return LinkStatistics(
            writes=self._writes,
            new=self._new,
            reused=self._reused,
            lost=self._lost,
            empty=self._empty,
            contended=self._contended,
            lock_recoveries=self._header[Word.LOCK_RECOVERIES],
        )

    # --- roles --------------------------------------------------------------------------------

    def _claim(self, role: Role) -> None:
        word = Word.SENDER_PID if role is Role.SENDER else Word.READER_PID
        h = self._header
        self._acquire()
        try:
            holder = h[word]
            if holder and _shm.pid_alive(holder):  # this very process too: two objects would share one slot
                raise LinkError(f"link '{self.name}' already has a {role}: pid {holder} (a link has one sender and one reader)")
            h[word] = self._pid
            newest, reading = h[Word.NEWEST], h[Word.READING]
            if role is Role.READER:
                h[Word.READING] = NO_SLOT  # a dead reader's mark
                if newest != NO_SLOT:
                    self._before_first = self._meta[newest * self._slot_words] - 1
            else:
                # A dead sender may have died in the middle of its swap: pick a free slot afresh.
                writing = h[Word.WRITING]
                if writing in (NO_SLOT, newest, reading):
                    writing = next(i for i in range(SLOTS) if i not in (newest, reading))
                    h[Word.WRITING] = writing
                self._writing = writing
                self._published = self._meta[newest * self._slot_words] if newest != NO_SLOT else 0
        finally:
            self._lock.release()
        self._set_role(role)

    def _release_role(self) -> None:
        word = Word.SENDER_PID if self.role is Role.SENDER else Word.READER_PID
        h = self._header
        self._acquire()
        try:
            if h[word] == self._pid:
                h[word] = 0
                if self.role is Role.READER:
                    h[Word.READING] = NO_SLOT
        finally:
            self._lock.release()
        self._set_role(None)

    def _set_role(self, role: Role | None) -> None:
        self.role = role
        self._is_sender = role is Role.SENDER  # plain bools for the per-item checks
        self._is_reader = role is Role.READER

    def _refuse(self, role: Role, action: str) -> None:
        held = f"as its {self.role}" if self.role else "with no role"
        raise LinkError(f"cannot {action} link '{self.name}': this process opened it {held}; only its {role} may")

    # --- the lock -----------------------------------------------------------------------------

    def _acquire(self) -> None:
        """Take the lock (inlined in `_publish` and `_take`, the per-item paths)."""
        try:
            self._lock.acquire(0)
        except posix_ipc.BusyError:
            self._wait_for_lock()
        self._header[_LOCK_HOLDER] = self._pid

    def _wait_for_lock(self) -> None:
        """The other side holds the lock (for its swap, microseconds) or died holding it."""
        self._contended += 1
        self._segment.wait_for_lock(LOCK_PATIENCE)

    def recover_lock_from(self, dead_pid: int, settle: float = 0.05) -> bool:
        """Release the lock if `dead_pid` died holding it; True if it was released.

        The swap a dead holder left half done leaves NEWEST and READING each pointing at a
        complete slot, and a sender that takes over picks its slot afresh (`_claim`).
        """
        return self._segment.recover_lock_from(dead_pid, settle)


def link_name(subsystem: str, run_id: str, link: str) -> str:
    """The POSIX name of a link's segment among the run's objects (its lock adds '.lock')."""
    return _shm.object_name(subsystem, run_id, f"link-{link}")


def _role(role: Role | str | None) -> Role | None:
    if role is None or isinstance(role, Role):
        return role
    try:
        return Role(role)
    except ValueError:
        raise LinkError(f"role must be one of {', '.join(r.value for r in Role)} (or None), got: {role!r}") from None


def _layout_problem(name: str, mapping: mmap.mmap | memoryview, layout: LinkLayout) -> str:
    if len(mapping) < HEADER_BYTES:
        return f"'{name}' is not a pbo link of version {VERSION} (only {len(mapping)} bytes)"
    header = memoryview(mapping)[: HEADER_WORDS * 8].cast("q")
    try:
        magic, version, found_hash, total = (header[w] for w in (Word.MAGIC, Word.VERSION, Word.LAYOUT_HASH, Word.TOTAL_BYTES))
    finally:
        header.release()
    if magic != MAGIC or version != VERSION:
        return f"'{name}' is not a pbo link of version {VERSION}"
    if found_hash != layout.layout_hash or total != layout.total_bytes or len(mapping) < layout.total_bytes:
        found = bytes(mapping[HEADER_WORDS * 8 : HEADER_BYTES]).split(b"\0", 1)[0].decode(errors="replace")
        if found == layout.description:  # same text, other bytes: another version's padding
            found, expected = f"{found} in {total} bytes", f"{layout.description} in {layout.total_bytes} bytes"
        else:
            expected = layout.description
        return f"link '{name}' carries {found}, this process expects {expected}: do both ends declare the same payload?"
    return ""
