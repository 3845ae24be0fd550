"""A thread of an RTPU working in Python beside its executive: how late does it make the releases?

An RTPU's log writer and background work (a killed logger's last chunk, summary and footer) run
in threads that share the executive's GIL. The executive (SCHED_FIFO 50, 1 ms releases on the
real clock, its 200 µs spin) runs in a child process beside a helper thread that computes in
Python for 3 ms every 10 ms (work at the GIL, as a writer's own Python is), while ordinary
processes keep every CPU busy. Three setups, taking turns round by round:

- **no helper**: the executive alone under the same load (the floor);
- **before**: the helper at SCHED_OTHER and CPython's default switch interval (5 ms), as an RTPU ran it;
- **pbo**: the helper through `Background.hand_off` (`below_the_cycle`: the lowest SCHED_FIFO
  priority) and the RTPU's switch interval (`GIL_HANDOVER`, 200 µs).

    python -m bench.helper_threads [--seconds 3] [--rounds 3] [--hogs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from bench._common import REPO, Section, Table, percentiles, ratio

PERIOD = 0.001
SETUPS = ("no helper", "before", "pbo")
CHILD = "bench.helper_threads"


def child(setup: str, seconds: float) -> None:
    """In the child: the executive's loop; prints its releases' lateness as JSON."""
    import threading

    from pbo_runtime.clock.clocks import RealClock
    from pbo_runtime.objects.helper_threads import GIL_HANDOVER
    from pbo_runtime.task.background import Background

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(50))
    except OSError as exc:
        print(json.dumps({"refused": str(exc)}))
        return
    stop = threading.Event()

    def python_work() -> None:
        while not stop.is_set():
            busy_until = time.perf_counter() + 0.003
            count = 0
            while time.perf_counter() < busy_until:
                count += 1
            stop.wait(0.007)

    background = None
    if setup == "before":
        threading.Thread(target=python_work, daemon=True).start()
    elif setup == "pbo":
        sys.setswitchinterval(GIL_HANDOVER)
        background = Background()
        background.hand_off(python_work, "helper", "python work")
    clock = RealClock(0.0002)
    late = np.empty(int(seconds / PERIOD), dtype=np.float64)
    release = clock.now() + 0.05
    for i in range(len(late)):
        late[i] = clock.sleep_until(release) - release
        release += PERIOD
    stop.set()
    if background is not None:
        background.close()
    print(json.dumps({"late": late.tolist()}))


def measure(setup: str, seconds: float, hogs: int) -> np.ndarray | str:
    loads = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
    try:
        done = subprocess.run([sys.executable, "-m", CHILD, "--child", setup, "--seconds", str(seconds)],
                              capture_output=True, text=True, cwd=REPO, timeout=60 + 4 * seconds)
    finally:
        for load in loads:
            load.kill()
            load.wait()
    if done.returncode != 0:
        return f"failed: {(done.stderr.strip().splitlines() or ['?'])[-1][:120]}"
    result = json.loads(done.stdout)
    return result["refused"] if "refused" in result else np.asarray(result["late"])


def run(seconds: float = 3.0, rounds: int = 3, hogs: int = 2) -> Section:
    section = Section(
        key="helper_threads",
        title="A helper thread computing beside the executive",
        command=f"python -m bench.helper_threads --seconds {seconds:g} --rounds {rounds} --hogs {hogs}",
        method=f"""
An RTPU's log writer and background thread share the executive's GIL. An executive loop (SCHED_FIFO 50,
releases every 1 ms, `RealClock` with its 200 µs spin) runs in a child process for {seconds:g} s beside a
helper thread that computes in Python for 3 ms every 10 ms, while {hogs} ordinary busy processes load
the CPUs. **no helper**: the loop alone under the same load (the floor). **before**: the helper at
SCHED_OTHER with CPython's default switch interval (5 ms), as RTPUs ran their helper threads. **pbo**:
the helper handed off to `Background` (its thread at the lowest SCHED_FIFO priority, `below_the_cycle`)
and the RTPU's switch interval (200 µs, within the spin). {rounds} rounds, the setups taking turns.
Lateness: how long after its release time each release began.
""",
        limits="""
A helper at SCHED_OTHER that holds the GIL is preempted by the machine's ordinary processes for a
scheduler time slice while the executive waits for the GIL: a priority inversion. At the lowest
real-time priority the helper keeps a CPU while it holds the GIL, and the short switch interval bounds
how long the executive waits for it to 200 µs, which its spin before each release absorbs.
""")
    late: dict[str, list[np.ndarray]] = {s: [] for s in SETUPS}
    for _ in range(rounds):
        for setup in SETUPS:
            measured = measure(setup, seconds, hogs)
            if isinstance(measured, str):
                section.notes.append(f"{setup}: {measured}: not measured")
                return section
            late[setup].append(measured)
    table = Table(["setup", "releases", "late p50 (µs)", "late p99 (µs)", "late max (µs)", "late > 1 period"],
                  numeric=(1, 2, 3, 4, 5))
    p99 = {}
    for setup in SETUPS:
        joined = np.concatenate(late[setup])
        p50, p99[setup] = percentiles(joined, (50, 99))
        table.add(setup, f"{len(joined):,}", f"{p50 * 1e6:.1f}", f"{p99[setup] * 1e6:.1f}", f"{joined.max() * 1e6:.0f}",
                  f"{int((joined > PERIOD).sum()):,}")
    section.tables.append(table)
    value = ratio(p99["pbo"], p99["before"])
    if value is not None:
        section.ratios["late p99 pbo / before"] = value
        section.notes.append(f"late p99 with the helper below the executive: {value:.3f}x what it was before")
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--hogs", type=int, default=2)
    parser.add_argument("--child", choices=SETUPS, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.seconds)
        return
    print(run(args.seconds, args.rounds, args.hogs).text())


if __name__ == "__main__":
    main()
