"""The wait before a release: what the timer slack, a spin and SCHED_FIFO each buy, and what they cost.

The executive sleeps in the kernel until `spin` before a release and spins the rest
(`RealClock.sleep_until`), with the timer slack lowered to 1 ns. This measures whether each part
pays on this machine, with the arm plant stepping at 1 kHz beside the loops:

- **variants**: the wait a plain loop would write (sleep to the release, default 50 µs timer
  slack); the same with 1 ns slack; then 1 ns slack with a spin of 50, 100, 200 (the default) and
  500 µs; and the default under SCHED_FIFO where the OS allows it (root or CAP_SYS_NICE);
- **loads**: one loop alone with the plant, and four loops at once (evenly staggered, as the
  supervisor staggers four RTPUs), where spinning takes CPU the others need: 2 vCPUs for 4
  loops and the plant;
- **rounds**: every variant runs once per round, in a new random order each round, so a change of
  load on the machine falls on all of them alike; figures pool the rounds.

Per variant: release jitter (p50, p99, max, over every loop's cycles), overruns (a cycle ending
after its next release: the executive's rule), and the CPU time the loops used per second of
wall time (what a spin costs). Ratios are against the 1 ns sleep without a spin, measured in the
same rounds.

    python -m bench.wait [--seconds 1.5] [--rounds 4]
"""

from __future__ import annotations

import argparse
import os
import random
import time
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from bench._common import Section, Table, ratio, us
from bench._processes import Workers
from bench.realtime import FIFO_PRIORITY, _bare_stretch, _Plant, config_path
from pbo_runtime.clock.clocks import RealClock, lower_timer_slack, release_stagger

PERIOD = 0.001
DEFAULT_SLACK_NS = 50_000  # Linux's default timer slack for a normal thread
BASELINE = "sleep, slack 1 ns"
DEFAULT = "spin 200 µs"


# name -> (spin seconds, timer slack ns, SCHED_FIFO)
VARIANTS: dict[str, tuple[float, int, bool]] = {
    "sleep, slack 50 µs": (0.0, DEFAULT_SLACK_NS, False),
    BASELINE: (0.0, 1, False),
    "spin 50 µs": (50e-6, 1, False),
    "spin 100 µs": (100e-6, 1, False),
    DEFAULT: (200e-6, 1, False),
    "spin 500 µs": (500e-6, 1, False),
    "spin 200 µs, SCHED_FIFO": (200e-6, 1, True),
}


def _loop_main(conn: Connection) -> None:
    """One loop process: runs a stretch per command (spin, slack, fifo, first release, end) until None."""
    conn.send("ready")
    while True:
        command = conn.recv()
        if command is None:
            return
        spin, slack_ns, fifo, first_release, end = command
        lower_timer_slack(slack_ns)
        scheduler = "SCHED_OTHER"
        try:
            if fifo:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
                scheduler = "SCHED_FIFO"
        except (OSError, AttributeError) as exc:
            scheduler = f"refused: {exc}"
        cpu_before, wall_before = time.process_time(), time.monotonic()
        record = _bare_stretch(RealClock(spin), PERIOD, first_release, end)
        cpu, wall = time.process_time() - cpu_before, time.monotonic() - wall_before
        if fifo and scheduler == "SCHED_FIFO":
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        conn.send({**record, "cpu": cpu, "wall": wall, "scheduler": scheduler})


def fifo_allowed() -> bool:
    """Whether this process may take SCHED_FIFO (tried, then given back)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except (OSError, AttributeError):
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


class Loops:
    """n loop processes, started once, each run stretch by stretch."""

    def __init__(self, n: int) -> None:
        self.workers = Workers(n, _loop_main, what="loop")
        self.n = n

    def stretch(self, variant: tuple[float, int, bool], seconds: float) -> list[dict[str, Any]]:
        spin, slack_ns, fifo = variant
        stagger = release_stagger(PERIOD, self.n)
        epoch = time.monotonic() + 0.05 + random.uniform(0.0, PERIOD)  # a random phase to the plant's steps
        self.workers.send_each([(spin, slack_ns, fifo, epoch + i * stagger, epoch + seconds) for i in range(self.n)])
        return self.workers.answers(seconds + 60)

    def close(self) -> None:
        self.workers.close()


def measure(n_loops: int, variants: dict[str, tuple[float, int, bool]], seconds: float, rounds: int) -> dict[str, dict[str, Any]]:
    """Per variant: every loop's samples pooled over the rounds, CPU share, and what the scheduler was."""
    pooled: dict[str, dict[str, Any]] = {name: {"jitter": [], "spanned": [], "cpu": 0.0, "wall": 0.0, "scheduler": set()}
                                         for name in variants}
    plant = _Plant(config_path(1), fifo=False)
    loops = Loops(n_loops)
    try:
        for _ in range(rounds):
            order = list(variants)
            random.shuffle(order)
            for name in order:
                for record in loops.stretch(variants[name], seconds):
                    p = pooled[name]
                    p["jitter"].append(record["jitter"])
                    p["spanned"].append(record["spanned"])
                    p["cpu"] += record["cpu"]
                    p["wall"] += record["wall"]
                    p["scheduler"].add(record["scheduler"])
    finally:
        loops.close()
        plant.stop()
    figures = {}
    for name, p in pooled.items():
        jitter, spanned = np.concatenate(p["jitter"]), np.concatenate(p["spanned"])
        figures[name] = {
            "cycles": len(jitter), "p50": float(np.percentile(jitter, 50)), "p99": float(np.percentile(jitter, 99)),
            "max": float(jitter.max()), "overruns": int(np.count_nonzero(spanned)),
            "cpu_per_loop": p["cpu"] / p["wall"] if p["wall"] else float("nan"),
            "scheduler": ", ".join(sorted(p["scheduler"])),
        }
    return figures


def _small_ratio(value: float | None) -> str:
    """A ratio that may be tiny (a spin turns tens of µs into tens of ns): '1/1,450' rather than '0.00x'."""
    if value is None:
        return "n/a"
    return f"{value:.2f}x" if value >= 0.1 else f"1/{1 / value:,.0f}"


def run(seconds: float = 1.5, rounds: int = 4, loads: tuple[int, ...] = (1, 4)) -> Section:
    variants = dict(VARIANTS)
    fifo_note = ""
    if not fifo_allowed():
        variants.pop("spin 200 µs, SCHED_FIFO")
        fifo_note = "SCHED_FIFO was refused to this user (it needs root or CAP_SYS_NICE): its row is left out."
    results = {n: measure(n, variants, seconds, rounds) for n in loads}
    section = Section(
        key="wait",
        title="The wait before a release: timer slack, spin and SCHED_FIFO",
        command=f"python -m bench.wait --seconds {seconds:g} --rounds {rounds}",
        method=f"""
Loops at 1 kHz with the arm plant (MuJoCo PUMA 560, 1 ms steps) stepping in its own process:
one loop alone, and {max(loads)} loops at once, evenly staggered over the period as the supervisor
staggers RTPUs (on 2 vCPUs, {max(loads)} loops and the plant compete for the CPUs). Each loop is the
executive's own wait, `RealClock.sleep_until` (absolute deadlines, `time.sleep` to `spin` before the
release, then a spin), and its overrun rule, with nothing else in the cycle. Variants: the plain
sleep with Linux's default 50 µs timer slack; the plain sleep with 1 ns slack (the baseline of the
ratios); 1 ns slack with a spin of 50, 100, 200 (the executive's default) and 500 µs; and the
default under SCHED_FIFO (priority {FIFO_PRIORITY}) where the OS allows it. {rounds} rounds of {seconds:g} s per
variant and load, the variants in a new random order each round; figures pool every loop and
round. CPU is the loops' process time per second of wall time, per loop.
""",
        limits="""A sleep ends when the kernel's timer fires and the scheduler runs the thread: the
timer slack (50 µs by default) lets the kernel defer the wake-up to batch timers, so a plain sleep
is late by about the slack at the median. Lowering it to 1 ns leaves the wake-up latency itself
(tens of µs on this VM, more when the other CPU must be interrupted). A spin hides that latency
when it is longer than the wake-up: the loop is already running when the release comes, and
its jitter is one clock read. The price is CPU: a 200 µs spin at 1 kHz is 20% of a CPU per loop,
which four loops on two vCPUs can only pay by taking it from each other and from the plant. The
tails (p99, max) are the machine's stalls, which no wait avoids; SCHED_FIFO lets a loop take the
CPU from every normal thread, the platform's own kernel threads included (`pbo run` asks for it
on the real clock; refused without root, CAP_SYS_NICE or `ulimit -r`, and the summary then says
so); `rtpus: {rtpu0: {cpu: 0}}` pins an RTPU to a CPU.""",
    )
    table = Table(["loops", "wait", "cycles", "jitter p50 µs", "jitter p99 µs", "jitter max µs", "overruns",
                   "CPU per loop", "p50 / baseline", "p99 / baseline"], numeric=(0, 2, 3, 4, 5, 6, 7, 8, 9))
    for n, figures in results.items():
        base = figures[BASELINE]
        for name, f in figures.items():
            p50_ratio, p99_ratio = ratio(f["p50"], base["p50"]), ratio(f["p99"], base["p99"])
            table.add(n, name, f"{f['cycles']:,}", us(f["p50"]), us(f["p99"]), us(f["max"]), f["overruns"],
                      f"{f['cpu_per_loop'] * 100:.1f}%", _small_ratio(p50_ratio), _small_ratio(p99_ratio))
            for q, value in (("p50", p50_ratio), ("p99", p99_ratio)):
                if value is not None:
                    section.ratios[f"{n} loops {name} {q} / baseline"] = value
        default = figures[DEFAULT]
        section.notes.append(
            f"{n} loop{'s' if n > 1 else ''}: the default spin (200 µs) against the sleep alone: jitter p50 "
            f"{us(base['p50'])} -> {us(default['p50'])} µs, p99 {us(base['p99'])} -> {us(default['p99'])} µs, for "
            f"{(default['cpu_per_loop'] - base['cpu_per_loop']) * 100:+.1f} points of a CPU per loop.")
    if fifo_note:
        section.notes.append(fifo_note)
    section.tables.append(table)
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=1.5, help="seconds per variant, load and round")
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args()
    print(run(args.seconds, args.rounds).text())


if __name__ == "__main__":
    main()
