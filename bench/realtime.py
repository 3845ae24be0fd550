"""Release jitter and overruns of the real subsystem against a bare hybrid-wait loop, in the same run.

For 1, 2 and 4 RTPUs at 1 kHz with the arm plant running, in paired rounds:

- **pbo**: `pbo run bench/realtime_<n>rtpu.yaml --duration D --report FILE`: n RTPU processes,
  each hosting one trivial 1 kHz task, and the plant host stepping the arm; the executive's own
  figures from the JSON run report;
- **bare loop**: n plain processes, each running only the hybrid wait and the executive's overrun
  rule. The wait is the executive's own `RealClock.sleep_until` (absolute deadlines counted as
  first + k x period, `time.sleep` to 0.2 ms before the release, spin to it, timer slack lowered
  as the RTPUs do), so the spin is the same code on both sides.

Same CPU: RTPU i is pinned (`rtpus: {rtpuI: {cpu: N}}`, in a copy of the file) to the same CPU
as bare loop i, and the bare loop is released in the middle between the releases of the RTPUs
on that CPU (`bare_phases`; the run's release epoch is in its table's header). The CPUs turn by
one each round. Why: the host wakes an idle virtual CPU late now and then, by 1 to 8 ms, while
the other runs on time. Left to the kernel, the plant (SCHED_FIFO 60) sat on one vCPU, the
RTPU started beside it went to the other, and the bare loop, warm from the round before, went
either way: in 60 rounds at 1 RTPU traced by a one-off script (2026-11-25) the RTPU had a vCPU to itself in 25, the
bare loop in 11. A vCPU that hosts one loop idles between its releases; in the round that
read 11:2, 7 of the 8 executive overruns the trace kept were its timer firing late there, while
the other vCPU woke the plant and the bare loop on time. Interleaved rounds of the two
designs that day read 19:13 (1.46x) left to the kernel and 18:24 (0.75x) sharing a CPU, where
nearly every round's counts came in equal pairs (1:1, 2:2, 3:3).

Same run, same load: the bare loops run while the `pbo run` runs, from the instant it says its
configuration is on until its duration ends, so both sides share the same seconds of the machine.
This matters for overruns. Under SCHED_FIFO nearly all are stalls of the virtual machine: the
timer that ends a loop's wait fires 1 to 8 ms late, on one vCPU or on both (`tools/cpu_trace.py`
shows each wake-up). A stall makes every loop on the stalled vCPUs overrun at once, both sides'
alike since they share each CPU, and the ratio cancels it. When the sides took turns instead
(bare - pbo - bare - ..., until 2026-11-25), a stall fell on one side only. One round of 5 s
then held 29 of a run's 46 executive overruns, and the ratio swung from 0.99x to 4.50x between
two runs. The price is load: both sides add their n loops to the other's, so each side runs
beside 2n spinning loops and the plant instead of n.

Like with like: both sides time a release at the clock reading that ended the spin (the value
`sleep_until` returns). The executive's choice of the task to run and its call into it come
after that instant and count in its execution time, not its jitter, as the bare loop's nothing
does.

Each round gives a p50 and a p99 ratio; the verdict takes their median over the rounds and shows
their spread. Overruns are rare events (a few per 100,000 cycles) that come in bursts: their rate ratio
pools the rounds and comes with a 95% interval from resampling whole rounds
(`round_bootstrap_interval`).

Both sides run under the runtime's default scheduler, SCHED_FIFO where the OS allows it, which
the targets judge; then under SCHED_OTHER (`pbo run --no-fifo`), reported beside it.

    python -m bench.realtime [--duration 240] [--rounds 48] [--rtpus 1 2 4] [--other-duration 60] [--other-rounds 12]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench._common import REPO, Section, Table, Target, fmt_ratio, ratio, us
from bench._processes import Workers
from pbo_runtime.clock.clocks import RealClock, lower_timer_slack, release_stagger
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.config.model import DEFAULT_SPIN
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.control import find_live_run
from pbo_runtime.ipc.shm import attach_segment
from pbo_runtime.reports.run_summary import scheduler_outcome
from pbo_runtime.supervisor.cleanup import remove_run
from pbo_runtime.table.table import Header
from rtpu._realtime import FIFO_PRIORITY  # as the RTPUs take it (the plant host takes its own, above)

SPIN = DEFAULT_SPIN  # the executive's spin before a release, unless an RTPU gives its own
CONFIDENCE = 0.95  # of the overrun rate ratio's interval (a bootstrap over rounds)


def config_path(n_rtpus: int) -> Path:
    return Path(REPO) / "bench" / f"realtime_{n_rtpus}rtpu.yaml"


# --- the bare loop ------------------------------------------------------------------------------

def _bare_main(period: float, fifo: bool, conn: Connection) -> None:
    """One bare loop process: runs a stretch per (first release, end, CPU) received, until None.

    It pins itself to the CPU it is given (None: any), as an RTPU pins itself to its `cpu:`.
    """
    lower_timer_slack()
    if fifo:
        with contextlib.suppress(OSError, AttributeError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
    clock = RealClock(SPIN)
    every_cpu = os.sched_getaffinity(0)
    conn.send("ready")
    while True:
        command = conn.recv()
        if command is None:
            return
        first_release, end, cpu = command  # set once every loop is ready: a slow start must not count as jitter
        with contextlib.suppress(OSError, ValueError):  # as an RTPU refused its CPU, it runs on where it is
            os.sched_setaffinity(0, every_cpu if cpu is None else {cpu})
        conn.send(_bare_stretch(clock, period, first_release, end))


def _bare_stretch(clock: RealClock, period: float, first_release: float, end: float) -> dict[str, np.ndarray]:
    """The plain hybrid wait and the executive's overrun rule, nothing else.

    Per cycle: its jitter, and 0 or, for an overrun, how many periods it spanned (the executive
    counts the overrun and misses all but one of them).
    """
    capacity = int((end - first_release) / period) + 16
    # written now, as the executive writes its rings at spawn: no page fault every 512 cycles
    jitter = np.full(capacity, 0.0)
    spanned = np.full(capacity, 0, dtype=np.int64)
    now, sleep_until = clock.now, clock.sleep_until
    n = index = 0
    release = first_release
    while release < end and n < capacity:
        start = sleep_until(release)  # the reading that ended the spin, as the executive times it
        jitter[n] = start - release
        finished = now()
        index += 1
        following = first_release + index * period  # counted, never summed, as the executive
        if finished > following:  # as the executive: count it, skip the releases gone, keep the phase
            periods = int((finished - release) // period)
            spanned[n] = periods
            index += periods - 1
            following = first_release + index * period
            if following <= finished:
                index += 1
                following = first_release + index * period
        n += 1
        release = following
    return {"jitter": jitter[:n], "spanned": spanned[:n]}


class _Plant:
    """The subsystem's plant process on its own (the real plant host), as the load for the bare loop."""

    def __init__(self, yaml_path: Path, fifo: bool) -> None:
        plant = load_subsystem(yaml_path).plant
        if plant is None:
            raise AssertionError(f"{yaml_path} has no plant")
        self.subsystem, self.run_id = "bench_bare", f"{os.getpid()}-{os.urandom(3).hex()}"
        self.events = messages.Queue(messages.event_queue_name(self.subsystem, self.run_id), create=True)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "pbo_runtime.supervisor.plant_host", "--type", plant.type, "--model", plant.model,
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
        remove_run(self.subsystem, self.run_id)  # a plant killed after its grace leaves its segment to us
        return self.stats


def _started_run(yaml_path: Path, seconds: float, fifo: bool, report: Path,
                 attempts: int = 3) -> tuple[subprocess.Popen[str], float]:
    """`pbo run FILE --duration D --report JSON`, started; returns once its configuration is on,
    with the instant the run said so (its D seconds count from there).

    Retried when the run does not come up: on a machine shared with other runs the per-user POSIX
    message queue quota (RLIMIT_MSGQUEUE) can be exhausted for a moment, and the run then refuses
    to start.
    """
    command = [sys.executable, "-m", "pbo_runtime.cli", "run", str(yaml_path), "--duration", f"{seconds:g}",
               "--report", str(report), "--out", str(report.with_suffix("")),  # its files beside the report, not in the checkout
               "--no-live", "--fifo" if fifo else "--no-fifo"]
    problem = ""
    for attempt in range(attempts):
        run = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert run.stdout is not None
        said = []
        for line in run.stdout:  # the supervisor flushes each line as it says it
            if "is on:" in line:
                return run, time.monotonic()
            said.append(line.strip())
        run.wait()
        problem = f"`pbo run` did not turn its configuration on (exit {run.returncode}): {' / '.join(said[-2:])}"
        if run.returncode == 1:  # the file has errors: trying again cannot help
            break
        time.sleep(3.0 * (attempt + 1))
    raise RuntimeError(problem)


def placement(n: int, cpus: list[int], round_index: int) -> list[int]:
    """The CPU of RTPU i (and of bare loop i) in a round: the CPUs in turn, turned by one each round.

    Turning them moves every RTPU over every CPU across the rounds, so no side keeps a CPU the
    host serves worse.
    """
    return [cpus[(i + round_index) % len(cpus)] for i in range(n)]


def bare_phases(where: list[int], period: float) -> list[float]:
    """When bare loop i is released, after the run's epoch (within a period): midway from RTPU i's
    release to the next release of an RTPU on the same CPU, so the loops on a CPU spin one after
    another, never together."""
    stagger = release_stagger(period, len(where))
    phases = []
    for i, cpu in enumerate(where):
        mine = i * stagger
        following = min(((j * stagger - mine) % period or period) for j, other in enumerate(where) if other == cpu)
        phases.append(mine + following / 2)
    return phases


def pinned_config(yaml_path: Path, cpus: list[int], folder: Path) -> tuple[Path, str]:
    """A copy of the benchmark's file with RTPU i pinned to `cpus[i]` (`rtpus: {name: {cpu: N}}`), and its subsystem's name."""
    document = yaml.safe_load(yaml_path.read_text())
    names = list(document["rtpus"])
    document["rtpus"] = {name: {"cpu": cpu} for name, cpu in zip(names, cpus, strict=True)}
    pinned = folder / yaml_path.name
    pinned.write_text(yaml.safe_dump(document, sort_keys=False))
    return pinned, document["subsystem"]


def release_epoch(subsystem: str) -> float:
    """The CLOCK_MONOTONIC second the live run's RTPUs release from (its table's header)."""
    _sub, _run_id, table_name = find_live_run(subsystem)
    segment = attach_segment(table_name)
    try:
        (epoch_ns,) = struct.unpack_from("q", segment, 8 * Header.RELEASE_EPOCH_NS)  # the header's int64 words
    finally:
        segment.close()
    if not epoch_ns:
        raise RuntimeError(f"the run of '{subsystem}' published no release epoch (a simulated clock?)")
    return epoch_ns / 1e9


def paired_round(workers: Workers, yaml_path: Path, n: int, period: float, seconds: float,
                 fifo: bool, round_index: int = 0) -> tuple[dict[str, Any], list[dict[str, np.ndarray]]]:
    """One round: `pbo run` for `seconds` and the n bare loops over the same seconds, at the same time.

    The bare loops start once the run's configuration is on and stop when its duration ends, so
    a stall of the machine, a burst of the kernel's work, another tenant's minute all fall on both
    sides at once. Bare loop i shares RTPU i's CPU (`placement`) and is released between the
    releases of the RTPUs there (`bare_phases`): the host's stalls of one virtual CPU then fall
    on both sides too. The plant runs where the kernel puts it, at its own phase to both.
    """
    cpus = sorted(os.sched_getaffinity(0))
    where = placement(n, cpus, round_index)
    with tempfile.TemporaryDirectory() as folder:
        report = Path(folder) / "report.json"
        pinned, subsystem = pinned_config(yaml_path, where, Path(folder))
        run, on = _started_run(pinned, seconds, fifo, report)
        try:
            epoch = release_epoch(subsystem)
            first = epoch + math.ceil((on + 0.01 - epoch) / period) * period  # a release of RTPU 0 after the start
            phase_cpus = zip(bare_phases(where, period), where, strict=True)
            workers.send_each([(first + phase, on + seconds, cpu) for phase, cpu in phase_cpus])
            records = workers.answers(seconds + 60)
            said, _ = run.communicate(timeout=120)
        finally:
            if run.poll() is None:  # stopped as Ctrl-C stops it, so it removes its shared memory
                run.send_signal(signal.SIGINT)
                try:
                    run.wait(15)
                except subprocess.TimeoutExpired:
                    run.kill()
                    run.wait()
        if not report.exists():
            tail = said.strip().splitlines()[-1:]
            raise RuntimeError(f"`pbo run` wrote no report (exit {run.returncode}): {' / '.join(tail)}")
        return json.loads(report.read_text()), records


def _figures(jitter: np.ndarray, spanned: np.ndarray) -> dict[str, float]:
    """One process's figures from its samples, as the executive's run report gives them."""
    return {"p50": float(np.percentile(jitter, 50)), "p99": float(np.percentile(jitter, 99)), "max": float(jitter.max()),
            "cycles": len(jitter), "overruns": int(np.count_nonzero(spanned)),
            "missed": int(np.maximum(spanned - 1, 0).sum())}


def _summary(per_process: list[dict[str, float]]) -> dict[str, float]:
    """Aggregate one run's processes: median of p50s, worst p99 and max, summed counts."""
    return {
        "p50": float(np.median([p["p50"] for p in per_process])),
        "p99": max(p["p99"] for p in per_process),
        "max": max(p["max"] for p in per_process),
        "cycles": sum(p["cycles"] for p in per_process),
        "overruns": sum(p["overruns"] for p in per_process),
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


def round_bootstrap_interval(rounds: list[tuple[dict[str, float], dict[str, float]]], confidence: float = CONFIDENCE,
                             draws: int = 5000, seed: int = 6) -> tuple[float, float]:
    """Interval for the pooled overrun-rate ratio pbo / bare, resampling whole rounds.

    Overruns are not independent events: a stall of the VM makes every RTPU overrun at once, and
    stalls come in bursts (one round of 5 s once had 266 of a run's 618). An interval that counts
    each overrun as independent (Poisson) is then far too narrow; the round, in which both sides
    ran back to back, is the unit that is independent enough to resample.
    """
    k_pbo = np.array([p["overruns"] for p, _ in rounds], dtype=float)
    n_pbo = np.array([p["cycles"] for p, _ in rounds], dtype=float)
    k_bare = np.array([b["overruns"] for _, b in rounds], dtype=float)
    n_bare = np.array([b["cycles"] for _, b in rounds], dtype=float)
    picks = np.random.default_rng(seed).integers(0, len(rounds), size=(draws, len(rounds)))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = (k_pbo[picks].sum(1) / n_pbo[picks].sum(1)) / (k_bare[picks].sum(1) / n_bare[picks].sum(1))
    ratios = np.where(np.isnan(ratios), 1.0, ratios)  # no overrun on either side in a draw: equal
    tail = (1.0 - confidence) / 2
    low, high = np.quantile(ratios, [tail, 1.0 - tail], method="inverted_cdf")  # no interpolation: inf stays inf
    return float(low), float(high)


def measure(n: int, seconds: float, fifo: bool, rounds: int = 8) -> dict[str, Any]:
    """`rounds` paired rounds, `seconds` in all; per round, the two sides' figures."""
    yaml_path = config_path(n)
    subsystem = load_subsystem(yaml_path)
    period = min(t.period for t in subsystem.tasks.values())
    pbo_runs, bare_runs, exec_p50s, realtime = [], [], [], {}
    plant_late = plant_steps = 0
    cpus_seen: dict[str, list[str]] = {}
    with Workers(n, _bare_main, (period, fifo), what="bare loop") as workers:
        for index in range(rounds):
            report, records = paired_round(workers, yaml_path, n, period, seconds / rounds, fifo, index)
            bare_runs.append(_summary([_figures(r["jitter"], r["spanned"]) for r in records]))
            try:
                tasks = report["tasks"].values()
                pbo = [{"p50": t["jitter_p50"], "p99": t["jitter_p99"], "max": t["jitter_max"], "cycles": t["cycles"],
                        "overruns": t["overruns"], "missed": t["missed"]} for t in tasks]
                exec_p50s.append(float(np.median([t["exec_p50"] for t in tasks])))
            except (KeyError, TypeError, AttributeError) as exc:
                raise RuntimeError(f"the run report lacks per-task timing ({exc!r}): has `pbo run --report` changed?") from exc
            pbo_runs.append(_summary(pbo))
            plant = report.get("plant") or {}
            plant_late += plant.get("late", 0)
            plant_steps += plant.get("steps", 0)
            for rtpu, settings in (report.get("realtime") or {}).items():  # the CPUs turn: name every one
                seen, cpu = cpus_seen.setdefault(rtpu, []), settings.get("cpu", "?")
                if cpu not in seen:
                    seen.append(cpu)
                realtime[rtpu] = {**settings, "cpu": " then ".join(seen)}
    return {"pbo": _over_rounds(pbo_runs), "bare": _over_rounds(bare_runs), "rounds": list(zip(pbo_runs, bare_runs, strict=True)),
            "exec_p50": float(np.median(exec_p50s)), "plant_late": (plant_late, plant_steps), "realtime": realtime}


def _spread(values: list[float]) -> str:
    return f"{min(values):.2f}-{max(values):.2f}x" if values else "n/a"


def run(seconds: float = 240.0, rtpus: tuple[int, ...] = (1, 2, 4), rounds: int = 48,
        other_seconds: float = 60.0, other_rounds: int = 12) -> Section:
    """The comparison under the runtime's default scheduler (SCHED_FIFO where the OS allows it),
    judged against the targets, then under SCHED_OTHER (`--no-fifo`, or what an unprivileged user
    gets), reported beside it; `other_seconds=0` leaves that out."""
    plan = [("fifo", seconds, rounds)] + ([("other", other_seconds, other_rounds)] if other_seconds > 0 else [])
    results: dict[tuple[str, int], dict[str, Any]] = {}
    failures: dict[tuple[str, int], str] = {}
    for scheduler, scheduler_seconds, scheduler_rounds in plan:
        for n in rtpus:
            try:
                results[scheduler, n] = measure(n, scheduler_seconds, scheduler == "fifo", scheduler_rounds)
            except Exception as exc:  # one configuration failing must not hide the others
                failures[scheduler, n] = f"{type(exc).__name__}: {exc}"
    share = seconds / rounds
    section = Section(
        key="realtime",
        title="Real-time quality: the executive against a bare hybrid-wait loop",
        command=f"python -m bench.realtime --duration {seconds:g} --rounds {rounds} --rtpus {' '.join(map(str, rtpus))} "
                f"--other-duration {other_seconds:g} --other-rounds {other_rounds}",
        method=f"""
For 1, 2 and 4 RTPUs at 1 kHz with the arm plant (MuJoCo PUMA 560, 1 ms steps) running, under each
scheduler in turn: first the runtime's default, **SCHED_FIFO** where the OS allows it (RTPUs and bare
loops at priority 50, the plant at 60; `pbo run` asks for it on the real clock), which the targets
judge; then **SCHED_OTHER** (`pbo run --no-fifo`, and what a user gets where the OS refuses
SCHED_FIFO), {other_seconds:g} s in {other_rounds} rounds, reported beside it. Both sides always run
under the same scheduler, and at the same time:

- **pbo**: `pbo run bench/realtime_<n>rtpu.yaml --duration {share:g} --report FILE`, {rounds} times: n RTPU
  processes, each hosting one trivial 1 kHz task (a goal input, a time integrator, a join, a fault
  injector that never fires: different modules because a module runs at most once per
  configuration), and the plant host; the figures are the executive's own, from the JSON run report.
- **bare loop**: n plain processes running only the hybrid wait, with the executive's own
  `RealClock.sleep_until` (absolute deadlines, `time.sleep` to 0.2 ms before the release, spin to it,
  timer slack 1 ns), and the executive's overrun rule.
- **same CPU**: RTPU i (pinned with `rtpus: {{rtpuI: {{cpu: N}}}}` in a copy of the file) and bare loop i
  share a CPU, the bare loop released midway between the releases of the RTPUs there; the CPUs
  turn by one each round. The plant runs where the kernel puts it, at its own phase to both. The
  host wakes an idle vCPU late now and then (1 to 8 ms) while the other runs on time, and then
  both sides' loops there are late together (below).
- **paired rounds**: in each of the {rounds} rounds the bare loops run while the `pbo run` runs, from
  the instant it says its configuration is on until its {share:g} s end. Whatever the machine does
  in those seconds, a stall of the virtual CPUs, a burst of kernel work, another tenant's load,
  falls on both sides at once. Each side runs beside the other's n loops as well as its own: 2n
  loops and the plant in all.

Release jitter is how late a cycle started after its release time, timed on both sides at the
clock reading that ended the spin (the executive's pick of the task and its call into it count
in its execution time, as they come after the release); an overrun is a cycle that ended after
its next release (the releases skipped are the "missed" ones). "Plant steps late" counts the
plant's whole life, the RTPUs' start and their spawns included. Within a round: the median of
the processes' p50s, the worst process's p99 and max. Per round: the ratio pbo / bare of the p50s
and of the p99s; the verdict takes the median of the {rounds} rounds' ratios (their range in
brackets). Overruns are rare: their rate ratio pools the rounds' counts, with a
{CONFIDENCE:.0%} interval from resampling whole rounds (a bootstrap: overruns come in bursts that
hit every loop at once, so single overruns are not independent). The rows of the first table are
medians over the rounds (p50, p99), the worst max, and summed counts.
""",
        limits="""The medians: both sides spin the last 0.2 ms to the release in the same code, so
both medians are the spin's own resolution, a few tens of ns (one clock read in CPython), and
their ratio is near 1. The tails are the machine's: with more busy processes than CPUs (at 4
RTPUs, 8 loops and the plant on 2 vCPUs, each loop spinning up to 0.2 ms per release), a loop
whose release falls on the plant's step waits for a CPU (the loops sharing a CPU are released
apart and spin one after another, unless one runs late). The
executive's process also does more per release than the bare loop (its timed wait on the signal
queue, the task's cycle: 10 to 20 µs), and a supervisor process runs beside it (awake every
100 ms to check its children and serve commands). Per round, p99 is either a few tenths of a µs
or tens of µs, as more or fewer than 1% of a loop's cycles were disturbed: a round's p99 ratio
can read 0.01x or 300x, and only the median over the rounds says something.

Under SCHED_OTHER, overruns are a few per 10,000 cycles on either side, and nearly all are late
releases (1 to 5 ms), not long cycles (the run summary and report tell the two apart). A
sched_switch trace of a 4-RTPU run (tracefs, CLOCK_MONOTONIC) showed what holds the CPU then:
not the loops' neighbours (while a loop waited, the other CPU was mostly idle) but foreign
threads that take a CPU for 1 to 2 ms, the VM's memory monitor kdamond, kcompactd and the
sandbox's agent; a loop on that CPU, spinning or due to wake, waits them out
(`tools/cpu_trace.py --no-fifo` names them for each overrun of a run). Such a thread holds one
CPU, so it makes the loops on that CPU overrun and not the others: one of each side, since bare
loop i shares RTPU i's CPU.

Under SCHED_FIFO no thread of the machine outranks a loop but the kernel's own real-time ones:
kdamond and the agent wait, and the overruns left are rarer (the first table). They are the
host's: `tools/cpu_trace.py` shows, for each, when the RTPU was woken. Nearly always either its
timer fired late (its wait was to end 0.2 ms before the release, and ended 1 to 8 ms after it),
or it was woken on time and its vCPU then did not run it; no setting inside the machine
prevents either.
(On this VM the switch out of the idle task is never traced on CPU 1: until 2026-11-25 the tool
counted a task's time there as idle, and read some of these as both CPUs idle.) Until 2026-11-25
the two sides took turns (bare, pbo, bare, ...), and a stall fell on one side only: one
round of 5 s held 29 of a run's 46 executive overruns at 4 RTPUs, and the ratio pooled over the
RTPU counts read 4.50x in one run and 0.99x in the next. Run at the same time, a stall makes
every loop of both sides overrun together (at 4 RTPUs on 2026-11-25: rounds of 30:30 and 4:4), and
the ratio keeps what is the executive's own.

Not every stall takes both vCPUs: the host wakes one idle vCPU late while the other runs on
time. Until 2026-11-25 the kernel placed the loops: the plant (SCHED_FIFO 60) sat on one vCPU,
the RTPU started beside it mostly went to the other, and the bare loop, warm from the round
before, went either way. The RTPU then had a vCPU to itself more often than the bare loop, and
the late wake-ups of a lone idle vCPU fell on it more often: a scheduler trace of those rounds
showed its timers firing late there while the other vCPU woke the plant and the bare loop on
time (`tools/cpu_trace.py` shows when each overrun's RTPU was woken). Since then bare loop i
shares RTPU i's CPU and the CPUs turn each round, and a round's counts mostly come in equal
pairs (the per-round table). At 1 RTPU, with the fewest overruns, the ratio still rests on a
few dozen.

Release offsets matter: spread over 0.45 of the period (until issue 6), 4 RTPUs spun inside each
other's spin and p99 was about 180 µs on both sides; spaced evenly (i/n of the period) it is
tens of µs.""",
    )
    _tables(section, results, failures, rtpus, {"fifo": rounds, "other": other_rounds})
    return section


SCHEDULER_LABELS = {"fifo": "FIFO", "other": "OTHER"}


def _scheduler_granted(result: dict[str, Any]) -> str:
    """What the RTPUs of a comparison ran under, from their run report: SCHED_FIFO or SCHED_OTHER."""
    outcomes = [scheduler_outcome(settings.get("scheduler", "")) for settings in result["realtime"].values()]
    return "SCHED_FIFO" if outcomes and all(o == "fifo" for o in outcomes) else "SCHED_OTHER"


def _overrun_ratio(rounds: list[tuple[dict[str, float], dict[str, float]]]) -> tuple[float | None, int, int, str]:
    """The pooled overrun-rate ratio pbo / bare (0 when pbo had none; None when the bare loop had none),
    both counts, and the interval from resampling rounds, printed."""
    pbo_k, bare_k = sum(p["overruns"] for p, _ in rounds), sum(b["overruns"] for _, b in rounds)
    pbo_n, bare_n = sum(p["cycles"] for p, _ in rounds), sum(b["cycles"] for _, b in rounds)
    value = (pbo_k / pbo_n) / (bare_k / bare_n) if bare_k and pbo_n and bare_n else None
    low, high = round_bootstrap_interval(rounds)
    return value, pbo_k, bare_k, f"[{low:.2f}-{'∞' if math.isinf(high) else f'{high:.2f}'}x]"


def _overrun_cell(value: float | None, pbo_k: int, bare_k: int, interval: str) -> str:
    if value is not None:
        return f"{fmt_ratio(value)} {interval}"
    if pbo_k == 0 and bare_k == 0:
        return "equal (0 and 0)"
    return f"n/a (bare: 0, pbo: {pbo_k}) {interval}"


def _tables(section: Section, results: dict[tuple[str, int], dict[str, Any]], failures: dict[tuple[str, int], str],
            rtpus: tuple[int, ...], rounds_of: dict[str, int]) -> None:
    """The figures, the ratios and the per-round counts of every comparison; the targets of the default's."""
    t = Table(["scheduler", "RTPUs", "loop", "cycles", "jitter p50 µs", "jitter p99 µs", "jitter max µs", "overruns",
               "overrun rate", "missed", "plant steps late"], numeric=(1, 3, 4, 5, 6, 7, 8, 9, 10))
    r_table = Table(["scheduler", "RTPUs", "p50 pbo / bare", "p99 pbo / bare", "overrun rate pbo / bare",
                     "p50 pbo - bare µs", "p99 pbo - bare µs"], numeric=(1, 2, 3, 4, 5, 6),
                    caption=f"Ratios (target: within 1.5x, judged under the default scheduler): p50 and p99, median of "
                            f"the rounds' ratios [range]; overrun rate, pooled [{CONFIDENCE:.0%} interval]; differences, "
                            f"median of the rounds'. The row \"all\" pools every RTPU count's rounds:")
    per_round = Table(["scheduler", "RTPUs", "p50 pbo / bare", "p99 pbo / bare", "overruns pbo : bare"], numeric=(1,),
                      caption="Per round, in order:")
    for scheduler in ("fifo", "other"):
        label = SCHEDULER_LABELS[scheduler]
        pooled: list[tuple[dict[str, float], dict[str, float]]] = []
        for n in rtpus:
            if (scheduler, n) in failures:
                t.add(label, n, "failed", failures[scheduler, n], "", "", "", "", "", "", "")
                continue
            if (scheduler, n) not in results:
                continue
            r = results[scheduler, n]
            _rows(section, t, r_table, per_round, scheduler, n, r, rounds_of[scheduler])
            pooled += r["rounds"]
        if len({n for s, n in results if s == scheduler}) > 1:
            value, pbo_k, bare_k, interval = _overrun_ratio(pooled)
            r_table.add(label, "all", "", "", _overrun_cell(value, pbo_k, bare_k, interval), "", "")
            section.notes.append(f"{label}, every RTPU count pooled: {pbo_k} overruns of the executive against {bare_k} "
                                 f"of the bare loop, rate ratio {fmt_ratio(value)} {interval}.")
    for n in rtpus:
        fifo, other = results.get(("fifo", n)), results.get(("other", n))
        if fifo and other and _scheduler_granted(fifo) == "SCHED_FIFO" and other["pbo"]["overrun_rate"] > 0:
            section.notes.append(
                f"{n} RTPU{'s' if n > 1 else ''}: the executive's overrun rate under SCHED_FIFO was "
                f"{fifo['pbo']['overrun_rate'] / other['pbo']['overrun_rate']:.2f} of its rate under SCHED_OTHER "
                f"({fifo['pbo']['overrun_rate'] * 100:.4f}% against {other['pbo']['overrun_rate'] * 100:.4f}%).")
    section.tables += [t, r_table, per_round]


def _rows(section: Section, t: Table, r_table: Table, per_round: Table, scheduler: str, n: int, r: dict[str, Any],
          rounds: int) -> None:
    """One comparison's rows; targets if it ran under the default scheduler, notes otherwise."""
    label = SCHEDULER_LABELS[scheduler]
    plural = "s" if n > 1 else ""
    late, steps = r["plant_late"]
    for side in ("pbo", "bare"):
        s = r[side]
        t.add(label, n, "pbo executive" if side == "pbo" else "bare hybrid wait", f"{s['cycles']:,}", us(s["p50"]),
              us(s["p99"]), us(s["max"]), s["overruns"], f"{s['overrun_rate'] * 100:.3f}%", s["missed"],
              f"{late} of {steps:,}" if side == "pbo" else "(the same plant)")
    by_round: dict[str, list[float]] = {}
    cells = []
    for q in ("p50", "p99"):
        values = [ratio(p[q], b[q]) for p, b in r["rounds"]]
        by_round[q] = [v for v in values if v is not None]
        cells.append(" ".join(fmt_ratio(v) for v in values))
    cells.append(" ".join(f"{p['overruns']}:{b['overruns']}" for p, b in r["rounds"]))
    per_round.add(label, n, *cells)
    medians = {q: float(np.median(v)) if v else None for q, v in by_round.items()}
    overrun_ratio, pbo_k, bare_k, interval = _overrun_ratio(r["rounds"])
    for q, value in (*medians.items(), ("overrun_rate", overrun_ratio)):
        if value is not None:
            section.ratios[f"{n} rtpus {q} pbo / bare ({label})"] = value
    differences = {q: float(np.median([p[q] - b[q] for p, b in r["rounds"]])) * 1e6 for q in ("p50", "p99")}
    r_table.add(label, n, *(f"{fmt_ratio(medians[q])} [{_spread(by_round[q])}]" for q in ("p50", "p99")),
                _overrun_cell(overrun_ratio, pbo_k, bare_k, interval), f"{differences['p50']:+.2f}",
                f"{differences['p99']:+,.1f}")
    granted = _scheduler_granted(r)
    if scheduler == "fifo":
        what = f"{n} RTPU{plural}, {granted}"
        for q, name in (("p50", "jitter p50"), ("p99", "jitter p99")):
            section.targets.append(Target(f"{what}: {name}, pbo / bare (median of {rounds} rounds)", medians[q], 1.5,
                                          note=f"rounds {_spread(by_round[q])}"))
        if pbo_k == 0 and bare_k == 0:
            section.notes.append(f"{what}: no overrun on either side.")
        else:
            note = f"{pbo_k} and {bare_k} overruns; {CONFIDENCE:.0%} interval {interval}"
            if overrun_ratio is None:
                note = f"the bare loop had no overrun, the executive {pbo_k}; {CONFIDENCE:.0%} interval {interval}"
            section.targets.append(Target(f"{what}: overrun rate, pbo / bare (pooled)", overrun_ratio, 1.5, note=note))
        if granted != "SCHED_FIFO":
            section.notes.append(f"{n} RTPU{plural}: the OS refused SCHED_FIFO, so the default ran SCHED_OTHER on both sides.")
    else:
        section.notes.append(
            f"{n} RTPU{plural}, SCHED_OTHER (reported, not judged): jitter p50 {fmt_ratio(medians['p50'])}, p99 "
            f"{fmt_ratio(medians['p99'])}, overrun rate {fmt_ratio(overrun_ratio)} ({pbo_k} and {bare_k} overruns; "
            f"{CONFIDENCE:.0%} interval {interval}), pbo / bare.")
    section.notes.append(f"{label}, {n} RTPU{plural}: the executive's cycle (pick, copy-in, cycle, copy-out) took "
                         f"{us(r['exec_p50'])} µs at the median.")
    if r["realtime"]:
        settings = sorted({", ".join(f"{k} {v}" for k, v in s.items()) for s in r["realtime"].values()})
        section.notes.append(f"{label}, {n} RTPU{plural}: the RTPUs reported: {'; '.join(settings)}.")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=240.0,
                        help="seconds of pbo run per RTPU count under the default scheduler "
                             "(the bare loops run at the same time)")
    parser.add_argument("--rtpus", type=int, nargs="+", default=[1, 2, 4], choices=[1, 2, 4])
    parser.add_argument("--rounds", type=int, default=48,
                        help="paired rounds (a pbo run with the bare loops beside it); the duration is split over them")
    parser.add_argument("--other-duration", type=float, default=60.0,
                        help="seconds per RTPU count under SCHED_OTHER (--no-fifo), reported beside; 0 leaves it out")
    parser.add_argument("--other-rounds", type=int, default=12, help="rounds under SCHED_OTHER")
    args = parser.parse_args()
    print(run(args.duration, tuple(args.rtpus), args.rounds, args.other_duration, args.other_rounds).text())


if __name__ == "__main__":
    main()
