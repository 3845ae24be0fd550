"""A dead RTPU restarted alone: from the kill to its tasks ON again, and what the arm did meanwhile.

The PID demo (`configs/pid_joint.yaml`) with a restart policy and its logger beside the robot
interface; once it is on, the controller's RTPU (trajectory generator, PID) is killed with
SIGKILL, again and again, each kill once the tasks of the last restart are ON again. Per kill,
from the run's report: *noticed*, from the kill to the supervisor handling the death; *ON again*,
from the kill to every task that was ON being ON again; the robot interface's *stable cycles*,
the cycles it ran its locally stable behaviour (the arm held) over that restart. The baseline,
in the same run: the subsystem's own cold start, from `pbo run` to its configuration on.

    python -m bench.restart [--kills 20]
"""

from __future__ import annotations

import argparse
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
from pbo_runtime.ipc import shm

DEMO = Path(REPO) / "configs" / "pid_joint.yaml"
SUBSYSTEM = "puma_restart"
ROBOT_PERIOD = 0.001  # s, the robot interface's, as in the demo
SAFETY_NET = 120.0  # s a run may take to say what the benchmark waits for: a net for a hang


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


def measure(kills: int) -> dict:
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        report_path = folder / "report.json"
        started = time.monotonic()
        process = subprocess.Popen([sys.executable, "-m", "pbo_runtime.cli", "run", str(bench_config(folder, kills)),
                                    "--duration", "0", "--no-live", "--out", str(folder / "out"), "--report", str(report_path)],
                                   cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            said_until(process, "is on")
            cold_start = time.monotonic() - started
            killed_at = []
            for _ in range(kills):
                pid = rtpu0(process)
                killed_at.append(time.monotonic())
                os.kill(pid, signal.SIGKILL)
                said_until(process, "restarted:")
            process.send_signal(signal.SIGINT)
            _, stderr = process.communicate(timeout=SAFETY_NET)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        if not report_path.exists():
            raise RuntimeError(f"no report (exit {process.returncode}): {stderr.strip()[-300:]}")
        report = json.loads(report_path.read_text())
    origin = report["started_monotonic"]
    noticed, back, stable = [], [], []
    for kill, restart in zip(killed_at, report["restarts"]):
        noticed.append(origin + restart["died_at"] - kill)
        back.append(origin + restart["on_again_at"] - kill)
        end = origin + restart["on_again_at"]
        held = [e for e in report["stable_episodes"]
                if e["task"] == "robot" and kill <= e["from"] <= end and e["to"] is not None]
        stable.append(sum(e["to"] - e["from"] for e in held) / ROBOT_PERIOD)
    robot = report["tasks"].get("robot", {})
    return {"cold_start": cold_start, "noticed": noticed, "back": back, "stable": stable,
            "restarts": len(report["restarts"]), "missed": robot.get("missed", 0), "overruns": robot.get("overruns", 0),
            "cycles": robot.get("cycles", 0), "failure": report["failure"]}


def run(kills: int = 20) -> Section:
    section = Section(
        key="restart",
        title=f"A dead RTPU restarted alone: {kills} kills of the controller's RTPU",
        command=f"python -m bench.restart --kills {kills}",
        method="""
The PID demo on the real clock with `restart: {max, within}` and its logger on the robot's RTPU.
Once it is on, the controller's RTPU (trajectory generator and PID) is SIGKILLed, and again each
time its tasks are ON again. *Noticed*: from the kill to the supervisor handling the death (its
pidfd watch wakes it). *ON again*: from the kill to every task that was ON being ON again: a new
RTPU process started, its tasks spawned and turned on. *Stable cycles*: the robot interface's
cycles in its locally stable behaviour (the arm held) over that restart. The baseline is the same
run's cold start: `pbo run` to its configuration on (every process started, every task spawned).
""",
        limits="""Most of a restart is a new Python process importing numpy, MuJoCo's and
Pinocchio's bindings and the module library before its tasks can be spawned; the robot interface
holds the arm from its input's freshness bound (2 ms) until the new PID writes again.""",
    )
    figures = measure(kills)
    noticed, back, stable = (np.array(figures[k]) * scale for k, scale in (("noticed", 1e3), ("back", 1e3), ("stable", 1)))
    table = Table(["kills", "noticed p50 ms", "noticed max ms", "ON again p50 ms", "ON again max ms",
                   "stable cycles p50", "stable cycles max", "cold start ms", "robot cycles", "robot missed"],
                  numeric=tuple(range(10)))
    n50, _ = percentiles(noticed)
    b50, _ = percentiles(back)
    s50, _ = percentiles(stable)
    table.add(len(back), f"{n50:.1f}", f"{noticed.max():.1f}", f"{b50:.0f}", f"{back.max():.0f}", f"{s50:.0f}",
              f"{stable.max():.0f}", f"{figures['cold_start'] * 1e3:.0f}", figures["cycles"], figures["missed"])
    section.tables.append(table)
    share = ratio(b50 / 1e3, figures["cold_start"])
    section.ratios["restart / cold start"] = share or float("nan")
    section.notes.append(f"{figures['restarts']} of {kills} kills restarted; kill to tasks ON again, p50 {b50:.0f} ms, "
                         f"max {back.max():.0f} ms: {fmt_ratio(share)} of the same run's cold start "
                         f"({figures['cold_start'] * 1e3:.0f} ms)")
    missed = figures["missed"]
    section.notes.append(f"robot interface: {missed} releases missed over the restarts (goal 0) -> "
                         f"{'met' if missed == 0 else 'NOT met'} ({figures['cycles']:,} cycles, {figures['overruns']} overruns)")
    if figures["failure"]:
        section.notes.append(f"the run failed: {figures['failure']}")
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kills", type=int, default=20)
    args = parser.parse_args()
    print(run(args.kills).text())


if __name__ == "__main__":
    main()
