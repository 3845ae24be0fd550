"""One cycle's transfer through the real state variable table, against a floor measured in the same run.

The transfer (TR §4.2): lock, 3 in-vars in, unlock; lock, 2 out-vars out, unlock; 6 float64
each. The floor does the same semaphore operations and the cheapest numpy copies of the same
bytes on a bare segment; the naive baseline copies variable by variable with `np.copyto`.
Short timed batches alternate between the three so machine noise falls on all alike. One
process: this is the cost a task pays per cycle, without anyone else on the lock.

    python -m bench.svar_transfer [--rounds 21] [--iterations 20000] [--table-variables 1000]
"""

from __future__ import annotations

import argparse
import mmap
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import posix_ipc

from bench._common import Section, Table, Target, fmt_ratio, ratio
from pbo_runtime import InVar, OutVar, PortBasedObject
from pbo_runtime.config.model import PortBinding, VariableSpec
from pbo_runtime.objects.ports import PortKind, PortSpec
from pbo_runtime.table.table import StateTable, TableLayout
from pbo_runtime.task.transfer import LocalTable

SIZE = 6  # float64 per variable
N_IN, N_OUT = 3, 2


class BenchTask(PortBasedObject):
    """Three inputs, two outputs: the shape of a small controller."""

    a = InVar("a", shape=(SIZE,))
    b = InVar("b", shape=(SIZE,))
    c = InVar("c", shape=(SIZE,))
    x = OutVar("x", shape=(SIZE,))
    y = OutVar("y", shape=(SIZE,))


def object_name(part: str) -> str:
    """A POSIX object name no run and no other benchmark uses."""
    return f"/pbo.bench.{os.getpid()}-{os.urandom(3).hex()}.{part}"


def bindings_for(inputs: list[str], outputs: list[str]) -> tuple[PortBinding, ...]:
    """A task's ports as bindings: one in-var per name of `inputs`, one out-var per name of `outputs`."""
    ports = [PortSpec(f"i_{v}", PortKind.IN_VAR, v, "float64", (SIZE,), "") for v in inputs]
    ports += [PortSpec(f"o_{v}", PortKind.OUT_VAR, v, "float64", (SIZE,), "") for v in outputs]
    return tuple(PortBinding(p, p.variable, (SIZE,)) for p in ports)


def vector_variables(names: list[str]) -> list[VariableSpec]:
    """Variables of SIZE float64, in table order."""
    return [VariableSpec(n, i, "float64", (SIZE,)) for i, n in enumerate(names)]


def time_each(step: Callable[[], None], iterations: int) -> np.ndarray:
    """Per-iteration times in ns (each includes one clock read, alike for every contender)."""
    clock = time.perf_counter_ns
    out = np.empty(iterations)
    for i in range(iterations):
        t0 = clock()
        step()
        out[i] = clock() - t0
    return out


def time_batch(step: Callable[[], None], iterations: int) -> float:
    """Mean ns per iteration over a batch: no clock read inside the loop."""
    t0 = time.perf_counter_ns()
    for _ in range(iterations):
        step()
    return (time.perf_counter_ns() - t0) / iterations


GOAL = 1.2  # issue 23 (issue 6 had 1.5)
SIGNED = "floor + lock record"
SIGNED_TWO_CALLS = "floor + lock record, read and write calls"

CHUNK = 500  # calls per timed batch: well under a scheduler slice, so most batches see no preemption


def interleaved_batches(contenders: dict[Any, Callable[[], None]], iterations: int, chunk: int = CHUNK) -> dict[Any, float]:
    """Median over short batches of each contender's mean ns per call, the contenders taking turns batch
    by batch: a preemption spoils one short batch of one contender instead of shifting a whole round."""
    means: dict[Any, list[float]] = {k: [] for k in contenders}
    for f in contenders.values():  # warm up
        time_batch(f, chunk)
    for _ in range(max(1, iterations // chunk)):
        for k, f in contenders.items():
            means[k].append(time_batch(f, chunk))
    return {k: statistics.median(v) for k, v in means.items()}


class Floor:
    """Two semaphore pairs and the cheapest copies of `n_in` + `n_out` words on a bare segment.

    `signed` and `read_signed` / `write_signed` add what the table's lock record costs and nothing
    else: the holder's pid after the read's acquire, the write sequence odd (naming the writer)
    and even again around the write (`ipc.segment`). They are not the floor: they measure how
    much of the table's cost over it those words and a cycle's two calls are.
    """

    def __init__(self, n_in: int, n_out: int) -> None:
        size = max(1 << 16, 8 * (256 + n_in + n_out))  # room after the two regions for other layouts
        self._shm = posix_ipc.SharedMemory(object_name("floor"), posix_ipc.O_CREX, mode=0o600, size=size)
        self._map = mmap.mmap(self._shm.fd, self._shm.size)
        self._shm.close_fd()
        self._sem = posix_ipc.Semaphore(object_name("floorlock"), posix_ipc.O_CREX, mode=0o600, initial_value=1)
        self.flat = np.frombuffer(self._map, dtype=np.float64)
        self.idx_in = np.arange(64, 64 + n_in, dtype=np.intp)
        self.idx_out = np.arange(128 + n_in, 128 + n_in + n_out, dtype=np.intp)
        self.local_in, self.local_out = np.zeros(n_in), np.ones(n_out)
        acquire, release, take, flat = self._sem.acquire, self._sem.release, self.flat.take, self.flat
        idx_in, idx_out, local_in, local_out = self.idx_in, self.idx_out, self.local_in, self.local_out

        def transfer() -> None:
            acquire()
            take(idx_in, out=local_in, mode="clip")
            release()
            acquire()
            flat[idx_out] = local_out
            release()

        self.transfer = transfer
        # the lock record, as the table keeps it: int64 words in the segment's header, stored through a memoryview
        words = self._words = memoryview(self._map)[: 16 * 8].cast("q")
        holder, sequence, pid = 4, 15, os.getpid()
        # as the table does it: the odd tag (2 pid + 1) is the scatter's first word
        idx_signed = np.concatenate([np.array([sequence], dtype=np.intp), idx_out])
        local_signed = np.concatenate([np.array([2 * pid + 1], dtype=np.int64).view(np.float64), local_out])

        def signed() -> None:
            acquire()
            words[holder] = pid
            take(idx_in, out=local_in, mode="clip")
            release()
            acquire()
            before = words[sequence]
            flat[idx_signed] = local_signed
            words[sequence] = before + 2
            release()

        wait, busy = [None], posix_ipc.BusyError  # the table's bounded wait (`StateTable.cycle_lock_wait`)

        def read_signed() -> bool:
            try:
                acquire(wait[0])
            except busy:
                return False
            words[holder] = pid
            take(idx_in, out=local_in, mode="clip")
            release()
            return True

        def write_signed() -> bool:
            try:
                acquire(wait[0])
            except busy:
                return False
            before = words[sequence]
            flat[idx_signed] = local_signed
            words[sequence] = before + 2
            release()
            return True

        self.signed, self.read_signed, self.write_signed = signed, read_signed, write_signed

    def close(self) -> None:
        self._words.release()
        self.flat = None  # type: ignore[assignment]
        self._shm.unlink()  # the mapping itself goes with the process; the names must not outlive it
        self._sem.unlink()


def run(rounds: int = 21, iterations: int = 20000, table_variables: int = 1000) -> Section:
    names = ["a", "b", "c", "x", "y"]
    variables = [VariableSpec(n, i, "float64", (SIZE,)) for i, n in enumerate(names)]
    variables += [VariableSpec(f"filler{i}", len(names) + i, "float64", (SIZE,)) for i in range(table_variables)]
    table = StateTable.create(TableLayout.build(variables, 8), object_name("table"))
    floor = Floor(N_IN * SIZE, N_OUT * SIZE)
    try:
        bindings = tuple(PortBinding(p, p.variable, (SIZE,)) for p in BenchTask.ports())
        local = LocalTable(table, bindings, task_index=3)
        read_inputs, write_outputs, outputs_finite = local.read_inputs, local.write_outputs, local.outputs_finite

        def pbo_transfer() -> None:
            read_inputs()
            write_outputs()

        def pbo_checked() -> None:  # what Task.run_cycle does around a cycle: no NaN or Inf is written
            read_inputs()
            if outputs_finite():
                write_outputs()

        # The naive way: one np.copyto per variable, views made once, same semaphore.
        flat = floor.flat
        global_views = [flat[4096 + i * SIZE: 4096 + (i + 1) * SIZE] for i in range(N_IN + N_OUT)]
        local_views = [np.zeros(SIZE) for _ in range(N_IN + N_OUT)]
        pairs_in = list(zip(local_views[:N_IN], global_views[:N_IN], strict=True))
        pairs_out = list(zip(global_views[N_IN:], local_views[N_IN:], strict=True))
        copyto, acquire, release = np.copyto, floor._sem.acquire, floor._sem.release

        def naive() -> None:
            acquire()
            for dst, src in pairs_in:
                copyto(dst, src)
            release()
            acquire()
            for dst, src in pairs_out:
                copyto(dst, src)
            release()

        read_signed, write_signed = floor.read_signed, floor.write_signed

        def signed_in_two_calls() -> None:  # a cycle reads, runs its module, then writes: two calls
            read_signed()
            write_signed()

        contenders = {"floor": floor.transfer, "pbo table": pbo_transfer, "pbo table + finite check": pbo_checked,
                      "per-variable copyto": naive, SIGNED: floor.signed, SIGNED_TWO_CALLS: signed_in_two_calls}
        each: dict[str, list[np.ndarray]] = {k: [] for k in contenders}
        batch = interleaved_batches(contenders, rounds * iterations)
        for _ in range(rounds):
            for key, f in contenders.items():
                each[key].append(time_each(f, iterations))
    finally:
        table.close()
        floor.close()

    section = Section(
        key="svar_transfer",
        title="One cycle's transfer, in one process, against the bare floor",
        command=f"python -m bench.svar_transfer --rounds {rounds} --iterations {iterations} --table-variables {table_variables}",
        method=f"""
What a task pays per cycle to move its ports: {N_IN} in-vars and {N_OUT} out-vars of {SIZE} float64, two
lock pairs, in a table of {len(variables):,} variables; {rounds * iterations:,} transfers of each contender in
batches of {CHUNK} (the contenders taking turns batch by batch, so machine noise falls on all alike),
then {rounds} rounds x {iterations:,} individually timed transfers for the per-call percentiles.

- **floor**: the same two semaphore acquire/release pairs and the cheapest numpy copies of the
  same bytes (one `take` in, one fancy assignment out) on a bare segment;
- **pbo table**: `LocalTable.read_inputs()` then `LocalTable.write_outputs()` of a real task on
  the real table, which also move each variable's writer word and the task's status block (its
  cycle count and release time, the outputs' sequence number and write time), sign the lock
  (the read stores the holder's pid; the write makes the table's write sequence odd, naming the
  writer, and even again: the seqlock observers read under without the lock);
- **pbo table + finite check**: the same, with the test a task's cycle makes before writing its
  outputs (`LocalTable.outputs_finite`: `np.isfinite` into a preallocated mask and
  `np.count_nonzero`, so no NaN or Inf reaches the table); its cost is the difference to the row above;
- **per-variable copyto**: the obvious implementation, one `np.copyto` per variable;
- **{SIGNED}**: the floor plus the table's lock record and nothing else (the holder's pid
  stored after the read's acquire; the write sequence loaded, made odd by the scatter's first
  word and even again after it), in the floor's one function: what the words the lock watch and
  the seqlock need cost;
- **{SIGNED_TWO_CALLS}**: the same as the two functions a task's cycle calls (it reads, runs
  its module, then writes), called from one as the table's are, each waiting for the lock as
  long as the table's bound says (`StateTable.cycle_lock_wait`) and saying whether it got it. This is the least a transfer
  with the table's guarantees can cost in Python; the floor itself signs nothing and is one call.

The batch median (the median over batches of the mean time per transfer, no clock read inside a
batch) is the figure the target is judged on; per-call figures include one `perf_counter_ns` pair
each (about 0.07 µs).
""",
        limits="""Python call overhead, not bytes: the table moves more words than the floor (each
variable's writer word, the status block, the sequence's tag) at no measurable cost, and pays over
it for a cycle's two calls and the three stores and loads of its lock record (this run's figures
are in the note above). Counted in instructions (valgrind, CPython 3.11, numpy 2.4; no timing
noise): the floor is ~7.0k per transfer (its four semaphore calls ~2.4k, the `take` ~3.0k, the
scatter ~1.6k); a Python call ~0.35-0.45k; one int64 word through a memoryview, the cheapest store
or load of a word Python has, ~0.3-0.4k. The table's transfer is ~9.8k, 1.39x the floor; floor
+ lock record is 1.17x and, as two calls, 1.27x (each ±0.03x): in instructions the lock record
and the two calls alone are past 1.2x. Per-variable stamping with `fill` cost
0.15 µs more and was replaced by the status-block scheme (see
[architecture](architecture.md#metadata-without-per-cycle-stamping)); the index arrays are built
at spawn, so the table's size does not enter (see the scale curves below).""",
    )
    t = Table(["transfer", "batch median µs", "per-call p50 µs", "per-call p99 µs", "ratio to floor (batch median)"],
              numeric=(1, 2, 3, 4))
    floor_batch = batch["floor"]
    for key in contenders:
        samples = np.concatenate(each[key])
        med = batch[key]
        r = ratio(med, floor_batch)
        if r is not None:
            section.ratios[key] = r
        t.add(key, f"{med / 1000:.3f}", f"{np.median(samples) / 1000:.3f}",
              f"{np.percentile(samples, 99) / 1000:.3f}", fmt_ratio(r))
    section.tables.append(t)
    signed, two_calls, table = (section.ratios.get(k) for k in (SIGNED, SIGNED_TWO_CALLS, "pbo table"))
    if signed is not None and two_calls is not None and table is not None:
        section.notes.append(
            f"Of the table's {table:.2f}x the floor, its lock record alone makes {signed:.2f}x and its two calls bring "
            f"that to {two_calls:.2f}x: the table costs {table / two_calls:.2f}x the least transfer with its guarantees. "
            f"{GOAL:g}x would need a transfer without the lock record the lock watch and the observers' seqlock rely on, "
            f"or a cycle without two calls."
        )
    section.targets.append(Target("pbo table / floor (batch median, one process)", table, GOAL, note="issue 23's goal"))
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=21)
    parser.add_argument("--iterations", type=int, default=20000)
    parser.add_argument("--table-variables", type=int, default=1000,
                        help="extra variables in the table (a task pays for its own ports only)")
    args = parser.parse_args()
    print(run(args.rounds, args.iterations, args.table_variables).text())


if __name__ == "__main__":
    main()
