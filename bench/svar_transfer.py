"""One cycle's transfer through the real state variable table, against a floor measured in the same run.

The transfer (TR §4.2): lock, 4 in-vars in, unlock; lock, 2 out-vars out, unlock; 6 float64
each. The floor does the same semaphore operations and the cheapest numpy copies of the same
bytes on a bare segment; the naive baseline copies variable by variable with `np.copyto`.
Rounds alternate between the three so machine noise falls on all alike.

    python bench/svar_transfer.py [--rounds 21] [--iterations 20000] [--table-variables 1000]
"""

from __future__ import annotations

import argparse
import mmap
import os
import platform
import statistics
import time

import numpy as np
import posix_ipc

from pbo_runtime import InVar, OutVar, PortBasedObject
from pbo_runtime._config_model import PortBinding, VariableSpec
from pbo_runtime._table import StateTable, TableLayout
from pbo_runtime._transfer import LocalTable

SIZE = 6  # float64 per variable


class BenchTask(PortBasedObject):
    """Four inputs, two outputs: the shape of a small controller."""

    a = InVar("a", shape=(SIZE,))
    b = InVar("b", shape=(SIZE,))
    c = InVar("c", shape=(SIZE,))
    d = InVar("d", shape=(SIZE,))
    x = OutVar("x", shape=(SIZE,))
    y = OutVar("y", shape=(SIZE,))


def _name(part: str) -> str:
    return f"/pbo.bench.{os.getpid()}-{os.urandom(3).hex()}.{part}"


def _time_each(step, iterations: int) -> np.ndarray:
    """Per-iteration times in ns (each includes one clock read, alike for every contender)."""
    clock = time.perf_counter_ns
    out = np.empty(iterations)
    for i in range(iterations):
        t0 = clock()
        step()
        out[i] = clock() - t0
    return out


def _time_batch(step, iterations: int) -> float:
    """Mean ns per iteration over a batch: no clock read inside the loop."""
    t0 = time.perf_counter_ns()
    for _ in range(iterations):
        step()
    return (time.perf_counter_ns() - t0) / iterations


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=21)
    parser.add_argument("--iterations", type=int, default=20000)
    parser.add_argument("--table-variables", type=int, default=1000, help="extra variables in the table (a task pays for its own ports only)")
    args = parser.parse_args()

    names = ["a", "b", "c", "d", "x", "y"]
    variables = [VariableSpec(n, i, "float64", (SIZE,)) for i, n in enumerate(names)]
    variables += [VariableSpec(f"filler{i}", len(names) + i, "float64", (SIZE,)) for i in range(args.table_variables)]
    table = StateTable.create(TableLayout.build(variables, 8), _name("table"))
    bindings = tuple(PortBinding(p, p.variable, (SIZE,)) for p in BenchTask.ports())
    local = LocalTable(table, bindings, task_index=3)
    read_inputs, write_outputs = local.read_inputs, local.write_outputs

    def pbo_transfer() -> None:
        read_inputs()
        write_outputs()

    # The floor: the same two lock pairs and the cheapest copies of the same bytes, bare segment.
    shm = posix_ipc.SharedMemory(_name("floor"), posix_ipc.O_CREX, mode=0o600, size=1 << 16)
    bare = mmap.mmap(shm.fd, shm.size)
    shm.close_fd()
    sem = posix_ipc.Semaphore(_name("floorlock"), posix_ipc.O_CREX, mode=0o600, initial_value=1)
    flat = np.frombuffer(bare, dtype=np.float64)
    idx_in = np.arange(64, 64 + 4 * SIZE, dtype=np.intp)
    idx_out = np.arange(512, 512 + 2 * SIZE, dtype=np.intp)
    local_in, local_out = np.zeros(4 * SIZE), np.ones(2 * SIZE)
    acquire, release, take = sem.acquire, sem.release, flat.take

    def floor() -> None:
        acquire()
        take(idx_in, out=local_in, mode="clip")
        release()
        acquire()
        flat[idx_out] = local_out
        release()

    # The naive way: one np.copyto per variable, views made once.
    global_views = [flat[1024 + i * SIZE : 1024 + (i + 1) * SIZE] for i in range(6)]
    local_views = [np.zeros(SIZE) for _ in range(6)]
    pairs_in = list(zip(local_views[:4], global_views[:4]))
    pairs_out = list(zip(global_views[4:], local_views[4:]))
    copyto = np.copyto

    def naive() -> None:
        acquire()
        for dst, src in pairs_in:
            copyto(dst, src)
        release()
        acquire()
        for dst, src in pairs_out:
            copyto(dst, src)
        release()

    contenders = {"floor": floor, "pbo table": pbo_transfer, "per-variable copyto": naive}
    each = {k: [] for k in contenders}
    batch = {k: [] for k in contenders}
    try:
        for f in contenders.values():  # warm up
            _time_batch(f, 2000)
        for _ in range(args.rounds):
            for key, f in contenders.items():
                each[key].append(_time_each(f, args.iterations))
                batch[key].append(_time_batch(f, args.iterations))
    finally:
        table.close()
        shm.unlink()  # the mapping itself goes with the process; the name must not outlive it
        sem.unlink()

    print(f"one cycle's transfer: 4 in-vars + 2 out-vars of {SIZE} float64, two lock pairs; "
          f"table of {len(variables)} variables; {args.rounds} rounds x {args.iterations} iterations")
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__}")
    print()
    print("| transfer | batch median µs | per-call median µs | per-call p99 µs | ratio to floor (batch median) |")
    print("|---|---:|---:|---:|---:|")
    floor_batch = statistics.median(batch["floor"])
    for key in contenders:
        samples = np.concatenate(each[key])
        med_batch = statistics.median(batch[key])
        print(f"| {key} | {med_batch / 1000:.3f} | {np.median(samples) / 1000:.3f} | "
              f"{np.percentile(samples, 99) / 1000:.3f} | {med_batch / floor_batch:.2f}x |")
    ratio = statistics.median(batch["pbo table"]) / floor_batch
    print()
    print(f"pbo table / floor = {ratio:.2f}x (target: within 1.5x) -> {'met' if ratio <= 1.5 else 'NOT met'}")
    print("per-call figures include one perf_counter_ns pair each (about 0.07 µs); the batch figures do not.")


if __name__ == "__main__":
    main()
