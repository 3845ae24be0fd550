"""Lock-free snapshots of the state table, for everyone who reads it without being an RTPU.

`pbo svar`, `pbo status` and job control's own reads (conditions, final values) never take the
table lock: a process stopped or killed while holding it would otherwise wedge every RTPU. They
read under the table's seqlock instead: every writer, under the lock it takes anyway, makes the
header's sequence word odd before it writes and even after (`LockedSegment.begin_write`); a reader
reads the sequence, copies the bytes it needs, and keeps the copy only if the sequence was even
and has not moved. Otherwise it tries again, a
bounded number of times, and then gives up with `TableBusy`: a reader never waits on a writer.

Aligned 8-byte words are read and written whole and x86 keeps loads, and stores, in program
order (TSO), so the sequence needs no fences there; the copy itself is a C call between the two
loads of the sequence.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

from pbo_runtime.errors import PboError

T = TypeVar("T")

SNAPSHOT_TRIES = 200  # copies tried before a reader gives up: a writer holds the lock for microseconds ...
SNAPSHOT_SPIN = 20  # ... so the first tries follow each other at once, the rest after a nap
SNAPSHOT_NAP = 0.0002  # seconds between the later tries: about 36 ms in all before "table busy"


class TableBusy(PboError):
    """The table's sequence stayed odd, or kept moving, through every try: a writer stopped mid-write."""


class Seqlock:
    """The reader's side of a segment's sequence word (`words[word]`, an int64 memoryview)."""

    def __init__(self, words: memoryview, word: int, name: str) -> None:
        self._words = words
        self._word = word
        self.name = name

    def read(self, copy: Callable[[], T]) -> T:
        """`copy()`'s result from a moment no writer was writing; TableBusy after SNAPSHOT_TRIES tries.

        `copy` must copy (never return views into the table) and must not fail on a torn state.
        """
        words, word = self._words, self._word
        for attempt in range(SNAPSHOT_TRIES):
            before = words[word]
            if not before & 1:
                result = copy()
                if words[word] == before:
                    return result
            if attempt >= SNAPSHOT_SPIN:
                time.sleep(SNAPSHOT_NAP)
        raise TableBusy(f"table busy: '{self.name}' was being written through all {SNAPSHOT_TRIES} tries to read it "
                        f"(a writer stopped or killed mid-write; the run's supervisor recovers the lock): try again")
