"""Faults on the real clock: what the runtime does when a part of a running subsystem fails.

Each case runs the PID demo (`configs/pid_joint.yaml`, its logger moved next to the robot
interface so the arm is recorded whatever else stops), injects one fault 0.3 s into the move,
and reads what happened from the run's report and log:

- detected after: from the fault to the first cycle the critical task ran its locally stable
  behaviour (ms), from the report's stable episodes (brief holds on a late input, timing that
  any run may show, are counted apart); for a held table lock, to the moment the
  supervisor ended the holding (its `lock_events`); for a hung module, the fault began at the
  release of the cycle that never returned (the table's status block);
- excursion: the largest distance a joint went past its goal, in the direction it was moving
  (rad), from the logged joint positions; a joint that was not to move counts any distance;
- objects left: shared-memory segments and queues of the run still there after it ended;
- exit: the status `pbo run` ended with (2: a fault was reported).

    python -m bench.faults [--cases controller_stop,lock_stop] [--stop-seconds 2]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from bench._common import REPO, Section, Table
from bench._inject import InjectionFailed, stop_process, stop_while_holding_the_lock, table_of
from pbo_runtime.ipc import shm

DEMO = Path(REPO) / "configs" / "pid_joint.yaml"
SUBSYSTEM = "puma_faults"
INTO_THE_MOVE = 0.3  # seconds after the configuration came on when the fault is injected
HANG_AFTER = 150  # cycles of the hung module's 2 ms task before its cycle stops returning: 0.3 s
RUN_SECONDS = 5.0  # the demo's move takes about 1.5 s; what follows shows the arm settled, or not


@dataclass
class Outcome:
    case: str
    what: str
    detected_ms: float | None
    excursion: float | None
    left: int
    exit_status: int
    note: str = ""


def bench_config(folder: Path, hang: bool = False) -> Path:
    """The demo with its own subsystem name, its logger on the robot's RTPU, every 2 ms; with `hang`,
    a module on the controller's RTPU whose cycle stops returning HANG_AFTER cycles in."""
    config = yaml.safe_load(DEMO.read_text())
    config["subsystem"] = SUBSYSTEM
    config["tasks"]["logger"].update({"rtpu": "rtpu1", "period": "2 ms",
                                      "params": {"variables": ["q_m"], "path": "arm.npy"}})
    if hang:
        config["tasks"]["stuck"] = {"module": "fault_injector", "rtpu": "rtpu0", "period": "2 ms",
                                    "params": {"fail_after": HANG_AFTER, "fault": "hang"}}
        config["configurations"]["joint_pid"].append("stuck")
    path = folder / "faults.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def run_objects() -> list[str]:
    """This benchmark's subsystem's objects in /dev/shm and /dev/mqueue."""
    names = []
    for folder in ("/dev/shm", "/dev/mqueue"):
        try:
            names += [f"{folder}/{n}" for n in os.listdir(folder) if f".{SUBSYSTEM}." in f".{n}"]
        except OSError:
            continue
    return names


def wait_for_the_move(process: subprocess.Popen, timeout: float = 60.0) -> None:
    """Until the robot task has run its first cycles (the configuration is on)."""
    from pbo_runtime.table.svar import open_table

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"pbo run ended before the move began (exit {process.returncode})")
        try:
            with open_table(SUBSYSTEM) as view:
                if max(row["cycles"] for row in view.task_status()) > 0:
                    return
        except Exception:  # not created yet
            pass
        time.sleep(0.01)
    raise RuntimeError("the move did not begin within a minute")


def excursion_past_goal(q: np.ndarray, goal: np.ndarray) -> float:
    """The largest distance a joint went past its goal, moving towards it (rad)."""
    start = q[0]
    direction = np.sign(goal - start)
    past = np.where(direction != 0, direction * (q - goal), np.abs(q - goal))
    return float(max(0.0, past.max()))


def child_with(pid: int, marker: str) -> int:
    """The child of `pid` whose command line holds `marker`, waiting a little for it to show in /proc."""
    for _ in range(100):
        found = [p for p, cmd in shm.children_of(pid).items() if marker in cmd]
        if found:
            return found[0]
        time.sleep(0.05)
    raise RuntimeError(f"no child of {pid} runs '{marker}'")


def controller_process(pid: int) -> int:
    return child_with(pid, "--rtpu rtpu0")


def robot_process(pid: int) -> int:
    return child_with(pid, "--rtpu rtpu1")


def plant_process(pid: int) -> int:
    return child_with(pid, "plant_host")


def resume(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):  # the supervisor killed it
        os.kill(pid, signal.SIGCONT)


@dataclass(frozen=True)
class LiveRun:
    supervisor: int  # the pid of its `pbo run`
    config: Path


# Each injector acts on a live run: it causes its fault, lets it last `seconds`, and returns the
# CLOCK_MONOTONIC time the fault began.
Injector = Callable[[LiveRun, float], float]


def stopped(target: Callable[[int], int]) -> Injector:
    """SIGSTOP the run's process that `target` finds, for `seconds`, then SIGCONT."""
    def inject(run: LiveRun, seconds: float) -> float:
        pid = target(run.supervisor)
        stopped_at = stop_process(pid)
        time.sleep(seconds)
        resume(pid)
        return stopped_at
    return inject


def stopped_holding_the_lock(run: LiveRun, seconds: float) -> float:
    """SIGSTOP the controller's RTPU at a moment it holds the table lock, for `seconds` (if it lives that long)."""
    pid = controller_process(run.supervisor)
    stopped_at = stop_while_holding_the_lock(pid, table_of(SUBSYSTEM, run.supervisor))
    time.sleep(seconds)
    resume(pid)
    return stopped_at


def observer_stopped_then_killed(_run: LiveRun, seconds: float) -> float:
    """`pbo svar --watch` on the run, SIGSTOPped for `seconds` while it watches, then SIGKILLed."""
    watcher = subprocess.Popen([sys.executable, "-m", "pbo_runtime.cli", "svar", "q_m", "tau_u", "--watch",
                                "--interval", "0.01", "--subsystem", SUBSYSTEM],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(0.2)  # it has read the table a few times
        if watcher.poll() is not None:
            raise InjectionFailed(f"pbo svar --watch ended by itself (exit {watcher.returncode})")
        stopped_at = stop_process(watcher.pid)
        time.sleep(seconds)
        watcher.kill()
        return stopped_at
    finally:
        if watcher.poll() is None:
            watcher.kill()
        watcher.wait()


def hung(run: LiveRun, seconds: float) -> float:
    """Nothing from outside: the module hangs by itself. The fault began at the release of the cycle
    that never ended, one period after the last one that did (the table's status block)."""
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.table.svar import attach

    stuck = load_subsystem(str(run.config)).tasks["stuck"]
    time.sleep(seconds)
    with attach(table_of(SUBSYSTEM, run.supervisor)) as view:
        row = view.task_status()[stuck.index]
    if row["cycles"] != HANG_AFTER:
        raise InjectionFailed(f"the module was to hang after {HANG_AFTER} cycles; its task has finished {row['cycles']}")
    return row["release"] + stuck.period


@dataclass(frozen=True)
class Case:
    what: str
    inject: Injector | None  # None: no fault
    hang: bool = False  # the run has a module that hangs (bench_config)


CASES: dict[str, Case] = {
    "none": Case("no fault: the baseline of the excursion", None),
    "controller_stop": Case("SIGSTOP the controller's RTPU (trajectory and PID) for {s:g} s", stopped(controller_process)),
    "plant_stop": Case("SIGSTOP the plant for {s:g} s", stopped(plant_process)),
    "robot_stop": Case("SIGSTOP the robot interface's RTPU (and the logger) for {s:g} s", stopped(robot_process)),
    "lock_stop": Case("SIGSTOP the controller's RTPU while it holds the table lock, for {s:g} s", stopped_holding_the_lock),
    "observer_stop": Case("SIGSTOP `pbo svar --watch` for {s:g} s, then SIGKILL it", observer_stopped_then_killed),
    "module_hang": Case("a module on the controller's RTPU whose cycle never returns", hung, hang=True),
}


def run_case(case: str, stop_seconds: float, run_seconds: float = RUN_SECONDS) -> Outcome:
    spec = CASES[case]
    what = spec.what.format(s=stop_seconds)
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        config = bench_config(folder, hang=spec.hang)
        out = folder / "out"
        report = folder / "report.json"
        goal = np.array(yaml.safe_load(DEMO.read_text())["variables"]["q_d"]["initial"], dtype=float)
        process = subprocess.Popen([sys.executable, "-m", "pbo_runtime.cli", "run", str(config), "--duration",
                                    str(run_seconds), "--out", str(out), "--report", str(report), "--no-live"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            wait_for_the_move(process)
            time.sleep(INTO_THE_MOVE)
            fault_at = spec.inject(LiveRun(process.pid, config), stop_seconds) if spec.inject else time.monotonic()
            _, stderr = process.communicate(timeout=run_seconds + stop_seconds + 60)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        left = len(run_objects())
        if not report.exists():
            return Outcome(case, what, None, None, left, process.returncode, f"no report: {stderr.strip()[-200:]}")
        result = json.loads(report.read_text())
        log = np.load(out / "arm.npy")
        excursion = excursion_past_goal(log["q_m"], goal)
        detected, said = detection(case, result, fault_at, stop_seconds, spec.inject is not None)
        return Outcome(case, what, detected, excursion, left, process.returncode, said)


def detection(case: str, result: dict, fault_at: float, seconds: float, faulted: bool) -> tuple[float | None, str]:
    """(detected after, ms; what the run said) from the run's report.

    The fault's hold is the first episode of the critical task that began during the fault and
    was not brief (the report's `brief`: a late input of a moment, told as timing); brief ones are
    counted in what the run said.
    """
    during = [e for e in result["stable_episodes"] if fault_at <= e["from"] <= fault_at + seconds]
    held = [e for e in during if not e.get("brief")]
    events = result.get("lock_events", [])
    detected = (held[0]["from"] - fault_at) * 1e3 if held else None
    said = held[0]["reason"] if held else "no hold" + (" after the fault" if faulted else "")
    if case == "robot_stop":  # the stopped task is the one that would hold: the plant's watchdog does
        detected, said = None, "no hold after the fault"
    if events:
        event = events[0]
        detected = (result["started_monotonic"] + event["at"] - fault_at) * 1e3
        said = (f"lock held {event['held_ms']:.0f} ms (bound {event['bound_ms']:.0f} ms) by {event['role'] or event['pid']}, "
                f"{event['state']}: {event['action']}; " + said)
    trips = result.get("plant", {}).get("watchdog_trips", 0)
    if trips:
        said += f"; the plant's drive watchdog held the arm {trips} time{'s' if trips > 1 else ''}"
    if case == "observer_stop" and not held and not events:
        said = "nothing to detect: the run never waited for the observer"
    brief = sum(1 for e in result["stable_episodes"] if e.get("brief"))
    if brief:
        said += f"; {brief} brief hold{'s' if brief > 1 else ''} on a late input (timing)"
    return detected, said


def run(cases: tuple[str, ...] = tuple(CASES), stop_seconds: float = 2.0, run_seconds: float = RUN_SECONDS) -> Section:
    section = Section(
        key="faults",
        title="Faults on the real clock",
        command=f"python -m bench.faults --cases {','.join(cases)} --stop-seconds {stop_seconds:g}",
        method=f"""
Each case runs the PID demo for {run_seconds:g} s on the real clock (its logger moved to the robot's
RTPU, every 2 ms) and injects its fault {INTO_THE_MOVE:g} s after the configuration came on, in the
middle of the move. *Detected after*: from the fault to the critical task's first locally stable
cycle. *Excursion*: the largest distance a joint went past its goal in the direction it moved,
from the logged positions. *Left*: the run's objects in /dev/shm and /dev/mqueue after it ended.
""",
        limits="""Detection is bounded by the freshness bound (two periods of the input's writer
by default) plus one period of the critical task; the excursion is what the arm does with the
brakes applied from then on, and after the fault ends, with the controller catching up.""",
    )
    table = Table(["case", "fault", "detected after ms", "excursion rad", "objects left", "exit", "what the run said"],
                  numeric=(2, 3, 4, 5))
    outcomes: dict[str, Outcome] = {}
    for case in cases:
        outcome = run_case(case, stop_seconds, run_seconds)
        table.add(outcome.case, outcome.what, "n/a" if outcome.detected_ms is None else f"{outcome.detected_ms:.1f}",
                  "n/a" if outcome.excursion is None else f"{outcome.excursion:.4f}", outcome.left, outcome.exit_status,
                  outcome.note.replace("|", "/"))
        outcomes[case] = outcome
    section.tables.append(table)
    if "controller_stop" in outcomes:
        excursion, detected = outcomes["controller_stop"].excursion, outcomes["controller_stop"].detected_ms
        section.notes.append(
            f"controller stopped: excursion past the goal {excursion if excursion is not None else float('nan'):.4f} rad "
            f"(target < 0.05 rad) -> {'met' if excursion is not None and excursion < 0.05 else 'NOT met'}; detected after "
            f"{detected if detected is not None else float('nan'):.1f} ms (target <= 3 periods of the robot task, 3 ms) -> "
            f"{'met' if detected is not None and detected <= 3.0 else 'NOT met'}")
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of: {', '.join(CASES)}")
    parser.add_argument("--stop-seconds", type=float, default=2.0)
    args = parser.parse_args()
    print(run(tuple(c.strip() for c in args.cases.split(",") if c.strip()), args.stop_seconds).text())


if __name__ == "__main__":
    main()
