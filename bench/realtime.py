"""Release jitter and overruns of the real subsystem against a bare hybrid-wait loop, same load.

For 1, 2 and 4 RTPUs at 1 kHz with the arm plant running:

- **pbo**: `pbo run bench/realtime_<n>rtpu.yaml --duration D --report FILE`: n RTPU processes,
  each hosting one trivial 1 kHz task; the executive's own figures from the JSON run report;
- **bare loop**: n plain processes, each running only the hybrid wait (absolute deadlines,
  `time.sleep` to 0.2 ms before the release, spin to it, timer slack lowered as the RTPUs do)
  and the executive's overrun rule, with the real plant process stepping, released at the same
  offsets as the supervisor staggers its RTPUs.

In each round the bare loop runs half its time right before the subsystem and half right after,
so a change of load on the machine falls on both alike; both sides are aggregated the same way.

    python -m bench.realtime [--duration 10] [--rounds 4] [--rtpus 1 2 4] [--fifo]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import tempfile
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from bench._common import REPO, Section, Table, Target, fmt_ratio, ratio, us
from pbo_runtime import _messages
from pbo_runtime._clock import lower_timer_slack
from pbo_runtime._config_loader import load_subsystem

SPIN = 0.0002  # RealClock's spin before a release
STAGGER_SHARE = 0.45  # the supervisor spreads RTPU release offsets over this share of the shortest period
FIFO_PRIORITY, PLANT_FIFO_PRIORITY = 50, 60  # as rtpu/_realtime.py and the plant host


def config_path(n_rtpus: int) -> Path:
    return Path(REPO) / "bench" / f"realtime_{n_rtpus}rtpu.yaml"


# --- the bare loop ------------------------------------------------------------------------------

def _bare_main(period: float, fifo: bool, conn: Connection) -> None:
    """The plain hybrid wait and the executive's overrun rule, nothing else."""
    lower_timer_slack()
    if fifo:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
        except (OSError, AttributeError):
            pass
    conn.send("ready")
    first_release, end = conn.recv()  # set once every loop is ready: a slow start must not count as jitter
    capacity = int((end - first_release) / period) + 16
    jitter = np.zeros(capacity)
    n = overruns = missed = 0
    now, sleep = time.monotonic, time.sleep
    release = first_release
    while release < end and n < capacity:
        remaining = release - now() - SPIN
        if remaining > 0:
            sleep(remaining)
        while now() < release:
            pass
        start = now()
        jitter[n] = start - release
        n += 1
        finished = now()
        following = release + period
        if finished > following:  # as the executive: count it, skip the releases gone, keep the phase
            overruns += 1
            skipped = int((finished - release) // period)
            missed += skipped - 1 if skipped > 1 else 0
            following = release + skipped * period
            if following <= finished:
                following += period
        release = following
    conn.send({"cycles": n, "overruns": overruns, "missed": missed, "jitter": jitter[:n]})


class _Plant:
    """The subsystem's plant process on its own (the real plant host), as the load for the bare loop."""

    def __init__(self, yaml_path: Path, fifo: bool) -> None:
        plant = load_subsystem(yaml_path).plant
        if plant is None:
            raise AssertionError(f"{yaml_path} has no plant")
        self.subsystem, self.run_id = "bench_bare", f"{os.getpid()}-{os.urandom(3).hex()}"
        self.events = _messages.Queue(_messages.event_queue_name(self.subsystem, self.run_id), create=True)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "pbo_runtime._plant_host", "--type", plant.type, "--model", plant.model,
             "--timestep", repr(plant.timestep), "--options", json.dumps(dict(plant.options)),
             "--subsystem", self.subsystem, "--run-id", self.run_id, "--parent", str(os.getpid()),
             *(["--fifo"] if fifo else [])],
            cwd=REPO,
        )
        deadline = time.monotonic() + 60
        while True:
            message = self.events.receive(1.0)
            if message and message[0] == "ready":
                break
            if message and message[0] == "crashed":
                self.stop()
                raise RuntimeError(f"the plant crashed: {message[2]}")
            if time.monotonic() > deadline or self.process.poll() is not None:
                self.stop()
                raise RuntimeError("the plant did not start within 60 s")
        self.stats: dict[str, int] = {}

    def stop(self) -> dict[str, int]:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        while True:
            message = self.events.receive(0)
            if message is None:
                break
            if message[0] == "plant_stats":
                self.stats = message[2]
        self.events.close()
        return self.stats


def bare_loops(n: int, seconds: float, period: float, yaml_path: Path, fifo: bool) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """n bare loop processes for `seconds` with the plant stepping; their records and the plant's."""
    ctx = multiprocessing.get_context("spawn")
    plant = _Plant(yaml_path, fifo)
    procs, pipes = [], []
    try:
        for _ in range(n):
            here, there = ctx.Pipe()
            p = ctx.Process(target=_bare_main, args=(period, fifo, there), daemon=True)
            p.start()
            procs.append(p)
            pipes.append(here)
        for here in pipes:
            if not here.poll(60) or here.recv() != "ready":
                raise RuntimeError("a bare loop process did not start within 60 s")
        stagger = STAGGER_SHARE * period / max(1, n - 1)
        epoch = time.monotonic() + 0.02
        for i, here in enumerate(pipes):
            here.send((epoch + i * stagger, epoch + seconds))
        records = [here.recv() for here in pipes if here.poll(seconds + 60)]
    finally:
        for p in procs:
            p.join(5)
            if p.is_alive():
                p.terminate()
        stats = plant.stop()
    if len(records) != n:
        raise RuntimeError(f"{n - len(records)} of {n} bare loop processes did not report")
    return records, stats


# --- the real subsystem -------------------------------------------------------------------------

def pbo_run(yaml_path: Path, seconds: float, fifo: bool, attempts: int = 3) -> dict[str, Any]:
    """`pbo run FILE --duration D --report JSON`: the run report.

    Retried when no report came: on a machine shared with other runs the per-user POSIX message
    queue quota (RLIMIT_MSGQUEUE) can be exhausted for a moment, and the run then refuses to start.
    """
    problem = ""
    for attempt in range(attempts):
        with tempfile.TemporaryDirectory() as folder:
            report = Path(folder) / "report.json"
            command = [sys.executable, "-m", "pbo_runtime.cli", "run", str(yaml_path), "--duration", f"{seconds:g}",
                       "--report", str(report), "--no-live", *(["--fifo"] if fifo else [])]
            done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=seconds + 120)
            if report.exists():
                return json.loads(report.read_text())
            tail = (done.stderr or done.stdout).strip().splitlines()[-1:]
            problem = f"`pbo run` wrote no report (exit {done.returncode}): {' / '.join(tail)}"
        time.sleep(3.0 * (attempt + 1))
    raise RuntimeError(problem)


def _summary(per_process: list[dict[str, float]]) -> dict[str, float]:
    """Aggregate one run's processes: median of p50s, worst p99 and max, summed counts."""
    cycles = sum(p["cycles"] for p in per_process)
    overruns = sum(p["overruns"] for p in per_process)
    return {
        "p50": float(np.median([p["p50"] for p in per_process])),
        "p99": max(p["p99"] for p in per_process),
        "max": max(p["max"] for p in per_process),
        "cycles": cycles,
        "overruns": overruns,
        "missed": sum(p["missed"] for p in per_process),
    }


def _over_rounds(runs: list[dict[str, float]]) -> dict[str, float]:
    """Aggregate rounds: medians of the rounds' p50 and p99 (one noisy round does not decide), worst max."""
    cycles = sum(r["cycles"] for r in runs)
    overruns = sum(r["overruns"] for r in runs)
    return {
        "p50": float(np.median([r["p50"] for r in runs])),
        "p99": float(np.median([r["p99"] for r in runs])),
        "max": max(r["max"] for r in runs),
        "cycles": cycles,
        "overruns": overruns,
        "missed": sum(r["missed"] for r in runs),
        "overrun_rate": overruns / cycles if cycles else float("nan"),
    }


def measure(n: int, seconds: float, fifo: bool, rounds: int = 4) -> dict[str, Any]:
    """`rounds` x (bare loop, pbo run, bare loop), `seconds` of each side in all."""
    yaml_path = config_path(n)
    subsystem = load_subsystem(yaml_path)
    period = min(t.period for t in subsystem.tasks.values())
    share = seconds / rounds
    pbo_runs, bare_runs, realtime = [], [], {}
    late = {"pbo": 0, "pbo_steps": 0, "bare": 0, "bare_steps": 0}
    for _ in range(rounds):
        first, plant_a = bare_loops(n, share / 2, period, yaml_path, fifo)
        report = pbo_run(yaml_path, share, fifo)
        second, plant_b = bare_loops(n, share / 2, period, yaml_path, fifo)
        bare = []
        for a, b in zip(first, second):
            j = np.concatenate([a["jitter"], b["jitter"]])
            bare.append({"p50": float(np.percentile(j, 50)), "p99": float(np.percentile(j, 99)), "max": float(j.max()),
                         "cycles": a["cycles"] + b["cycles"], "overruns": a["overruns"] + b["overruns"],
                         "missed": a["missed"] + b["missed"]})
        bare_runs.append(_summary(bare))
        try:
            pbo = [{"p50": t["jitter_p50"], "p99": t["jitter_p99"], "max": t["jitter_max"], "cycles": t["cycles"],
                    "overruns": t["overruns"], "missed": t["missed"]} for t in report["tasks"].values()]
        except (KeyError, TypeError, AttributeError) as exc:
            raise RuntimeError(f"the run report lacks per-task timing ({exc!r}): has `pbo run --report` changed?") from exc
        pbo_runs.append(_summary(pbo))
        plant = report.get("plant") or {}
        late["pbo"] += plant.get("late", 0)
        late["pbo_steps"] += plant.get("steps", 0)
        for stats in (plant_a, plant_b):
            late["bare"] += stats.get("late", 0)
            late["bare_steps"] += stats.get("steps", 0)
        realtime = report.get("realtime", {}) or realtime
    return {"pbo": _over_rounds(pbo_runs), "bare": _over_rounds(bare_runs), "plant_late": late, "realtime": realtime}


def run(seconds: float = 10.0, rtpus: tuple[int, ...] = (1, 2, 4), fifo: bool = False, rounds: int = 4) -> Section:
    results: dict[int, dict[str, Any]] = {}
    failures: dict[int, str] = {}
    for n in rtpus:
        try:
            results[n] = measure(n, seconds, fifo, rounds)
        except Exception as exc:  # one configuration failing must not hide the others
            failures[n] = f"{type(exc).__name__}: {exc}"
    scheduler = "SCHED_FIFO (RTPUs and bare loops 50, plant 60)" if fifo else "SCHED_OTHER"
    section = Section(
        key="realtime",
        title="Real-time quality: the executive against a bare hybrid-wait loop",
        command=f"python -m bench.realtime --duration {seconds:g} --rounds {rounds} --rtpus {' '.join(map(str, rtpus))}"
                + (" --fifo" if fifo else ""),
        method=f"""
For 1, 2 and 4 RTPUs at 1 kHz with the arm plant (MuJoCo PUMA 560, 1 ms steps) running, {scheduler}:

- **pbo**: `pbo run bench/realtime_<n>rtpu.yaml --duration {seconds / rounds:g} --report FILE`, {rounds} times: n RTPU processes, each
  hosting one trivial 1 kHz task (a goal input, a time integrator, a join, a fault injector that never
  fires: different modules because a module runs at most once per configuration); the figures are the
  executive's own, from the JSON run report.
- **bare loop**: n plain processes running only the hybrid wait (absolute deadlines, `time.sleep` to
  0.2 ms before the release, spin to it, timer slack 1 ns) and the executive's overrun rule, released at
  the offsets the supervisor staggers its RTPUs by, with the real plant host process stepping. Each
  round runs it {seconds / rounds / 2:g} s right before the subsystem and {seconds / rounds / 2:g} s right after it, so a change of
  load on the machine falls on both alike.

Release jitter is how late a cycle started after its release time; an overrun is a cycle that ended
after its next release (the releases skipped are the "missed" ones). Both sides are aggregated the
same way: within a run, the median of the processes' p50s and the worst process's p99 and max;
over the {rounds} rounds, the median of the runs' p50s and p99s and the worst max. Counts are summed.
""",
        limits="""The medians: both sides sleep in the kernel and spin the last 0.2 ms, so both
medians are tiny. The executive's is higher by its Python work between the end of the spin and
the release timestamp (returning from the wait, picking the most urgent ready task): a fraction
of a µs, but a large p50 ratio over a bare loop that does nothing there. The tails are the machine's: with
more busy processes than CPUs (4 RTPUs and the plant on 2 vCPUs, each loop spinning up to 0.2 ms
per release), a loop whose release falls on the plant's step or on another loop's spin waits for
a CPU, and that phase is set by when each process happened to start, differently in every run;
hence several rounds and medians. On this shared VM other tenants add their own delays.
SCHED_FIFO (`--fifo`) is the largest lever where the OS allows it.""",
    )
    t = Table(["RTPUs", "loop", "cycles", "jitter p50 µs", "jitter p99 µs", "jitter max µs", "overruns", "overrun rate",
               "missed", "plant steps late"], numeric=(0, 2, 3, 4, 5, 6, 7, 8, 9))
    r_table = Table(["RTPUs", "p50 pbo / bare", "p99 pbo / bare", "overrun rate pbo / bare", "p50 pbo - bare µs",
                     "p99 pbo - bare µs"], numeric=(0, 1, 2, 3, 4, 5), caption="Ratios (target: within 1.5x) and differences:")
    for n in rtpus:
        if n in failures:
            t.add(n, "failed", failures[n], "", "", "", "", "", "", "")
            continue
        r = results[n]
        for side in ("pbo", "bare"):
            s = r[side]
            late = r["plant_late"][side]
            steps = r["plant_late"][f"{side}_steps"]
            t.add(n, "pbo executive" if side == "pbo" else "bare hybrid wait", f"{s['cycles']:,}", us(s["p50"]), us(s["p99"]),
                  us(s["max"]), s["overruns"], f"{s['overrun_rate'] * 100:.2f}%", s["missed"], f"{late} of {steps:,}")
        ratios = {}
        for q in ("p50", "p99", "overrun_rate"):
            ratios[q] = ratio(r["pbo"][q], r["bare"][q])
            if ratios[q] is not None:
                section.ratios[f"{n} rtpus {q} pbo / bare"] = ratios[q]
        bare_zero = r["bare"]["overruns"] == 0
        overrun_cell = fmt_ratio(ratios["overrun_rate"])
        if ratios["overrun_rate"] is None:
            overrun_cell = "equal (0 and 0)" if r["pbo"]["overruns"] == 0 and bare_zero else f"n/a (bare: 0, pbo: {r['pbo']['overruns']})"
        r_table.add(n, fmt_ratio(ratios["p50"]), fmt_ratio(ratios["p99"]), overrun_cell,
                    f"{(r['pbo']['p50'] - r['bare']['p50']) * 1e6:+.2f}", f"{(r['pbo']['p99'] - r['bare']['p99']) * 1e6:+,.0f}")
        for q, label in (("p50", "jitter p50"), ("p99", "jitter p99")):
            section.targets.append(Target(f"{n} RTPU{'s' if n > 1 else ''}: {label}, pbo / bare", ratios[q], 1.5))
        if r["pbo"]["overruns"] == 0 and bare_zero:
            section.notes.append(f"{n} RTPU{'s' if n > 1 else ''}: no overrun on either side.")
        else:
            section.targets.append(Target(f"{n} RTPU{'s' if n > 1 else ''}: overrun rate, pbo / bare", ratios["overrun_rate"], 1.5,
                                          note="" if ratios["overrun_rate"] is not None
                                          else f"the bare loop had no overrun, the executive {r['pbo']['overruns']}"))
        realtime = r["realtime"]
        if realtime:
            settings = sorted({", ".join(f"{k} {v}" for k, v in s.items()) for s in realtime.values()})
            section.notes.append(f"{n} RTPU{'s' if n > 1 else ''}: the RTPUs reported: {'; '.join(settings)}.")
    section.tables += [t, r_table]
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=10.0, help="seconds of pbo run per RTPU count (the bare loop runs as long)")
    parser.add_argument("--rtpus", type=int, nargs="+", default=[1, 2, 4], choices=[1, 2, 4])
    parser.add_argument("--rounds", type=int, default=4, help="rounds of (bare, pbo, bare); the duration is split over them")
    parser.add_argument("--fifo", action="store_true", help="SCHED_FIFO for both sides and the plant (root or CAP_SYS_NICE)")
    args = parser.parse_args()
    print(run(args.duration, tuple(args.rtpus), args.fifo, args.rounds).text())


if __name__ == "__main__":
    main()
