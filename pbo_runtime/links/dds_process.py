"""A task's DDS work in a process of its own: records shared under a sequence lock, a wake, a hang-up.

Cyclone DDS's threads and the encoding of messages are Python work that holds the GIL; inside an
RTPU they would take it from the executive and delay its releases. So the DDS participant, its
readers and writers live in a child process (`python -m PROGRAM`, started at SCHED_OTHER), and the RTPU
and the child share only a memfd of records, each a sequence number then its values. The writer
of a record makes the number odd, writes the values, makes it even again; a reader copies the
values and uses them only when the number was even and the same before and after the copy, so a
record torn mid-write is never used. The RTPU's side reads once and, when the copy was torn,
keeps what it had (the child at SCHED_OTHER may be preempted mid-write: waiting for it could
hold a cycle); the child retries. An eventfd wakes the child for what the RTPU wrote. The lock
counts on each side's stores being seen in the order made, as x86-64 orders them; a weakly
ordered CPU (ARM) would want a fence around the values' copy.

The child says "ready" (or why it could not start) on a pipe before the task's init returns, and
ends when the other pipe, whose write end only the RTPU holds, closes: at the task's kill, or when
the RTPU died (the kernel closes its files). A memfd has no name: nothing is left in /dev/shm.
When the child ends on its own, a thread of the RTPU (asleep until then) says so on stderr and
sets `ended`, which the task reads on its cycle.
"""

from __future__ import annotations

import contextlib
import json
import math
import mmap
import os
import select
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from pbo_runtime.errors import ModuleError
from pbo_runtime.objects.helper_threads import below_the_cycle, process_below_the_cycle
from pbo_runtime.objects.waits import sleep_while_cycling

READY = b"ready"
START_PATIENCE = 60.0  # s an init waits for the child's "ready": importing cyclonedds on a loaded machine
COUNTERS = 4  # int64 words the child counts in (what each means is the program's)
WAIT = 1_000_000_000  # ns a reading thread of the child waits for a sample before it looks again


class SharedRecord:
    """A sequence number and `size` float64 `values` (`words`: the same bytes as int64) in shared memory."""

    def __init__(self, buffer: Any, offset: int, size: int) -> None:
        self.sequence = np.frombuffer(buffer, dtype=np.int64, count=1, offset=offset)
        self.values = np.frombuffer(buffer, dtype=np.float64, count=size, offset=offset + 8)
        self.words = self.values.view(np.int64)

    @staticmethod
    def bytes_for(size: int) -> int:
        return 8 * (1 + size)

    def begin(self) -> None:
        """Before the values are written: the number goes odd (no reader uses them meanwhile)."""
        self.sequence[0] += 1

    def end(self) -> None:
        """After: the number goes even again, one more record written."""
        self.sequence[0] += 1

    def read(self, into: np.ndarray) -> int:
        """Copy the values into `into`: the record's sequence number, or -1 when the copy may be torn
        (the writer was in the middle of it). No allocation beyond the numbers read."""
        before = int(self.sequence[0])
        np.copyto(into, self.values)
        if before & 1 or before != int(self.sequence[0]):
            return -1
        return before

    def read_settled(self, into: np.ndarray) -> int:
        """`read` until a copy is whole: for the child, which may wait for the RTPU's write to end."""
        while (taken := self.read(into)) < 0:
            time.sleep(0)
        return taken


def _layout(sizes: Sequence[int]) -> tuple[list[int], int]:
    offsets, at = [], 8 * COUNTERS
    for size in sizes:
        offsets.append(at)
        at += SharedRecord.bytes_for(size)
    return offsets, at


def _records(buffer: Any, sizes: Sequence[int]) -> tuple[np.ndarray, list[SharedRecord]]:
    offsets, _ = _layout(sizes)
    counters = np.frombuffer(buffer, dtype=np.int64, count=COUNTERS)
    return counters, [SharedRecord(buffer, offset, size) for offset, size in zip(offsets, sizes, strict=True)]


class DdsProcess:
    """The RTPU's handle on a child running `python -m program`: its `records`, `counters`, `wake`, `ended`, `close`.

    `what` names the child in messages ("task 'goal': its ROS 2 subscriber"); `if_it_ends` says what
    its ending means for the run. `keep_up`: once started, its threads run just below every
    executive (`process_below_the_cycle`), for an input a cycle needs fresh, which a child at
    SCHED_OTHER behind every ordinary process of a loaded machine would deliver late. ModuleError
    when the child could not start, saying why."""

    def __init__(self, program: str, setup: Mapping[str, Any], sizes: Sequence[int], what: str, if_it_ends: str,
                 keep_up: bool = False) -> None:
        self.what, self._if_it_ends = what, if_it_ends
        self.ended = ""  # why the child ended on its own; "" while it runs (or was closed)
        self._closing = False
        _, total = _layout(sizes)
        self._memfd = os.memfd_create("pbo-dds", os.MFD_CLOEXEC)
        os.ftruncate(self._memfd, total)
        self._shared = mmap.mmap(self._memfd, total)
        self.counters, self.records = _records(self._shared, sizes)
        self._wake = os.eventfd(0, os.EFD_CLOEXEC)
        hangup_read, self._hangup = os.pipe2(os.O_CLOEXEC)
        ready_read, ready_write = os.pipe2(os.O_CLOEXEC)
        child_fds = (self._memfd, self._wake, hangup_read, ready_write)
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", program, *map(str, child_fds), json.dumps({**setup, "sizes": list(sizes)})],
                pass_fds=child_fds, stdin=subprocess.DEVNULL)
        finally:
            os.close(hangup_read)
            os.close(ready_write)
        try:
            said = _read_until_closed(ready_read, START_PATIENCE)
        finally:
            os.close(ready_read)
        if said != READY:
            self.close()
            reason = said.decode(errors="replace").strip() or f"it ended with exit status {self.process.returncode}"
            raise ModuleError(f"{what} process did not start: {reason}")
        if keep_up:
            for thread in os.listdir(f"/proc/{self.process.pid}/task"):
                process_below_the_cycle(int(thread))
        self._watcher = threading.Thread(target=self._watch, args=(os.pidfd_open(self.process.pid),), daemon=True,
                                         name=f"watch-{self.process.pid}")
        self._watcher.start()

    def wake(self) -> None:
        """Wake the child for what was written (one system call, no allocation)."""
        os.eventfd_write(self._wake, 1)

    def hang_up(self) -> None:
        """Close the hang-up pipe: the child ends (at once; `close` waits for it)."""
        self._closing = True
        if self._hangup >= 0:
            os.close(self._hangup)
            self._hangup = -1

    def close(self, patience: float = 5.0) -> None:
        """Hang up and wait for the child; killed if it does not end within `patience`."""
        self.hang_up()
        try:
            self.process.wait(timeout=patience)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        if self._wake >= 0:
            os.close(self._wake)
            os.close(self._memfd)
            self._wake = -1

    def _watch(self, pidfd: int) -> None:
        """Asleep until the child ends; if nobody hung up, say so (once, outside every cycle)."""
        below_the_cycle()
        try:
            select.select([pidfd], [], [])
        finally:
            os.close(pidfd)
        if self._closing:
            return
        status = self.process.wait()
        self.ended = f"{self.what} process (pid {self.process.pid}) ended with exit status {status}"
        print(f"{self.ended}: {self._if_it_ends}", file=sys.stderr, flush=True)


def _read_until_closed(fd: int, patience: float) -> bytes:
    """What the child says before it closes its end (or `patience` runs out). Polled: in a live
    spawn's init the RTPU's other tasks go on cycling meanwhile (`sleep_while_cycling`)."""
    said = b""
    deadline = time.monotonic() + patience
    while time.monotonic() < deadline:
        if not select.select([fd], [], [], 0)[0]:
            sleep_while_cycling(0.005)
            continue
        chunk = os.read(fd, 4096)
        if not chunk:
            break
        said += chunk
    return said


# --- the child's side ------------------------------------------------------------------------------


class DdsChild:
    """What a program's `start` gets: the `setup`, the `records` and `counters`, and ways to serve them."""

    def __init__(self, setup: dict[str, Any], counters: np.ndarray, records: list[SharedRecord]) -> None:
        self.setup, self.counters, self.records = setup, counters, records
        self.on_wake: Callable[[], None] | None = None  # called once for each batch of wakes from the RTPU
        self._kept: list[Any] = []

    def keep(self, *entities: Any) -> None:
        """Keep DDS entities alive while the child serves (a node announced, a participant)."""
        self._kept.extend(entities)

    @staticmethod
    def say(line: str) -> None:
        """One line on the run's stderr (the child's is the RTPU's)."""
        print(line, file=sys.stderr, flush=True)

    def refuse(self, counter: int, why: Callable[[int], str]) -> None:
        """Count a refused message in `counters[counter]`; say `why(count)` at the 1st, 10th, 100th...
        (said before counted: whoever sees the count finds it said)."""
        refused = int(self.counters[counter]) + 1
        if math.log10(refused).is_integer():
            self.say(why(refused))
        self.counters[counter] = refused

    def take_in_thread(self, participant: Any, reader: Any, kind: type[Any], handle: Callable[[Any], None]) -> None:
        """Call `handle` with each message `reader` takes, in a thread of the child's own."""
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet

        waitset = WaitSet(participant)
        waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))

        def take() -> None:
            while True:
                waitset.wait(WAIT)  # releases the GIL until a sample comes
                for sample in reader.take(N=16):
                    if isinstance(sample, kind):  # (else a writer's end: DDS's invalid sample, not a message)
                        handle(sample)

        self.keep(waitset)
        threading.Thread(target=take, daemon=True, name="dds-take").start()


def serve_dds_process(start: Callable[[DdsChild], None]) -> None:
    """A child program's main: map the records, `start` (make the DDS entities; an exception is the
    reason the task's init gives), say ready, then call `on_wake` at each wake until the hang-up."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C reaches the RTPU, whose kill hangs up
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # (the RTPU's children start there already)
    memfd, wake, hangup, ready = (int(fd) for fd in sys.argv[1:5])
    setup = json.loads(sys.argv[5])
    shared = mmap.mmap(memfd, _layout(setup["sizes"])[1])
    child = DdsChild(setup, *_records(shared, setup["sizes"]))
    try:
        start(child)
    except Exception as exc:
        os.write(ready, f"{type(exc).__name__}: {exc}".encode())
        return
    os.write(ready, READY)
    os.close(ready)
    poller = select.poll()
    poller.register(wake, select.POLLIN)
    poller.register(hangup, select.POLLIN)
    while True:
        woken = dict(poller.poll())
        if hangup in woken:
            return
        os.eventfd_read(wake)
        if child.on_wake is not None:
            child.on_wake()
