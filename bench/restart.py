"""A dead RTPU restarted alone: from the kill to its tasks ON again, and what the arm did meanwhile.

The PID demo (`configs/pid_joint.yaml`) with a restart policy and its logger beside the robot
interface; once it is on, the controller's RTPU (trajectory generator, PID) is killed with
SIGKILL, again and again, each kill once the tasks of the last restart are ON again. Per kill,
from the run's report: each phase of the restart (noticed, launch, ready, spawn, on); *ON again*,
from the kill to every task that was ON being ON again; the robot interface's *stable cycles*,
the cycles it ran its locally stable behaviour (the arm held) over that restart. Three runs: the
restarts forked from the kept fork server, the same from fresh interpreters (PBO_FORK_SERVER=0,
how restarts were made before), and the subsystem on as long without a kill: the robot's missed
releases there are the machine's. Each run's cold start is its same-run baseline.

    python -m bench.restart [--kills 20]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from bench._common import REPO, Section, Table, fmt_ratio, percentiles, ratio
from bench._inject import table_of
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.ipc import shm
from pbo_runtime.table.table import StateTable, TableLayout
from pbo_runtime.table.table import StatusWord as W

DEMO = Path(REPO) / "configs" / "pid_joint.yaml"
SUBSYSTEM = "puma_restart"
ROBOT_PERIOD = 0.001  # s, the robot interface's, as in the demo
SAFETY_NET = 120.0  # s a run may take to say what the benchmark waits for: a net for a hang
SETTLE = 0.1  # s after its tasks are ON again that still count as the restart's (its first cycles at SCHED_FIFO)


def bench_config(folder: Path, kills: int) -> Path:
    """The demo under its own name, restarting rtpu0 at every kill, its logger on the robot's RTPU."""
    config = yaml.safe_load(DEMO.read_text())
    config["subsystem"] = SUBSYSTEM
    config["restart"] = {"max": kills + 1, "within": "1 h"}
    config["tasks"]["logger"].update({"rtpu": "rtpu1", "params": {"variables": ["q_m"], "path": "arm.npy"}})
    path = folder / "restart.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def said_until(process: subprocess.Popen, text: str) -> None:
    """Read the run's output until a line holds `text` (RuntimeError if it ends first)."""
    assert process.stdout is not None
    give_up = time.monotonic() + SAFETY_NET
    for line in process.stdout:
        if text in line:
            return
        if time.monotonic() > give_up:
            break
    raise RuntimeError(f"the run did not say '{text}' (exit {process.poll()})")


def rtpu0(process: subprocess.Popen) -> int:
    for _ in range(200):
        found = [pid for pid, command in shm.children_of(process.pid).items() if "--rtpu rtpu0" in command]
        if found:
            return found[0]
        time.sleep(0.01)
    raise RuntimeError("no rtpu0 among the run's children")


def start_run(config: Path, folder: Path, report: Path, duration: float, fresh: bool) -> subprocess.Popen:
    """`pbo run` of the bench's subsystem; `fresh`: every child (a restarted one too) a fresh interpreter."""
    environment = {**os.environ, **({"PBO_FORK_SERVER": "0"} if fresh else {})}
    return subprocess.Popen([sys.executable, "-m", "pbo_runtime.cli", "run", str(config), "--duration", repr(duration),
                             "--no-live", "--out", str(folder / "out"), "--report", str(report)],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environment)


def finish(process: subprocess.Popen, report_path: Path, stop: bool) -> dict:
    """Stop the run (SIGINT) if `stop`, else wait for its duration to end; its report."""
    try:
        if stop:
            process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=SAFETY_NET)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    if not report_path.exists():
        raise RuntimeError(f"no report (exit {process.returncode}): {stderr.strip()[-300:]}")
    return json.loads(report_path.read_text())


def robot_figures(report: dict) -> dict:
    robot = report["tasks"].get("robot", {})
    return {"missed": robot.get("missed", 0), "overruns": robot.get("overruns", 0), "cycles": robot.get("cycles", 0),
            "failure": report["failure"], "running": report.get("running_wall_seconds", 0.0),
            "lock_recoveries": report.get("lock_recoveries", 0), "lock_waits_given_up": robot.get("lock_waits_given_up", 0)}


class RobotCounts:
    """The robot interface's cycle and missed-release counts, read from the run's table as it runs."""

    def __init__(self, config: Path, supervisor: int) -> None:
        subsystem = load_subsystem(config)
        self.table = StateTable.attach(TableLayout.of(subsystem), table_of(SUBSYSTEM, supervisor))
        self.index = subsystem.tasks["robot"].index

    def now(self) -> np.ndarray:
        words = self.table.status[self.index]
        return np.array([words[W.CYCLES], words[W.MISSED]], dtype=float)


def measure(kills: int, fresh: bool = False, quiet_windows: bool = False) -> dict:
    """One run with `kills` kills of rtpu0: per kill, its phases (seconds from the kill); the robot's figures.
    `quiet_windows`: before each kill, as long without one as the last restart took (its SETTLE included):
    the robot's cycles and misses in the restarts' windows and in those, from its counts in the table."""
    windows = {"restart": np.zeros(3), "quiet": np.zeros(3)}  # cycles, missed, seconds
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        report_path = folder / "report.json"
        started = time.monotonic()
        config = bench_config(folder, kills)
        process = start_run(config, folder, report_path, 0, fresh)
        killed_at = []
        counts = None
        try:
            said_until(process, "is on")
            cold_start = time.monotonic() - started
            counts = RobotCounts(config, process.pid) if quiet_windows else None
            last = 0.2
            for _ in range(kills):
                pid = rtpu0(process)
                if counts is not None:
                    begin, at = counts.now(), time.monotonic()
                    time.sleep(last)
                    windows["quiet"] += [*(counts.now() - begin), time.monotonic() - at]
                    begin = counts.now()
                killed_at.append(time.monotonic())
                os.kill(pid, signal.SIGKILL)
                said_until(process, "restarted:")
                if counts is not None:
                    time.sleep(SETTLE)
                    last = time.monotonic() - killed_at[-1]
                    windows["restart"] += [*(counts.now() - begin), last]
        finally:
            if counts is not None:
                counts.table.close()
            report = finish(process, report_path, stop=True)
    origin = report["started_monotonic"]
    phases: dict[str, list[float]] = {phase: [] for phase in PHASES}
    stable = []
    for kill, restart in zip(killed_at, report["restarts"], strict=True):
        marks = [kill] + [origin + restart[key] for key in ("died_at", "launched_at", "ready_at", "spawned_at", "on_again_at")]
        for phase, (begin, end) in zip(PHASES, itertools.pairwise(marks), strict=True):
            phases[phase].append(end - begin)
        held = [e for e in report["stable_episodes"]
                if e["task"] == "robot" and kill <= e["from"] <= marks[-1] and e["to"] is not None]
        stable.append(sum(e["to"] - e["from"] for e in held) / ROBOT_PERIOD)
    back = [restart["on_again_at"] + origin - kill for kill, restart in zip(killed_at, report["restarts"], strict=True)]
    return {"cold_start": cold_start, "phases": phases, "back": back, "stable": stable, "windows": windows,
            "restarts": len(report["restarts"]), **robot_figures(report)}


def measure_without_kills(seconds: float) -> dict:
    """The same subsystem on for `seconds` without a kill: the robot's figures (the machine's own misses)."""
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        report_path = folder / "report.json"
        process = start_run(bench_config(folder, 0), folder, report_path, max(seconds, 0.5), fresh=False)
        return robot_figures(finish(process, report_path, stop=False))


# a restart's phases, each from the end of the one before (the first from the kill)
PHASES = {"noticed": "the supervisor handles the death (its pidfd watch wakes it)",
          "launch": "the new process started: forked from the kept fork server, or a fresh interpreter",
          "ready": "the new RTPU opens the table, its queues and its clock and says it is ready",
          "spawn": "its tasks spawned one by one, each init done (const order)",
          "on": "its tasks turned on, each at its next cycle boundary"}


def per_10k(figures: dict) -> str:
    """The robot's missed releases per 10,000 cycles (runs of different lengths compared)."""
    return f"{figures['missed'] / figures['cycles'] * 1e4:.1f}" if figures["cycles"] else ""


def run(kills: int = 20) -> Section:
    section = Section(
        key="restart",
        title=f"A dead RTPU restarted alone: {kills} kills of the controller's RTPU",
        command=f"python -m bench.restart --kills {kills}",
        method="""
The PID demo on the real clock with `restart: {max, within}` and its logger on the robot's RTPU.
Once it is on, the controller's RTPU (trajectory generator and PID) is SIGKILLed, and again each
time its tasks are ON again. *ON again*: from the kill to every task that was ON being ON again.
Three runs, one after the other: the restarts as `pbo run` makes them (the new RTPU forked from
the fork server the run keeps while an RTPU has a restart policy); the same kills with
`PBO_FORK_SERVER=0` (every process, a restarted one too, a fresh interpreter: how restarts were
made before); and the subsystem on for as long as the first run's kills took, without a kill:
the robot interface's missed releases there are the machine's, not the restarts'. Each run's
cold start (`pbo run` to its configuration on) is its same-run baseline. A restart's phases,
from the run's report: *noticed* (the kill to the supervisor handling the death), *launch* (the
new process started), *ready* (it opened the table and its queues), *spawn* (its tasks' inits),
*on* (its tasks ON, each at a cycle boundary). *Stable cycles*: the robot interface's cycles in
its locally stable behaviour (the arm held) over a restart. The goal, no release of the robot
interface missed, is judged in the restarts' windows (each kill to its tasks ON again + 100 ms),
from its counts in the table as the run goes; before each kill as long a window without one says
what the machine alone costs. A kill that lands while the controller's RTPU holds the table lock
is counted: the robot's RTPU then gives up its wait for the lock (an eighth of its period) and
runs the stable cycle until job control releases the lock.
""",
        limits="""A fresh interpreter imports numpy, MuJoCo's and Pinocchio's bindings and the
module library before its tasks can be spawned (most of a restart when forking is off); forked,
what is left is the tasks' inits and the new process touching the pages it shares with the fork
server. The robot interface holds the arm from its input's freshness bound (2 ms) until the new
PID writes again. Missed releases on a shared 2-CPU machine come from the machine too: the run
without kills says how many.""",
    )
    forked = measure(kills, quiet_windows=True)
    fresh = measure(kills, fresh=True)
    quiet = measure_without_kills(forked["running"])
    table = Table(["restart from", "kills", "ON again p50 ms", "ON again max ms", "stable cycles p50", "stable cycles max",
                   "cold start ms", "robot cycles", "robot missed", "missed per 10k", "robot overruns"],
                  numeric=tuple(range(1, 11)))
    for label, figures in (("kept fork server", forked), ("fresh interpreter", fresh)):
        back, stable = np.array(figures["back"]) * 1e3, np.array(figures["stable"])
        table.add(label, len(back), f"{percentiles(back)[0]:.0f}", f"{back.max():.0f}", f"{percentiles(stable)[0]:.0f}",
                  f"{stable.max():.0f}", f"{figures['cold_start'] * 1e3:.0f}", figures["cycles"], figures["missed"],
                  per_10k(figures), figures["overruns"])
    table.add("no kill (same time on)", 0, "", "", "", "", "", quiet["cycles"], quiet["missed"],
              per_10k(quiet), quiet["overruns"])
    section.tables.append(table)
    steps = Table(["phase", "p50 ms", "max ms", "fresh p50 ms", "fresh max ms", "what"], numeric=(1, 2, 3, 4),
                  caption="Where a restart's time goes, per phase (each from the end of the one before):")
    for phase, what in PHASES.items():
        ours, theirs = np.array(forked["phases"][phase]) * 1e3, np.array(fresh["phases"][phase]) * 1e3
        steps.add(phase, f"{percentiles(ours)[0]:.1f}", f"{ours.max():.1f}", f"{percentiles(theirs)[0]:.1f}",
                  f"{theirs.max():.1f}", what)
    section.tables.append(steps)
    b50 = percentiles(np.array(forked["back"]))[0]
    f50 = percentiles(np.array(fresh["back"]))[0]
    share = ratio(b50, forked["cold_start"])
    section.ratios["restart / cold start"] = share or float("nan")
    section.ratios["forked restart / fresh restart"] = ratio(b50, f50) or float("nan")
    section.notes.append(f"{forked['restarts']} of {kills} kills restarted; kill to tasks ON again, p50 {b50 * 1e3:.0f} ms, "
                         f"max {max(forked['back']) * 1e3:.0f} ms: {fmt_ratio(share)} of the same run's cold start "
                         f"({forked['cold_start'] * 1e3:.0f} ms); from a fresh interpreter p50 {f50 * 1e3:.0f} ms, "
                         f"max {max(fresh['back']) * 1e3:.0f} ms ({fmt_ratio(ratio(b50, f50))})")
    (r_cycles, r_missed, r_seconds), (q_cycles, q_missed, q_seconds) = forked["windows"]["restart"], forked["windows"]["quiet"]
    section.notes.append(f"robot interface: {r_missed:.0f} releases missed in the {kills} restarts' windows (goal 0) -> "
                         f"{'met' if r_missed == 0 else 'NOT met'} ({r_cycles:,.0f} releases: from each kill to its tasks "
                         f"ON again + {SETTLE * 1e3:.0f} ms, {r_seconds:.1f} s in all); {q_missed:.0f} of {q_cycles:,.0f} "
                         f"in as long without a kill before each ({q_seconds:.1f} s)")
    section.notes.append(f"robot interface over the whole runs, their starts included: {forked['missed']} missed "
                         f"({forked['cycles']:,} cycles, {forked['overruns']} overruns); without kills, "
                         f"{quiet['running']:.1f} s on: {quiet['missed']} missed ({quiet['cycles']:,} cycles, "
                         f"{quiet['overruns']} overruns); fresh-interpreter restarts: {fresh['missed']} missed "
                         f"({fresh['cycles']:,} cycles)")
    section.notes.append(f"a killed RTPU held the table lock {forked['lock_recoveries']} + {fresh['lock_recoveries']} times "
                         f"(released by job control); the robot's RTPU gave up its wait for it in "
                         f"{forked['lock_waits_given_up']} + {fresh['lock_waits_given_up']} cycles "
                         "(its stable behaviour ran instead)")
    for label, figures in (("kept fork server", forked), ("fresh interpreter", fresh), ("no kill", quiet)):
        if figures["failure"]:
            section.notes.append(f"the run ({label}) failed: {figures['failure']}")
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kills", type=int, default=20)
    args = parser.parse_args()
    print(run(args.kills).text())


if __name__ == "__main__":
    main()
