"""Write and read latency of a periodic link between two processes: the triple buffer against its alternatives.

For each payload (48 B, 4 KiB, 1 MiB) and each contender, a sender process writes items and a
reader process reads them, each timing every call (`perf_counter_ns`). By default both are
periodic at unrelated rates (the reader's period is 0.65 of the sender's, as in TR §5.2 where
subsystems run at rates that are not multiples of each other), spinning to their next release;
`--back-to-back` drops the periods, so each side calls as fast as it can (the worst contention).

- triple buffer: `pbo_runtime.links.triple_buffer.TripleBuffer` (`write`, `read(out)`): the lock is
  held for the index swap only; neither side waits for the other's copy (TR §5.2);
- locked buffer: one shm buffer and one semaphore held during each side's copy (a double buffer
  as usually written): each side waits for the other's copy;
- posix_ipc queue: each item is one message (payloads above fs.mqueue.msgsize_max go in chunks
  of that size), the sender blocks while the queue is full, and a read drains what is waiting
  (at most the queue's capacity) and keeps the newest complete item, as a state link needs;
- zenoh: `pbo_runtime.links.zenoh_link.ZenohLink`, the same periodic link over eclipse-zenoh on
  tcp/127.0.0.1 (the sender's session listens, the reader's connects; no scouting): a write is
  one express `put` that never waits for the reader; a read takes the newest sample zenoh kept
  in a one-sample ring and copies it out ("zenoh", the default delivery), or copies the item a
  Python callback swapped in as it arrived ("zenoh callback"). Skipped, with a note, when
  eclipse-zenoh is not installed.

Ratios are each figure over the triple buffer's for the same payload and side, measured in the
same run. Python call overhead dominates small payloads.

The links that stamp their items (triple buffer, zenoh) also give rows of one-way latency: from
the sender's time stamp (taken as `write` is called) to the reader's `read` that first got the
item ("one-way (read)": includes waiting for the reader's next period, as a task would), and for
zenoh to the item's arrival in the reader's process ("one-way (arrival)": the transport alone).

    python bench/links.py [--quick] [--items N] [--rounds R] [--back-to-back]
"""

from __future__ import annotations

import argparse
import importlib.util
import mmap
import multiprocessing
import os
import platform
import signal
import struct
import sys
import time

import numpy as np
import posix_ipc

from pbo_runtime.clock.clocks import lower_timer_slack
from pbo_runtime.ipc import messages
from pbo_runtime.links.triple_buffer import Freshness, LinkLayout, TripleBuffer
from pbo_runtime.links.zenoh_link import ZenohLink
from pbo_runtime.links.zenoh_session import free_port

PAYLOADS = (48, 4096, 1 << 20)
ITEMS = {48: 50_000, 4096: 50_000, 1 << 20: 2_000}
QUICK_ITEMS = {48: 2_000, 4096: 2_000, 1 << 20: 100}
SENDER_PERIOD_NS = {48: 20_000, 4096: 20_000, 1 << 20: 300_000}  # a few times the slowest contender's usual write
ROUNDS = 5  # the contenders take turns this many times (--quick: once)
READER_PERIOD_SHARE = 0.65  # reader period / sender period: not a multiple, so the two drift through every phase
ZENOH = importlib.util.find_spec("zenoh") is not None  # found, not imported: children open sessions after the fork
MECHANISMS = ("triple buffer", "locked buffer", "posix_ipc queue") + (("zenoh", "zenoh callback") if ZENOH else ())
SIDES = ("write", "read", "one-way (read)", "one-way (arrival)")
READS_PER_WRITE_CAP = 50  # the reader keeps at most this many samples per item written (and reads on)
FORK = multiprocessing.get_context("fork")
_CHUNK_HEADER = struct.Struct("<qq")  # item counter, chunk index


def _name(part: str) -> str:
    return f"/pbo.bench.{os.getpid()}-{os.urandom(3).hex()}.{part}"


def _label(nbytes: int) -> str:
    return f"{nbytes >> 20} MiB" if nbytes >= 1 << 20 else f"{nbytes >> 10} KiB" if nbytes >= 1024 else f"{nbytes} B"


# --- the contenders: each has a creator (owner of the names) and two ends that attach by name ----


WARM_WRITES = 3  # one per slot


class _TripleEnd:
    def __init__(self, name: str, nbytes: int, role: str) -> None:
        self._link = TripleBuffer.attach(name, LinkLayout.raw(nbytes), role)
        self.write, self.read = self._link.write, self._link.read  # bound once: no wrapper in the timed call
        self._role = role

    def warm(self, out: np.ndarray) -> None:
        if self._role == "sender":
            for _ in range(WARM_WRITES):
                self._link.write(out)
        else:
            for slot in self._link._payloads:  # fault in all three slots' pages before timing
                np.copyto(out, slot)
            self._link.read(out)  # the sender's warm-up items are all written by now: take the newest, as zenoh's reader does
            self._last = self._link.counter

    def items(self) -> int:
        stats = self._link.statistics()
        return stats.writes - WARM_WRITES if self._role == "sender" else stats.new - 1

    def age(self) -> tuple[int, int] | None:
        """(now - stamp, -1) in ns after the read that first got an item; None after any other read."""
        link = self._link
        if link.counter == self._last:
            return None
        self._last = link.counter
        return time.monotonic_ns() - link.stamp_ns, -1

    _last = 0

    def close(self) -> None:
        self.write = self.read = None  # type: ignore[assignment]
        self._link.close()


class _Triple:
    def __init__(self, nbytes: int) -> None:
        self.name = _name("link")
        self._link = TripleBuffer.create(self.name, LinkLayout.raw(nbytes))

    def end(self, nbytes: int, role: str) -> _TripleEnd:
        return _TripleEnd(self.name, nbytes, role)

    def close(self) -> None:
        self._link.close()


class _LockedEnd:
    """One end of the locked buffer: the copy itself happens under the semaphore."""

    def __init__(self, name: str, nbytes: int) -> None:
        self._mapping = _attach(name)
        self._counter = np.frombuffer(self._mapping, dtype=np.int64, count=1)
        self._data = np.frombuffer(self._mapping, dtype=np.uint8, count=nbytes, offset=64)
        self._lock = posix_ipc.Semaphore(name + ".lock")
        self._last = 0
        self._items = 0

    def write(self, value: np.ndarray) -> None:
        self._lock.acquire()
        try:
            np.copyto(self._data, value)
            self._counter[0] += 1
        finally:
            self._lock.release()
        self._items += 1

    def read(self, out: np.ndarray) -> None:
        self._lock.acquire()
        try:
            np.copyto(out, self._data)
            counter = int(self._counter[0])
        finally:
            self._lock.release()
        if counter != self._last:
            self._last = counter
            self._items += 1

    def warm(self, out: np.ndarray) -> None:
        np.copyto(out, self._data)  # both ends fault in the buffer's pages before timing

    def items(self) -> int:
        return self._items

    def close(self) -> None:
        self._counter = self._data = None  # type: ignore[assignment]
        self._mapping.close()
        self._lock.close()


class _Locked:
    def __init__(self, nbytes: int) -> None:
        self.name = _name("locked")
        self._shm = posix_ipc.SharedMemory(self.name, posix_ipc.O_CREX, mode=0o600, size=64 + nbytes)
        self._shm.close_fd()
        self._lock = posix_ipc.Semaphore(self.name + ".lock", posix_ipc.O_CREX, mode=0o600, initial_value=1)

    def end(self, nbytes: int, role: str) -> _LockedEnd:
        return _LockedEnd(self.name, nbytes)

    def close(self) -> None:
        self._shm.unlink()
        self._lock.unlink()
        self._lock.close()


class _QueueEnd:
    def __init__(self, name: str, nbytes: int) -> None:
        self._queue = posix_ipc.MessageQueue(name)
        self._chunk = self._queue.max_message_size - _CHUNK_HEADER.size
        self._chunks = -(-nbytes // self._chunk)
        self._staging = np.zeros(nbytes, dtype=np.uint8)
        self._items = 0

    def write(self, value: np.ndarray) -> None:
        self._items += 1
        raw = value.data
        for index in range(self._chunks):
            piece = raw[index * self._chunk : (index + 1) * self._chunk]
            self._queue.send(_CHUNK_HEADER.pack(self._items, index) + piece, timeout=None)  # waits while full

    def read(self, out: np.ndarray) -> None:
        staging = self._staging
        # What was waiting, not what keeps arriving. Asking first: posix_ipc's polling receive
        # costs tens of µs on an empty queue, and with one reader each waiting message is there.
        for _ in range(self._queue.current_messages):
            message, _priority = self._queue.receive()
            _counter, index = _CHUNK_HEADER.unpack_from(message)
            start = index * self._chunk
            data = np.frombuffer(message, dtype=np.uint8, offset=_CHUNK_HEADER.size)
            if self._chunks == 1:
                np.copyto(out, data)
                self._items += 1
                continue
            staging[start : start + data.size] = data
            if index == self._chunks - 1:
                np.copyto(out, staging)  # a complete item only: out is never half of one
                self._items += 1

    def warm(self, out: np.ndarray) -> None:
        pass  # a message is new memory each time: nothing to fault in ahead

    def items(self) -> int:
        return self._items

    def close(self) -> None:
        self._queue.close()


class _Queue:
    def __init__(self, nbytes: int) -> None:
        self.name = _name("queue")
        size = min(nbytes + _CHUNK_HEADER.size, messages.MESSAGE_BYTES)
        self._queue = posix_ipc.MessageQueue(
            self.name, posix_ipc.O_CREX, mode=0o600, max_messages=messages.MAX_MESSAGES, max_message_size=size
        )

    def end(self, nbytes: int, role: str) -> _QueueEnd:
        return _QueueEnd(self.name, nbytes)

    def close(self) -> None:
        self._queue.close()
        self._queue.unlink()


class _ZenohEnd:
    """The sender's session listens on the port, the reader's connects to it (both in the children)."""

    def __init__(self, key: str, port: int, nbytes: int, role: str, delivery: str) -> None:
        layout = LinkLayout.raw(nbytes)
        if role == "sender":
            self._link = ZenohLink.create(key, layout, role, port=port)
        else:
            self._link = ZenohLink.attach(key, layout, role, port=port, wait=30.0, delivery=delivery)
        self._arrival_known = delivery == "callback"  # a ring is drained by read(): the arrival time is not seen
        self.write, self.read = self._link.write, self._link.read
        self._role = role
        self._last = 0

    def warm(self, out: np.ndarray) -> None:
        link = self._link
        give_up = time.monotonic() + 30.0
        if self._role == "sender":
            while not link._publisher.matching_status.matching:  # the reader's subscription has arrived
                if time.monotonic() > give_up:
                    raise RuntimeError(f"no reader subscribed to '{link.name}' within 30 s")
                time.sleep(0.001)
            for _ in range(WARM_WRITES):
                link.write(out)
        else:
            while link.read(out) is Freshness.NONE:  # the sender's first warm-up item has arrived
                if time.monotonic() > give_up:
                    raise RuntimeError(f"nothing received on '{link.name}' within 30 s")
                time.sleep(0.001)
            self._last = link.counter

    def items(self) -> int:
        stats = self._link.statistics()
        return stats.writes - WARM_WRITES if self._role == "sender" else stats.new - 1

    def age(self) -> tuple[int, int] | None:
        link = self._link
        if link.counter == self._last:
            return None
        self._last = link.counter
        return time.monotonic_ns() - link.stamp_ns, link.received_ns - link.stamp_ns if self._arrival_known else -1

    def close(self) -> None:
        self.write = self.read = None  # type: ignore[assignment]
        self._link.close()


class _Zenoh:
    delivery = "ring"

    def __init__(self, nbytes: int) -> None:
        self.key = f"pbo/bench/{os.getpid()}-{os.urandom(3).hex()}/link"
        self.port = free_port()

    def end(self, nbytes: int, role: str) -> _ZenohEnd:
        return _ZenohEnd(self.key, self.port, nbytes, role, self.delivery)

    def close(self) -> None:
        pass  # nothing outlives the children's sessions


class _ZenohCallback(_Zenoh):
    delivery = "callback"


CONTENDERS = {"triple buffer": _Triple, "locked buffer": _Locked, "posix_ipc queue": _Queue, "zenoh": _Zenoh,
              "zenoh callback": _ZenohCallback}


def _attach(name: str) -> mmap.mmap:
    shm = posix_ipc.SharedMemory(name)
    try:
        return mmap.mmap(shm.fd, shm.size)
    finally:
        shm.close_fd()


# --- the two processes ------------------------------------------------------------------------


def _doze(release: int) -> None:
    """Sleep until `release` (perf_counter ns), as a periodic task does, instead of spinning to it."""
    delay = release - time.perf_counter_ns()
    if delay > 0:
        time.sleep(delay / 1e9)


def _sender(contender, nbytes: int, items: int, period: int, start, finished, results, sleep: bool = False) -> None:
    if sleep:
        lower_timer_slack()
    end = contender.end(nbytes, "sender")
    value = np.ones(nbytes, dtype=np.uint8)
    samples = np.empty(items, dtype=np.int64)
    clock, write = time.perf_counter_ns, end.write
    try:
        end.warm(value)
        start.wait()  # the reader warms up after the sender
        start.wait()
        release = clock()
        for i in range(items):
            if sleep:
                _doze(release)
            while clock() < release:
                pass
            t0 = clock()
            write(value)
            samples[i] = clock() - t0
            release = max(release + period, t0)  # an overrun starts the next period late, with no burst
    finally:
        finished.value = 1
    results.send((samples, end.items(), None))
    end.close()


def _reader(contender, nbytes: int, items: int, period: int, start, finished, results, sleep: bool = False) -> None:
    if sleep:
        lower_timer_slack()
    end = contender.end(nbytes, "reader")
    out = np.ones(nbytes, dtype=np.uint8)
    samples = np.empty(items * READS_PER_WRITE_CAP, dtype=np.int64)
    age = getattr(end, "age", None)  # links that stamp their items: one-way latency of each new item
    ages = np.empty((items + 2 * WARM_WRITES, 2), dtype=np.int64)
    aged = 0
    clock, read = time.perf_counter_ns, end.read
    start.wait()
    end.warm(out)
    start.wait()
    count = 0
    release = clock()
    while count == 0 or not finished.value:  # until the sender is done: a queue's sender may be waiting for us
        if sleep:
            _doze(release)
        while clock() < release:
            pass
        t0 = clock()
        read(out)
        if count < samples.size:
            samples[count] = clock() - t0
            count += 1
        if age is not None and (one_way := age()) is not None and aged < len(ages):
            ages[aged] = one_way
            aged += 1
        release = max(release + period, t0)
    results.send((samples[:count], end.items(), ages[:aged] if age is not None else None))
    end.close()


def measure(mechanism: str, nbytes: int, items: int, periods: tuple[int, int],
            sleep: bool = False) -> dict[str, tuple[np.ndarray, int, np.ndarray | None]]:
    """{side: (latencies in ns, items written or read, one-way ns per new item)} of one contender, two processes.

    Periods in ns (sender, reader); each side spins to its next release, or sleeps to it (`sleep`,
    with the timer slack lowered, as an RTPU does). The one-way array (reader only, stamped links only) has two
    columns: stamp to read, stamp to arrival in the reader's process (-1 where not known).
    """
    contender = CONTENDERS[mechanism](nbytes)
    start, finished = FORK.Barrier(2), FORK.RawValue("b", 0)
    pipes = {side: FORK.Pipe(duplex=False) for side in ("write", "read")}
    children = {
        "write": FORK.Process(target=_sender, args=(contender, nbytes, items, periods[0], start, finished,
                                                    pipes["write"][1], sleep)),
        "read": FORK.Process(target=_reader, args=(contender, nbytes, items, periods[1], start, finished,
                                                   pipes["read"][1], sleep)),
    }
    try:
        for child in children.values():
            child.start()
        results = {side: pipes[side][0].recv() for side in ("write", "read")}
    finally:
        for child in children.values():
            child.join(60)
            if child.is_alive():
                child.terminate()
        contender.close()
    return results


def run(quick: bool = False, items: int | None = None, back_to_back: bool = False, rounds: int | None = None) -> list[dict]:
    """One row per payload, contender and side: latencies in µs and ratios to the triple buffer.

    The items are split over `rounds`, and the contenders take turns round by round (in a
    rotating order), so that what else the machine does falls on all of them alike.
    """
    counts = QUICK_ITEMS if quick else ITEMS
    rounds = rounds or (1 if quick else ROUNDS)
    rows: list[dict] = []
    for nbytes in PAYLOADS:
        per_round = -(-(items or counts[nbytes]) // rounds)
        sender_period = 0 if back_to_back else SENDER_PERIOD_NS[nbytes]
        periods = (sender_period, int(sender_period * READER_PERIOD_SHARE))
        pooled: dict[tuple[str, str], list[tuple[np.ndarray, int]]] = {}
        turns = len(MECHANISMS)
        for turn in range(rounds):
            for mechanism in MECHANISMS[turn % turns :] + MECHANISMS[: turn % turns]:
                for side, (samples, moved, ages) in measure(mechanism, nbytes, per_round, periods).items():
                    pooled.setdefault((mechanism, side), []).append((samples, moved))
                    if ages is not None and len(ages):
                        pooled.setdefault((mechanism, "one-way (read)"), []).append((ages[:, 0], len(ages)))
                        if (ages[:, 1] >= 0).all():
                            pooled.setdefault((mechanism, "one-way (arrival)"), []).append((ages[:, 1], len(ages)))
        figures = {}
        for key, results in pooled.items():
            samples = np.concatenate([r[0] for r in results])
            p50, p99 = np.percentile(samples, [50, 99]) / 1000
            figures[key] = (samples.size, sum(r[1] for r in results), p50, p99, samples.max() / 1000)
        for mechanism in MECHANISMS:
            for side in SIDES:
                if (mechanism, side) not in figures:
                    continue  # one-way rows: stamped links only
                operations, moved, p50, p99, worst = figures[mechanism, side]
                base = figures.get(("triple buffer", side), figures.get(("triple buffer", "one-way (read)")))
                rows.append({
                    "payload_bytes": nbytes,
                    "payload": _label(nbytes),
                    "sender_period_us": periods[0] / 1000,
                    "reader_period_us": periods[1] / 1000,
                    "mechanism": mechanism,
                    "side": side,
                    "operations": int(operations),
                    "items": int(moved),
                    "p50_us": float(p50),
                    "p99_us": float(p99),
                    "max_us": float(worst),
                    "p50_ratio": float(p50 / base[2]),
                    "p99_ratio": float(p99 / base[3]),
                    "max_ratio": float(worst / base[4]),
                })
    return rows


def table(rows: list[dict]) -> str:
    headers = ("payload", "period µs", "mechanism", "side", "ops", "items", "p50 µs", "p99 µs", "max µs",
               "p50 x", "p99 x", "max x")
    lines = [
        f"Link latency between two processes ({os.cpu_count()} CPUs, {platform.python_implementation()} "
        f"{platform.python_version()}); x = ratio to the triple buffer, same payload and side",
        "period: of the side's calls (0: back to back); items: written by the sender, newest items the reader got",
    ]
    body = [
        (r["payload"], f"{r['sender_period_us' if r['side'] == 'write' else 'reader_period_us']:g}", r["mechanism"], r["side"],
         str(r["operations"]), str(r["items"]), f"{r['p50_us']:.2f}",
         f"{r['p99_us']:.2f}", f"{r['max_us']:.1f}", f"{r['p50_ratio']:.2f}", f"{r['p99_ratio']:.2f}", f"{r['max_ratio']:.2f}")
        for r in rows
    ]
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(headers)]
    fmt = "  ".join(f"{{:{'<' if i in (0, 2, 3) else '>'}{w}}}" for i, w in enumerate(widths))
    lines.append(fmt.format(*headers))
    lines.append(fmt.format(*("-" * w for w in widths)))
    lines += [fmt.format(*b) for b in body]
    if not ZENOH:
        lines.append("zenoh: not measured: eclipse-zenoh is not installed (pip install 'eclipse-zenoh>=1.0')")
    lines.append("one-way: sender's time stamp to the reader's first read of the item (read) or to its arrival in the "
                 "reader's process (arrival); x of one-way rows: to the triple buffer's one-way (read)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small counts: a check that it runs, not a measurement")
    parser.add_argument("--items", type=int, default=None, help="items per payload (default: 50,000, or 2,000 for 1 MiB)")
    parser.add_argument("--back-to-back", action="store_true", help="no periods: each side calls as fast as it can")
    parser.add_argument("--rounds", type=int, default=None, help=f"turns the contenders take (default: {ROUNDS}, --quick: 1)")
    args = parser.parse_args(argv)
    rows = run(args.quick, args.items, args.back_to_back, args.rounds)
    print(table(rows))
    return rows


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # so that `finally` removes the links' names
    main()


def section(quick: bool = False, rounds: int | None = None):
    """The benchmark as a section of docs/performance.md (`python -m bench` runs it)."""
    # In a fresh interpreter: the runner's process has threads by now (other benchmarks'), and
    # this benchmark forks its two ends.
    import json
    import subprocess
    import sys

    from bench._common import Section, Table

    code = f"import json; from bench.links import run; print(json.dumps(run(quick={quick!r}, rounds={rounds!r})))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900, check=True)
    rows = json.loads(done.stdout.strip().splitlines()[-1])
    result = Table(["payload", "mechanism", "side", "ops", "items", "p50 µs", "p99 µs", "max µs", "p50 x", "p99 x"],
                   numeric=(3, 4, 5, 6, 7, 8, 9), caption="Ratios are to the triple buffer's same side and payload.")
    for r in rows:
        result.add(r["payload"], r["mechanism"], r["side"], r["operations"], r["items"], f"{r['p50_us']:.2f}",
                   f"{r['p99_us']:.2f}", f"{r['max_us']:.1f}", f"{r['p50_ratio']:.2f}", f"{r['p99_ratio']:.2f}")
    code = f"import json; from bench.message_links import run; print(json.dumps(run(quick={quick!r}, rounds={rounds!r})))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900, check=True)
    messages = Table(["mode", "mechanism", "side", "calls", "p50 µs", "p99 µs", "max µs", "p50 x", "p99 x", "refused"],
                     numeric=(3, 4, 5, 6, 7, 8, 9),
                     caption="Message links (`python -m bench.message_links`): ratios to the POSIX queue, same mode and side.")
    for r in json.loads(done.stdout.strip().splitlines()[-1]):
        messages.add(r["mode"], r["mechanism"], r["side"], r["calls"], f"{r['p50_us']:.1f}", f"{r['p99_us']:.1f}",
                     f"{r['max_us']:.0f}", f"{r['p50_ratio']:.2f}", f"{r['p99_ratio']:.2f}", r["refused"])
    return Section(
        key="links", title="Links between subsystems: triple buffer, locked buffer, queue, Zenoh (TR §5)",
        command="python -m bench.links",
        method="Two processes, a sender and a reader at their own periods (the reader at 0.65 of the sender's), "
               "for 48 B, 4 KiB and 1 MiB items; write and read are the cost of one call on each side, one-way "
               "is from the sender's time stamp to the reader's first read of the item. The contenders take "
               "turns round by round so the machine's other work falls on all alike. Message links: a sender "
               "every 500 µs, a receiver that takes what waits every 325 µs (cycle) or waits in `receive` as "
               "a server's relay does (waiting); send and receive are the cost of one call, one-way from the "
               "message's sending time to the receive that took it.",
        limits="On 2 shared vCPUs the maxima are the scheduler's; the 1 MiB queue is split into 8 KiB messages "
               "(fs.mqueue.msgsize_max), and its sender waits whenever the queue is full.",
        tables=[result, messages])
