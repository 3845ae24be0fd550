"""Operator verbs on running subsystems: do they disturb a cycle?

Each shipped configuration that runs on the real clock (configs/*.yaml) is started under its own
name, and the operator's verbs are sent to it one by one over its control queue, as `pbo VERB`
sends them: set, switch, job, spawn (a data logger writing MCAP), off, on, kill (of that
logger), replace, save. Each verb has a window of fixed length from its request; the same
length just before the request, without a verb, is its baseline. Counted in each window: the
critical tasks' holds (stable episodes beginning in it, from the run's report) and the releases
of every task missed (late by more than its period, from the table's counts as the run goes).

    python -m bench.verbs [--window 0.6] [--rounds 1] [--configs pid_joint,switch_joint]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench._common import REPO, Section, Table
from bench._inject import table_of
from bench.platform_probe import GAP_BEYOND, PROBE_PRIORITY, WAKE_EVERY, Gaps, PlatformProbe
from pbo_runtime import module_class, read_log
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import ControlClient
from pbo_runtime.supervisor.commands import COMMANDS
from pbo_runtime.table.table import StateTable, TableLayout
from pbo_runtime.table.table import StatusWord as W

CONFIGS = Path(REPO) / "configs"
QUICK_CONFIGS = ("pid_joint", "switch_joint")
VERBS = ("set", "switch", "job", "spawn", "off", "on", "kill", "replace", "save")
SAFETY_NET = 120.0  # s a run may take to say it is on: a net for a hang
MACHINE_MARGIN = 0.001  # s: a hold this soon (and two periods of the held task) after a gap of the machine is its doing
LOGGER = "vlog"  # the data logger the benchmark spawns, turns off and on, and kills
SKIPPED = {"fault_drill": "injects faults on purpose", "cartesian_teleop_hmi": "driven from the browser HMI",
           "leader": "a subsystem of the application leader_follower.yaml: its links need it",
           "follower": "a subsystem of the application leader_follower.yaml: its links need it",
           "leader_follower": "an application of two subsystems (links): not measured here",
           "two_arms": "an application of parallel stages: not measured here",
           "ros2_control": "its robot is a ros2_control peer that is not started here"}


@dataclass
class Window:
    verb: str
    outcome: str = ""  # "" done, else why it was refused or skipped
    holds: int = 0
    missed: int = 0
    took: float = math.nan  # s from request to reply
    causes: list[str] = field(default_factory=list)  # each hold's cause and length, "stale q_m of robot 2 ms"
    baseline_holds: int = 0
    baseline_missed: int = 0
    longest: float = 0.0  # s, the longest hold that began in the window
    baseline_longest: float = 0.0
    longest_periods: int = 0  # the same, in whole periods of the held task (`periods_held`)
    baseline_longest_periods: int = 0
    machine_holds: int = 0  # holds that began while the machine held a CPU from the probe (not counted above)
    baseline_machine_holds: int = 0


@dataclass
class ConfigRun:
    name: str
    windows: list[Window] = field(default_factory=list)
    failure: str = ""
    exit: int | None = None
    log_rows: int = -1  # rows of the spawned logger's MCAP log, read back after the run
    machine: Gaps = field(default_factory=Gaps)  # the platform probe's gaps while it ran


class Counts:
    """Every task's missed releases, summed, read from the run's table as it runs."""

    def __init__(self, config: Path, subsystem: str, supervisor: int) -> None:
        self.table = StateTable.attach(TableLayout.of(load_subsystem(config)), table_of(subsystem, supervisor))

    def missed(self) -> int:
        return int(self.table.status[:, W.MISSED].sum())


def copy_of(source: Path, folder: Path) -> tuple[Path, str]:
    """The configuration under a name of its own (runs side by side never share one)."""
    config = yaml.safe_load(source.read_text())
    name = f"verbs_{source.stem}"[:40]
    config["subsystem"] = name
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path, name


def requests(config: Path, status: dict[str, Any], folder: Path, round_index: int = 0) -> dict[str, dict[str, Any] | str]:
    """Each verb's request on this subsystem in round `round_index`, or why it has none here."""
    subsystem = load_subsystem(config)
    on = [t["task"] for t in status.get("tasks", []) if t.get("state") == "ON"]
    specs = [subsystem.tasks[name] for name in on if name in subsystem.tasks]
    critical = [s for s in specs if s.critical]
    others = [s for s in specs if not s.critical]
    made: dict[str, dict[str, Any] | str] = {}
    tunable = next(((s, p, v) for s in others + critical for p, v in tunables(s)), None)
    made["set"] = ({"task": tunable[0].name, "param": tunable[1], "values": [repr(v * 1.01) for v in tunable[2]]}
                   if tunable else "no tunable number")
    current = status.get("configuration", "")
    other = [c for c in subsystem.configurations if c != current]
    made["switch"] = {"configuration": other[0]} if other else "one configuration"
    made["job"] = job_request(subsystem, current) or "no job for the configuration on"
    logged = next((b.variable for s in critical for b in s.bindings if b.port.kind.name in ("OUT_VAR", "OUT_BOTH")), None)
    if logged is None:
        logged = next(iter(subsystem.variables))
    rtpu = (others or critical)[0].rtpu if specs else next(iter(subsystem.rtpus)).name
    made["spawn"] = {"task": LOGGER, "module": "data_logger", "rtpu": rtpu, "period": "10ms",
                     "param": [f"variables=[{logged}]", f"path={LOGGER}{round_index or ''}.mcap"]}
    made["off"] = made["on"] = made["kill"] = {"task": LOGGER}
    # a task holding an exclusive device cannot be replaced while it holds it (the new one's init is refused the device)
    exclusive = {name for name, device in subsystem.devices.items() if device.exclusive}
    replaceable = [s for s in others if s.module != "data_logger" and not exclusive.intersection(s.resources)]
    made["replace"] = {"task": replaceable[0].name, "new": f"{replaceable[0].name}_b"} if replaceable else "no task to replace"
    made["save"] = {"file": str(folder / "saved.yaml"), "force": True}
    return {verb: request if isinstance(request, str) else COMMANDS[verb].request(request) for verb, request in made.items()}


def tunables(spec: Any) -> list[tuple[str, list[float]]]:
    """A task's live-tunable numeric parameters given in its file (a number or one per element), with
    their values; none of a task whose gains come from a bandwidth (its raw gains are refused)."""
    module = module_class(spec.module)
    if spec.params.get("bandwidth"):
        return []
    found = []
    for param in module.TUNABLE:
        value = spec.params.get(param)
        if isinstance(value, bool) or value is None:
            continue
        values = np.ravel(np.asarray(value, dtype=float)) if isinstance(value, (int, float, list, tuple, np.ndarray)) else None
        if values is not None and values.size and np.all(values > 0):
            found.append((param, [float(v) for v in values]))
    return found


def job_request(subsystem: Any, current: str) -> dict[str, Any] | None:
    """A job of the configuration on (no switch), with its object's initial values, or None."""
    for job in subsystem.jobs.values():
        if job.configuration != current:
            continue
        if job.object is None:
            return {"name": job.name, "values": None}
        initial = getattr(subsystem.variables.get(job.object), "initial", None)
        if initial is not None:
            return {"name": job.name, "values": [repr(float(v)) for v in np.ravel(initial)]}
    return None


def measure(source: Path, window: float, rounds: int = 1) -> ConfigRun:
    result = ConfigRun(source.stem)
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        config, name = copy_of(source, folder)
        report_path = folder / "report.json"
        marks: list[tuple[Window, float, float]] = []  # (window, baseline from, window from)
        with PlatformProbe() as probe:
            process = run_verbs(config, name, folder, report_path, window, rounds, marks, result)
        result.machine = probe.gaps
        if not report_path.exists():
            result.failure = result.failure or f"no report (exit {process.returncode})"
            return result
        report = json.loads(report_path.read_text())
        critical = {name for name, t in report["tasks"].items() if t.get("critical")} or {"robot"}
        periods = {name: spec.period for name, spec in load_subsystem(config).tasks.items()}
        episodes: list[dict[str, Any]] = []
        machine: list[dict[str, Any]] = []
        for e in report.get("stable_episodes", []):
            if e["task"] in critical:
                # a hold begins at the first release after its input went stale: up to two writer periods after the gap
                began_by = e["from"] - 2 * periods.get(e["task"], 0.0) - MACHINE_MARGIN
                (machine if probe.gaps.during(began_by, e["to"] or e["from"]) else episodes).append(e)
        for entry, baseline_from, window_from in marks:
            before = [e for e in episodes if baseline_from <= e["from"] < window_from]
            held = [e for e in episodes if window_from <= e["from"] < window_from + window]
            entry.baseline_holds, entry.holds = len(before), len(held)
            entry.baseline_machine_holds = sum(baseline_from <= e["from"] < window_from for e in machine)
            entry.machine_holds = sum(window_from <= e["from"] < window_from + window for e in machine)
            entry.baseline_longest = max((_length(e) for e in before), default=0.0)
            entry.longest = max((_length(e) for e in held), default=0.0)
            entry.baseline_longest_periods = max((periods_held(e, periods) for e in before), default=0)
            entry.longest_periods = max((periods_held(e, periods) for e in held), default=0)
            entry.causes = [f"{_cause(e)} {_length(e) * 1e3:.0f} ms" for e in held]
            entry.causes += [f"{_cause(e)} {_length(e) * 1e3:.0f} ms (the machine's)" for e in machine
                             if window_from <= e["from"] < window_from + window]
        logs = sorted((folder / "out").glob(f"{LOGGER}*.mcap"))
        if logs:
            result.log_rows = sum(len(read_log(log)) for log in logs)
    return result


def run_verbs(config: Path, name: str, folder: Path, report_path: Path, window: float, rounds: int,
              marks: list[tuple[Window, float, float]], result: ConfigRun) -> subprocess.Popen[str]:
    """Start the run, send it every verb `rounds` times in its windows (`marks`), stop it; the ended process."""
    process = subprocess.Popen([sys.executable, "-m", "pbo_runtime.cli", "run", str(config), "--duration", "0",
                                "--out", str(folder / "out"), "--report", str(report_path)],
                               cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        if not said(process, "is on"):
            result.failure = "did not start: " + (process.stderr.read().strip().splitlines() or ["?"])[-1][:160]  # type: ignore[union-attr]
            return process
        client = ControlClient(name, next(r for r in _run_ids(name, process.pid)))
        counts = Counts(config, name, process.pid)
        try:
            time.sleep(window)  # the start's own late releases are over
            for round_index in range(rounds):
                made = requests(config, client.call("status"), folder, round_index)
                marks += windows(client, counts, made, window, result)
        finally:
            counts.table.close()
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
        try:
            process.communicate(timeout=SAFETY_NET)
        except subprocess.TimeoutExpired:
            process.kill()
            process.communicate()
        result.exit = process.returncode
    return process


def _length(episode: dict[str, Any]) -> float:
    return float((episode["to"] or episode["from"]) - episode["from"])


def periods_held(episode: dict[str, Any], periods: dict[str, float]) -> int:
    """A hold's length in whole periods of the held task: the cycles it ran stable instead of its
    cycle. Its ends are release times, so the length is a whole number of periods up to the
    clock's reading; rounding makes two holds of as many cycles equal however they were read."""
    period = periods.get(episode["task"])
    if not period:
        return 0
    return round(_length(episode) / period)


def _periods(count: int) -> str:
    return f"{count} period{'' if count == 1 else 's'}"


def more_than_chance(in_windows: int, in_baselines: int) -> float:
    """One-sided p-value that events fell in the verbs' windows rather than their baselines (of
    equal length) by chance: P(X >= in_windows) for X ~ Binomial(in_windows + in_baselines, 1/2)."""
    n = in_windows + in_baselines
    return sum(math.comb(n, k) for k in range(in_windows, n + 1)) / 2**n if n else 1.0


def _cause(episode: dict[str, Any]) -> str:
    """A hold's cause, and for a stale input its variable and writer: "stale q_m of robot"."""
    found = re.search(r"in-var '([^']+)'.*\('([^']+)' stopped", episode.get("reason", ""))
    cause = episode.get("cause", "?")
    return f"{cause} {found[1]} of {found[2]}" if cause == "stale" and found else cause


def windows(client: ControlClient, counts: Counts, made: dict[str, dict[str, Any] | str], window: float,
            result: ConfigRun) -> list[tuple[Window, float, float]]:
    """Each verb sent in its window after a baseline as long; (window, baseline from, window from) of each."""
    marks = []
    for verb in VERBS:
        entry = Window(verb)
        request = made[verb]
        if isinstance(request, str):
            entry.outcome = request
            result.windows.append(entry)
            continue
        before = counts.missed()
        time.sleep(window)
        at = time.monotonic()
        middle = counts.missed()
        entry.baseline_missed = middle - before
        try:
            client.call(verb, request, timeout=COMMANDS[verb].timeout)
        except PboError as exc:
            entry.outcome = f"refused: {str(exc)[:400]}"
        entry.took = time.monotonic() - at
        time.sleep(max(at + window - time.monotonic(), 0.0))
        entry.missed = counts.missed() - middle
        marks.append((entry, at - window, at))
        result.windows.append(entry)
    return marks


def said(process: subprocess.Popen, text: str) -> bool:
    assert process.stdout is not None
    give_up = time.monotonic() + SAFETY_NET
    for line in process.stdout:
        if text in line:
            return True
        if time.monotonic() > give_up:
            break
    return False


def _run_ids(subsystem: str, supervisor: int) -> list[str]:
    from pbo_runtime.ipc.runs import live_runs

    return [run.run_id for run in live_runs() if run.subsystem == subsystem and run.pid == supervisor]


def shipped(names: tuple[str, ...] = ()) -> list[Path]:
    return [path for path in sorted(CONFIGS.glob("*.yaml")) if (not names or path.stem in names)]


def run(window: float = 0.6, configs: tuple[str, ...] = (), rounds: int = 1) -> Section:
    paths = shipped(configs)
    section = Section(
        key="verbs",
        title="Operator verbs on running subsystems",
        command=f"python -m bench.verbs --window {window:g} --rounds {rounds}"
                + (f" --configs {','.join(configs)}" if configs else ""),
        method=f"""
{len(VERBS)} verbs on {len(paths)} configurations: each of configs/ that runs on the real clock
is started under a name of its own (live changes on), and once it is on the benchmark sends the
operator's verbs over its control queue, as `pbo VERB` does, one at a time: `set` (the first live-tunable number of a task, times
1.01), `switch` (to another configuration), `job` (one of the configuration on, with its object's
initial values), `spawn` (a data logger `{LOGGER}` writing MCAP, on the RTPU of the first
non-critical task), `off`, `on` and `kill` of that logger, `replace` (a non-critical task by a
copy of itself), `save` (the live subsystem to a file), {rounds} round(s) of them. Each verb's window is {window:g} s from its
request; the {window:g} s just before the request, without a verb, is its baseline in the same run.
Counted in each: the **holds** of the critical tasks (stable episodes that begin in it, from the
run's report) and the **missed** releases of all tasks (a release late by more than its period is
skipped and counted, from the table as the run goes). The goal: none caused by a verb. Beside
each run, a probe at SCHED_FIFO {PROBE_PRIORITY} on each CPU (`bench.platform_probe`, as cyclictest) records when the
machine itself (the kernel, the hypervisor) held a CPU from the highest priority for more than
{GAP_BEYOND * 1e3:g} ms: a hold that began within such a gap (or two periods of the held task after it) is listed
as the machine's and counted neither for nor against a verb. A machine
that holds now and then without any verb does so in windows and baselines alike, so a verb is
blamed when its windows hold (or have a missed release) more often than its baselines beyond
chance (one-sided binomial test at p < 0.05 over the {len(VERBS)} verbs), or when a hold in its windows
lasts at least one whole period of the held task longer than any hold in any baseline (a hold is
a whole number of periods the task ran stable: lengths are compared in periods, not in ms). After
the run, the spawned logger's MCAP log is
read back (it was killed live: its summary and footer were written off the cycle).
""",
        limits="""A window counts what happened in it, whatever caused it: on this shared 2-CPU
machine the hypervisor and other tenants cause holds and missed releases too, which the
baselines count. A verb that is not applicable to a configuration (one configuration: no switch)
is listed as such. `spawn` and `replace` make the new task on its RTPU between two cycles: the
executive runs the cycles that come due between its steps (its timing rings, its `init`) and
through an `init`'s waits for a device (`sleep_while_cycling`: the special-purpose processor's
start), and the RTPU imported every module of the library before the run came on; a step longer
than a period still makes releases late.

What a verb costs on its RTPU (measured on 2026-11-28 with each RTPU timing its own handling of
every signal, on force_sensing and join, a loaded machine): a verb's work runs between cycles,
never inside one. `on`, `off`, `kill` 0.1-0.6 ms; a live change staged (what `spawn`, `kill`,
`replace` and `set` send every RTPU) 0.3-0.84 ms; a plan applied at its boundary 0.06-0.93 ms; a
`spawn` 1.6-3.9 ms in all, in steps of at most 1.3 ms with the cycles due run between them. `save`
sends an RTPU nothing. Of 165 releases later than a period in those runs, 2 bursts followed a
verb's step on their RTPU; the others came with no verb's work on it, most on both RTPUs at once
and the largest with a stall of the plant: the machine's, not the verbs'.""",
    )
    results = []
    for path in paths:
        if path.stem in SKIPPED:
            results.append(ConfigRun(path.stem, failure=f"skipped: {SKIPPED[path.stem]}"))
            continue
        results.append(measure(path, window, rounds))
    table = Table(["verb", "verbs sent", "holds", "baseline holds", "longest hold periods (ms)", "baseline longest periods (ms)",
                   "windows with a missed release", "baselines with one", "reply p50 ms", "reply max ms"],
                  numeric=(1, 2, 3, 4, 5, 6, 7, 8, 9))
    blamed: list[str] = []
    all_done = [w for r in results for w in r.windows if not w.outcome]
    # the longest hold of any baseline, in periods of its task (its length in ms for the reader)
    longest_baseline = max(all_done, key=lambda w: (w.baseline_longest_periods, w.baseline_longest), default=Window(""))
    for verb in VERBS:
        done = [w for r in results for w in r.windows if w.verb == verb and not w.outcome]
        holds, base_holds = sum(w.holds for w in done), sum(w.baseline_holds for w in done)
        missing, base_missing = sum(w.missed > 0 for w in done), sum(w.baseline_missed > 0 for w in done)
        longest = max(done, key=lambda w: (w.longest_periods, w.longest), default=Window(verb))
        base_longest = max(done, key=lambda w: (w.baseline_longest_periods, w.baseline_longest), default=Window(verb))
        took = np.array([w.took for w in done]) * 1e3
        table.add(verb, len(done), holds, base_holds, f"{longest.longest_periods} ({longest.longest * 1e3:.0f})",
                  f"{base_longest.baseline_longest_periods} ({base_longest.baseline_longest * 1e3:.0f})",
                  missing, base_missing, f"{np.median(took):.1f}" if done else "", f"{took.max():.1f}" if done else "")
        # a verb is blamed when its windows hold or miss more often than chance allows beside their baselines
        # (one-sided binomial test, p < 0.05 over the verbs: Bonferroni), or hold at least one whole period
        # of the held task longer than any baseline did
        for what, seen, base in (("holds", holds, base_holds), ("windows with a missed release", missing, base_missing)):
            p = more_than_chance(seen, base)
            if p < 0.05 / len(VERBS):
                blamed.append(f"{verb}: {what} {seen} against {base} in its baselines (p = {p:.2g})")
        if longest.longest_periods > longest_baseline.baseline_longest_periods:
            blamed.append(f"{verb}: a hold of {_periods(longest.longest_periods)} ({longest.longest * 1e3:.0f} ms), longer "
                          f"than any in a baseline ({_periods(longest_baseline.baseline_longest_periods)}, "
                          f"{longest_baseline.baseline_longest * 1e3:.0f} ms)")
    section.tables.append(table)
    per_config = Table(["configuration", "verbs done", "holds (baseline)", "missed (baseline)", "exit", "note"],
                       numeric=(1, 2, 3, 4), caption="Per configuration:")
    for r in results:
        done = [w for w in r.windows if not w.outcome]
        notes = list(dict.fromkeys(f"{w.verb}: {w.outcome}" for w in r.windows if w.outcome))
        if r.log_rows >= 0:
            notes.append(f"{LOGGER}.mcap read back: {r.log_rows} rows")
        per_config.add(r.name, len(done), f"{sum(w.holds for w in done)} ({sum(w.baseline_holds for w in done)})",
                       f"{sum(w.missed for w in done)} ({sum(w.baseline_missed for w in done)})",
                       "" if r.exit is None else r.exit, r.failure or "; ".join(notes))
    section.tables.append(per_config)
    for r in results:
        for w in r.windows:
            if w.causes:
                section.notes.append(f"{r.name}, {w.verb}: held {', '.join(w.causes)}")
            if w.missed > 0:
                section.notes.append(f"{r.name}, {w.verb}: {w.missed} missed release(s) in its window, "
                                     f"{w.baseline_missed} in its baseline")
    if sys.flags.dont_write_bytecode:
        section.notes.append("PYTHONDONTWRITEBYTECODE is set where this ran: no module's bytecode is cached, so each RTPU "
                             "compiles the library it imports at start-up (a `spawn` imports nothing)")
    machine_holds = sum(w.machine_holds for w in all_done)
    base_machine_holds = sum(w.baseline_machine_holds for w in all_done)
    probed = [r.machine for r in results if r.machine.seconds]
    gaps = [g for m in probed for g in m.gaps]
    longest_gap = max((g.length for g in gaps), default=0.0)
    section.notes.append(
        f"the machine itself (a SCHED_FIFO {PROBE_PRIORITY} probe on each CPU, waking every {WAKE_EVERY * 1e3:g} ms): "
        + (f"{len(gaps)} gaps over {GAP_BEYOND * 1e3:g} ms in {sum(m.seconds for m in probed):.0f} s, the longest "
           f"{longest_gap * 1e3:.2f} ms; holds that began within one: {machine_holds} in the verbs' windows, "
           f"{base_machine_holds} in their baselines (listed as the machine's, not counted against the verbs)"
           if probed and all(m.realtime for m in probed)
           else "not measured: SCHED_FIFO refused to the probe, every hold is counted"))
    holds, base_holds = sum(w.holds for w in all_done), sum(w.baseline_holds for w in all_done)
    missing, base_missing = sum(w.missed > 0 for w in all_done), sum(w.baseline_missed > 0 for w in all_done)
    section.notes.append(f"all verbs: holds of a critical task {holds} in the verbs' windows, {base_holds} in their baselines "
                         f"(p = {more_than_chance(holds, base_holds):.2g}); windows with a missed release {missing}, "
                         f"baselines {base_missing} (p = {more_than_chance(missing, base_missing):.2g}); "
                         f"{len(all_done)} verbs, {window:g} s windows")
    section.notes.append("holds or late releases caused by verbs (goal: none) -> "
                         + ("met: no verb holds or misses more often than its baselines beyond chance, nor longer than them"
                            if not blamed else "NOT met: " + "; ".join(blamed)))
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--window", type=float, default=0.6)
    parser.add_argument("--configs", default="", help="comma-separated names of configs/*.yaml (default: all)")
    parser.add_argument("--rounds", type=int, default=1, help="times each configuration is sent every verb")
    args = parser.parse_args()
    print(run(args.window, tuple(c for c in args.configs.split(",") if c), args.rounds).text())


if __name__ == "__main__":
    main()
