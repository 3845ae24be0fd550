"""How fast the simulated clock runs Figure 8: simulated time / wall time, against real time (1x).

    pbo run configs/pid_joint.yaml --clock sim --duration D --out DIR

Figure 8 (`configs/pid_joint.yaml`: the arm's plant, two RTPUs, four tasks at 1 to 10 ms, a data
logger) on `--clock sim`, under a subsystem name of its own, `rounds` times. Each run's report
gives the simulated duration and two wall times: from the configuration on to the stop (the
ticks), and the whole run (start-up and stop included). The baseline is real time: a run on
`--clock real` takes its duration in wall time, 1x. The runs' logs must be byte-identical (the
replay promise): the benchmark says whether they were.

    python -m bench.sim_speed [--seconds 10] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench._common import REPO, Section, Table, Target, fmt_ratio

CONFIG = "configs/pid_joint.yaml"
SUBSYSTEM = "bench_sim_speed"  # its own name: a run of Figure 8 elsewhere on the machine does not refuse this one
GOAL = 10.0
ONE_PROCESS_GOAL = 20.0  # --one-process, whole process (start-up included), over ONE_PROCESS_SECONDS
ONE_PROCESS_SECONDS = 60.0
ONE_PROCESS_RUNS = 3  # the goal's runs: the median is judged (a whole process on a shared machine, as the start-up figures)


def children_cpu() -> float:
    """CPU seconds of every process this one waited for, theirs included (`pbo run` waits for its plant and RTPUs)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def environment(folder: Path) -> dict[str, str]:
    """Bytecode cached under `folder` (the first run writes it), as a user's install has it, even where
    PYTHONDONTWRITEBYTECODE is set: every run, and its start-up, then imports what a user's would."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    return {**env, "PYTHONPYCACHEPREFIX": str(folder / "pycache")}


def run_once(seconds: float, folder: Path, index: int, one_process: bool = False) -> dict[str, Any]:
    """One simulated run of Figure 8: its durations, the CPU time of its processes, and its log's bytes;
    `one_process`: the plant and the RTPUs in the supervisor's process (`--one-process`)."""
    text = (Path(REPO) / CONFIG).read_text().replace("\nsubsystem: puma\n", f"\nsubsystem: {SUBSYSTEM}\n")
    config = folder / "pid_joint.yaml"
    config.write_text(text)
    out = folder / f"run{index}"
    command = [sys.executable, "-m", "pbo_runtime.cli", "run", str(config), "--clock", "sim", "--duration", f"{seconds:g}",
               "--no-live", "--out", str(out), *(["--one-process"] if one_process else [])]
    cpu = children_cpu()
    started = time.monotonic()
    done = subprocess.run(command, cwd=folder, env=environment(folder), capture_output=True, text=True,
                          timeout=seconds * 50 + 300)
    process_wall = time.monotonic() - started
    cpu = children_cpu() - cpu
    report_path = out / "report.json"
    if done.returncode != 0 or not report_path.exists():
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:]
        raise RuntimeError(f"`pbo run` failed (exit {done.returncode}): {' / '.join(tail)}")
    report = json.loads(report_path.read_text())
    log = out / "pid_joint.mcap"
    return {"duration": report["duration"], "wall": report["wall_seconds"], "running": report["running_wall_seconds"],
            "steps": report["plant"].get("steps", 0), "cpu": cpu, "log": log.read_bytes() if log.exists() else b"",
            "process": process_wall}


def run(seconds: float = 10.0, rounds: int = 3, goal_seconds: float = ONE_PROCESS_SECONDS,
        goal_runs: int = ONE_PROCESS_RUNS) -> Section:
    section = Section(
        key="sim_speed",
        title="The simulated clock on Figure 8: simulated time / wall time",
        command=f"python -m bench.sim_speed --seconds {seconds:g} --rounds {rounds} --goal-seconds {goal_seconds:g} "
                f"--goal-runs {goal_runs}",
        method=f"""
`pbo run {CONFIG} --clock sim --duration {seconds:g}` (the arm's plant, two RTPUs, four tasks at
1 to 10 ms, a data logger), {rounds} runs back to back. Each tick the plant steps once, then
rtpu0 and rtpu1 run their released tasks, one process after the other; the participants hand
the turn to each other and begin the next tick themselves, and job control takes part only
after a tick that sent it an event, or when the time it asked for is run. The figure is the
simulated duration over the wall time from the configuration on to the stop (the ticks), median
over the runs; the whole run's (start-up of the plant and RTPU processes and stop included) is
shown beside it, and the CPU time the ticks took (every process of the run, a run of one tick's
subtracted), which on a busy machine says what the wall time cannot. The baseline is real time,
1x. Before this benchmark existed (job control releasing each participant in turn and taking
its turn back, every tick), the run summary read 3.4x for 10 s on a quiet machine, start-up
included.

Each run is followed by the same run with `--one-process` (the plant and both RTPUs in the
supervisor's process, given their turns by calls in the same order): the ratio of the two wall
times, measured as whole processes from outside, and whether their logs are byte-identical. Then
{goal_runs} runs of Figure 8 with `--one-process` over {goal_seconds:g} simulated seconds, the
median judged against its goal: simulated time over the whole process's wall time, start-up
included. Every run
imports bytecode cached by the first (the run of one tick), as a user's install has it.
""",
        limits="""One tick is three processes run one after the other: the plant's MuJoCo step and
its I/O boards, rtpu0's trajectory, PID (with Pinocchio's gravity) and logger, rtpu1's robot
interface, each in Python, plus three hand-overs between processes (a semaphore post and a
wake-up). On a 2-CPU machine shared with other work every hand-over also waits for the CPU.
In one process the hand-overs are calls. A tick is then, by cost: the tasks' cycles (numpy calls
on six-element arrays, each costing more than its arithmetic even as the cheapest call numpy
has, a ufunc named once with its output positional and arrays for operands, and Pinocchio's
gravity); the executive's work per release (the transfers through the table under its lock, the
finite check, the timing record, a critical task's freshness check); the plant's step, MuJoCo's
step and the Python around it (the command's read and clip, the state's publication). The I/O
boards' conversions are served only when the subsystem declares a board (Figure 8 declares
none), and whether a signal waits for an RTPU is a count its queue's ends share in the one
process, not a system call. Time stands still within a turn, so the executive reads the clock
once a turn, not after every cycle; job control runs the ticks in stretches of 100 simulated ms
(the table lock's looks do not cut them shorter: the participants take the lock only within their
turns); the data logger fills up to 32 chunk buffers ahead of its MCAP encoder, whose process's
start the ticks would otherwise wait for. The start-up (interpreter, imports, MuJoCo's model) is then a larger
share of a short run.""",
    )
    results: list[dict[str, Any]] = []
    failures: list[str] = []
    fixed: dict[str, Any] | None = None  # a run of one tick: the CPU time of starting and stopping
    in_one: list[dict[str, Any]] = []  # the same runs with --one-process, each right after its run of processes
    long_runs: list[dict[str, Any]] = []  # --one-process over ONE_PROCESS_SECONDS: the goal's runs
    fixed_one: dict[str, Any] | None = None  # a run of one tick in one process: its start-up and stop
    with tempfile.TemporaryDirectory() as folder:
        try:
            fixed = run_once(0.001, Path(folder), rounds)
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            failures.append(f"the run of one tick: {exc}")
        for index in range(rounds):
            try:
                results.append(run_once(seconds, Path(folder), index))
            except (RuntimeError, subprocess.TimeoutExpired) as exc:
                failures.append(f"run {index + 1}: {exc}")
            try:
                in_one.append(run_once(seconds, Path(folder), rounds + 1 + index, one_process=True))
            except (RuntimeError, subprocess.TimeoutExpired) as exc:
                failures.append(f"run {index + 1} in one process: {exc}")
        try:
            fixed_one = run_once(0.001, Path(folder), 2 * rounds + 2, one_process=True)
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            failures.append(f"the run of one tick in one process: {exc}")
        for index in range(goal_runs):
            try:
                long_runs.append(run_once(goal_seconds, Path(folder), 2 * rounds + 3 + index, one_process=True))
            except (RuntimeError, subprocess.TimeoutExpired) as exc:
                failures.append(f"run {index + 1} of {goal_seconds:g} s in one process: {exc}")
    table = Table(["run", "simulated, s", "plant steps", "wall from configuration on, s", "speed", "whole run, s",
                   "speed (whole run)"], numeric=(1, 2, 3, 4, 5, 6),
                  caption=f"Figure 8 on the simulated clock, {len(results)} runs of {seconds:g} simulated seconds:")
    for index, r in enumerate(results):
        table.add(index + 1, f"{r['duration']:.2f}", r["steps"], f"{r['running']:.2f}", fmt_ratio(r["duration"] / r["running"]),
                  f"{r['wall']:.2f}", fmt_ratio(r["duration"] / r["wall"]))
    if results:
        section.tables.append(table)
    speed = statistics.median(r["duration"] / r["running"] for r in results) if results else None
    whole = statistics.median(r["duration"] / r["wall"] for r in results) if results else None
    if speed is not None and whole is not None:
        section.ratios.update({"sim/wall from configuration on": speed, "sim/wall whole run": whole})
        per_tick = statistics.median(r["running"] / max(r["steps"], 1) for r in results)
        section.notes.append(f"one tick took {per_tick * 1e6:,.0f} µs of wall time (median over the runs)")
        if fixed is not None:
            # The processes run one at a time: on a machine with a CPU free for them the ticks would
            # take about their CPU time, start-up and stop (a run of one tick) taken out.
            cpu_per_second = statistics.median((r["cpu"] - fixed["cpu"]) / r["duration"] for r in results)
            if cpu_per_second > 0:
                section.ratios["sim/cpu of the ticks"] = 1.0 / cpu_per_second
                section.notes.append(f"the ticks took {cpu_per_second:.2f} s of CPU time (supervisor, plant and RTPUs "
                                     f"together) per simulated second, start-up and stop (a run of one tick: "
                                     f"{fixed['cpu']:.1f} s) taken out: {fmt_ratio(1.0 / cpu_per_second)} real time on "
                                     "a machine with a CPU free for them")
    if len(results) > 1:
        identical = all(r["log"] == results[0]["log"] for r in results[1:])
        section.notes.append(f"the {len(results)} runs' logs are {'byte-identical' if identical else 'NOT identical'}")
    _one_process_figures(section, results, in_one, long_runs, fixed_one, goal_seconds)
    for failure in failures:
        section.notes.append(f"failed: {failure}")
    section.targets.append(Target("Figure 8 on the simulated clock: simulated time / wall time (baseline: real time, 1x)",
                                  speed, GOAL, at_least=True,
                                  note=f"whole run, start-up included: {fmt_ratio(whole)}" if whole is not None else ""))
    return section


def _one_process_figures(section: Section, results: list[dict[str, Any]], in_one: list[dict[str, Any]],
                         long_runs: list[dict[str, Any]], fixed_one: dict[str, Any] | None, goal_seconds: float) -> None:
    """`--one-process` beside the runs of processes: its speed, the ratio between the two, the same log, the goal."""
    if in_one:
        table = Table(["run", "mode", "simulated, s", "wall from configuration on, s", "whole process, s",
                       "speed (whole process)"], numeric=(2, 3, 4, 5),
                      caption="The same runs with processes and in one process (`--one-process`), whole process "
                              "measured from outside (start-up included):")
        for index, (processes, one) in enumerate(zip(results, in_one, strict=True)):
            for mode, r in (("processes", processes), ("one process", one)):
                table.add(index + 1, mode, f"{r['duration']:.2f}", f"{r['running']:.2f}", f"{r['process']:.2f}",
                          fmt_ratio(r["duration"] / r["process"]))
        for index, r in enumerate(long_runs):
            table.add(f"goal {index + 1}", "one process", f"{r['duration']:.2f}", f"{r['running']:.2f}",
                      f"{r['process']:.2f}", fmt_ratio(r["duration"] / r["process"]))
        section.tables.append(table)
        pairs = list(zip(results, in_one, strict=True))
        if pairs:
            section.ratios["one process / processes, whole process"] = statistics.median(
                p["process"] / o["process"] for p, o in pairs)
            section.ratios["one process / processes, from configuration on"] = statistics.median(
                p["running"] / o["running"] for p, o in pairs)
            same = all(p["log"] == o["log"] for p, o in pairs)
            section.notes.append(f"in one process, the logs are {'byte-identical' if same else 'NOT identical'} to the "
                                 "runs of processes'")
            section.notes.append("one process / processes, wall time of the whole process: "
                                 f"{fmt_ratio(section.ratios['one process / processes, whole process'])} faster "
                                 "(from the configuration on: "
                                 f"{fmt_ratio(section.ratios['one process / processes, from configuration on'])})")
        per_tick = statistics.median(o["running"] / max(o["steps"], 1) for o in in_one)
        section.notes.append(f"in one process, one tick took {per_tick * 1e6:,.0f} µs of wall time (median)")
    long_one = sorted(long_runs, key=lambda r: r["duration"] / r["process"])[len(long_runs) // 2] if long_runs else None
    if long_one is not None and fixed_one is not None:
        ticks_cpu = (long_one["cpu"] - fixed_one["cpu"]) / long_one["duration"]
        if ticks_cpu > 0:
            section.ratios["one process: sim/cpu of the ticks"] = 1.0 / ticks_cpu
            section.notes.append(
                f"in one process, over {long_one['duration']:g} s (the median run): the ticks took {ticks_cpu:.2f} s of "
                f"CPU time per simulated second ({ticks_cpu * 1e3:,.0f} µs a tick), start-up and stop "
                f"({fixed_one['cpu']:.1f} s of CPU, a run of one tick) taken out; on a machine with a CPU free for it "
                "the whole process would take about "
                f"{fixed_one['cpu'] + ticks_cpu * long_one['duration']:.1f} s: "
                f"{fmt_ratio(long_one['duration'] / (fixed_one['cpu'] + ticks_cpu * long_one['duration']))} real time")
    speed = long_one["duration"] / long_one["process"] if long_one is not None else None
    section.targets.append(Target(f"Figure 8 with --one-process: {goal_seconds:g} simulated s / wall time of the "
                                  f"whole process, start-up included, median of {len(long_runs)} runs (baseline: real "
                                  "time, 1x)", speed, ONE_PROCESS_GOAL,
                                  at_least=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--goal-seconds", type=float, default=ONE_PROCESS_SECONDS,
                        help="simulated seconds of the --one-process runs judged against their goal")
    parser.add_argument("--goal-runs", type=int, default=ONE_PROCESS_RUNS, help="how many such runs (their median is judged)")
    args = parser.parse_args()
    print(run(args.seconds, args.rounds, args.goal_seconds, args.goal_runs).text())


if __name__ == "__main__":
    main()
