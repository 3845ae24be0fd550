"""How long `pbo run` takes to turn its first configuration on, and where that time goes.

The figure is wall time on CLOCK_MONOTONIC, from just before this process starts the command
(`pbo run configs/pid_joint.yaml`, as subsystem `bench_startup` so it never meets another run of
the demo) to the moment the supervisor saw every task of the first configuration ON: the run
report's `started_monotonic`. The report's `startup` time line splits it into phases. Each
round starts every contender once, in an order rotated round by round, so the machine's other
work falls on all alike; a bare interpreter that imports numpy and exits is the floor, the least
any Python process of the run costs.

Bytecode is cached, as after a run of the installed package (pip compiles it at install; a
checkout writes it on its first run): each run's Python caches it under one temporary
PYTHONPYCACHEPREFIX, written by a first run that is not counted.

    python -m bench.startup [--rounds 12]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench._common import REPO, Section, Table, Target, fmt_ratio, ratio

SUBSYSTEM = "bench_startup"
GOAL = 0.3  # seconds, `pbo run` to configuration on (issues 23, 40)
RUN_SECONDS = 0.05  # how long each run lasts once on: the figure ends at "on"; the rest is the stop
# The report's time line, in the order the phases run, and what each phase's segment is called
# (a segment ends at its mark and starts at the one before; "start" is this process's Popen)
PHASES = (
    ("cli", "interpreter and the CLI's imports"),
    ("loaded", "load and check the file"),
    ("table", "clean-up, queues, table"),
    ("children", "start the plant and the RTPUs"),
    ("spawned", "spawn the tasks (each init)"),
    ("on", "turn the configuration on"),
)


def demo_copy(folder: Path) -> Path:
    text = (Path(REPO) / "configs" / "pid_joint.yaml").read_text()
    if "\nsubsystem: puma\n" not in text:
        raise RuntimeError("configs/pid_joint.yaml no longer says 'subsystem: puma': update bench/startup.py")
    path = folder / f"{SUBSYSTEM}.yaml"
    path.write_text(text.replace("\nsubsystem: puma\n", f"\nsubsystem: {SUBSYSTEM}\n"))
    return path


def environment(cache: Path, results: Path) -> dict[str, str]:
    """Bytecode cached under `cache`, and pbo's result cache (`pbo_runtime.objects.result_cache`) in `results`."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    return {**env, "PYTHONPYCACHEPREFIX": str(cache), "PBO_CACHE_DIR": str(results)}


def time_run(file: Path, folder: Path, env: dict[str, str], fork_server: bool = True) -> dict[str, float]:
    """One `pbo run`: seconds from its start to each mark of its time line ('on' the figure)."""
    report = folder / "report.json"
    report.unlink(missing_ok=True)
    command = [sys.executable, "-m", "pbo_runtime.cli", "run", str(file), "--duration", repr(RUN_SECONDS),
               "--no-live", "--out", str(folder / "out"), "--report", str(report)]
    env = {**env, "PBO_FORK_SERVER": "1" if fork_server else "0"}
    start = time.monotonic()
    done = subprocess.run(command, cwd=folder, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True)
    # the figure ends at "on": a run that came on and then failed (exit 2: a busy machine's timing
    # faults, a stop that overran) still measured it
    timeline = json.loads(report.read_text()).get("startup", {}) if report.exists() else {}
    if "on" not in timeline:
        said = (done.stderr.strip() or done.stdout.strip()).splitlines()
        raise RuntimeError(f"`pbo run` did not turn its configuration on (exit {done.returncode}): {' / '.join(said[-2:])}")
    return {phase: at - start for phase, at in timeline.items() if phase != "process"}


def time_floor(env: dict[str, str]) -> float:
    """A bare interpreter that imports numpy and exits: the least any process of the run costs."""
    start = time.monotonic()
    subprocess.run([sys.executable, "-c", "import numpy"], env=env, check=True, stdin=subprocess.DEVNULL)
    return time.monotonic() - start


CLI_FLOOR = "floor: `python -c pass`"
CHECK = "`pbo check FILE`"
COLD_CHECK = "`pbo check FILE`, the machine's first (no result cache)"
CLI_ANSWERS = (  # (what, the command after the interpreter, environment over the run's): the answers a terminal waits for
    (CLI_FLOOR, ["-c", "pass"], {}),
    ("`pbo --version`", ["-m", "pbo_runtime.cli", "--version"], {}),
    ("`pbo --help`", ["-m", "pbo_runtime.cli", "--help"], {}),
    (CHECK, ["-m", "pbo_runtime.cli", "check", "FILE"], {}),
    (COLD_CHECK, ["-m", "pbo_runtime.cli", "check", "FILE"], {"PBO_CACHE_DIR": "off"}),
)
CLI_GOALS = {"`pbo --version`": 0.1, CHECK: 0.3}  # seconds, p50 of the whole process (issue 40)


def time_cli(arguments: list[str], file: Path, env: dict[str, str]) -> float:
    """One CLI command, from its start to its end (its output discarded)."""
    command = [sys.executable, *(str(file) if a == "FILE" else a for a in arguments)]
    start = time.monotonic()
    subprocess.run(command, env=env, check=True, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    return time.monotonic() - start


def verdict(seconds: float, goal: float) -> str:
    return "met" if seconds <= goal else "not met"


def segments(marks: dict[str, float]) -> dict[str, float]:
    """Each phase's own seconds, from the end of the one before it ('children': until the last child is ready)."""
    out, before = {}, 0.0
    for phase, _ in PHASES:
        out[phase] = marks[phase] - before
        before = marks[phase]
    return out


def run(rounds: int = 12) -> Section:
    section = Section(
        key="startup",
        title="Start-up: `pbo run` to configuration on",
        command=f"python -m bench.startup --rounds {rounds}",
        method=f"""
Wall time from just before this process starts `pbo run configs/pid_joint.yaml` (as subsystem
`{SUBSYSTEM}`, real clock) to the moment the supervisor saw every task of its first configuration
ON (the run report's `started_monotonic`; `startup` in the report holds each phase's end). Each of
{rounds} rounds starts `pbo run`, `pbo run` with PBO_FORK_SERVER=0 (the plant and each RTPU a fresh
interpreter, as before the fork server) and a bare interpreter that imports numpy (the floor: the
least a Python process costs), in an order rotated round by round; then, as many rounds, the CLI's
quick answers (`pbo --version`, `pbo --help`, `pbo check` of the demo, and the same check with no
result cache: a machine's first) against a bare interpreter that does nothing. Bytecode is cached,
as after the first run of an installed package, under a temporary PYTHONPYCACHEPREFIX written by an
uncounted run, which also fills a temporary result cache (PBO_CACHE_DIR). Goals (issue 40), each
the p50 of a whole process: `pbo --version` <= 0.1 s, `pbo check` <= 0.3 s, configuration on <= 0.3 s.
Phases: the interpreter and the CLI's imports; the file's load and check; removing a dead run's
leftovers, the queues and the table; the plant and the RTPU processes, until the last is ready;
spawning each task (its init); turning the configuration on.
""",
        limits="""What is left at each floor (`python -X importtime`, shares of a process's imports;
the absolute times move with the machine's load, the shares hardly):
`pbo --version` imports only `pbo_runtime.objects.version` and reads one METADATA file: what is left
is the interpreter and `site` (about 1.1x the floor `python -c pass`); an editable install's finder
(pathlib, importlib.util), which a wheel does not have, is most of the rest.
`pbo --help` builds every verb's parser (argparse, the verb and command tables: about 2x the floor).
`pbo check FILE`, after a first check of the robot on this machine (its MuJoCo description and
Pinocchio inertia range kept in the result cache): numpy is about a third of its imports (the
ports, the model and the checker compute with it), rich's console about an eighth, the parser a
tenth, the checker's own modules and PyYAML most of the rest. The registry's entry points are
read from each installed distribution's `entry_points.txt` by `pbo_runtime.objects.distributions`,
without importing `importlib.metadata` (the email package and zipfile: more than the reading
itself). Within the check, compiling the checker's and PyYAML's regular expressions is a visible
share (the dataclasses' methods are read from the code kept per machine); the file checked itself
is a few tens of ms.
The line "the machine's first" is the same check with no result cache: it imports MuJoCo for the
plant's description and Pinocchio for the inertia range, and computes both. Below this floor
would take a checker without numpy, or printing without rich.
`pbo run`: the CLI imports numpy and what it shares with the children (the model, the table, the
queues, the clocks), freezes that heap (`gc.freeze()`: no collection in either process then walks
what they share, which would copy its pages) and forks the fork server from itself, before its
parser (`cli/main.py`). The methods `dataclasses` generates for the runtime's classes (about 300 in
the shared imports alone, one compile each) are compiled once per machine and kept beside the result
cache, so no process of the run compiles them again. The server forks the plant's middle process at
once. Then three processes share the two CPUs: the CLI builds its verb's parser, loads and checks
the file, hands the server the checked subsystem, imports the supervisor and makes the table (rich
it imports only for the summary, once the configuration is on, where its output is no terminal); the
server imports the RTPU's code and the module library, Pinocchio most of it (the demo's PID needs it
for its gravity feed-forward, and every RTPU holds the whole library so that a task spawned live
never imports between two cycles); the plant's middle process imports MuJoCo (and numpy's random
generators). Asked, the server's middle forks both RTPUs and the plant's middle forks the plant,
side by side; the plant compiles its model; each task's init runs; the server ends once the
configuration is on. Of the three, the server is the last to be warm (its imports are slowed by the
pages a forked process writes, which are copied): the phase "start the plant and the RTPUs" above is
mostly the CLI waiting for it. From the fork to the children's request both CPUs are busy, and
before the fork one is idle while the CLI imports what both need: the figure is the CPU time of
numpy, Pinocchio, MuJoCo, the check and the runtime's own imports, shared by two CPUs. What is left:
numpy and the shared runtime once, before the fork; Pinocchio and MuJoCo; the check; the copying
after the fork. Shorter would take less of that work: a library whose Pinocchio modules could be
imported between cycles without holding the GIL (it cannot), or a server kept warm between runs.
Read each figure against its floor: on a busy machine both grow alike.""",
    )
    with tempfile.TemporaryDirectory(prefix="pbo-bench-startup-") as tmp:
        folder = Path(tmp)
        file = demo_copy(folder)
        env = environment(folder / "pycache", folder / "results")
        time_run(file, folder, env)  # writes the bytecode cache and the result cache; not counted
        runs: list[dict[str, float]] = []
        fresh: list[dict[str, float]] = []
        floors: list[float] = []
        contenders = (lambda: runs.append(time_run(file, folder, env)),
                      lambda: fresh.append(time_run(file, folder, env, fork_server=False)),
                      lambda: floors.append(time_floor(env)))
        for index in range(rounds):
            for k in range(len(contenders)):
                contenders[(index + k) % len(contenders)]()
        answers: dict[str, list[float]] = {what: [] for what, _, _ in CLI_ANSWERS}
        for index in range(rounds):
            for k in range(len(CLI_ANSWERS)):
                what, arguments, over = CLI_ANSWERS[(index + k) % len(CLI_ANSWERS)]
                answers[what].append(time_cli(arguments, file, {**env, **over}))
    on = [marks["on"] for marks in runs]
    p50, worst = statistics.median(on), max(on)
    fresh_p50 = statistics.median(marks["on"] for marks in fresh)
    floor = statistics.median(floors)
    table = Table(["phase", "p50 ms", "max ms", "fresh interpreters: p50 ms", "max ms"], numeric=(1, 2, 3, 4),
                  caption=f"Where the time goes ({rounds} runs each; the children forked from the fork server, "
                          "or each a fresh interpreter, PBO_FORK_SERVER=0):")
    split = [segments(marks) for marks in runs]
    split_fresh = [segments(marks) for marks in fresh]
    for phase, what in PHASES:
        values, others = [s[phase] for s in split], [s[phase] for s in split_fresh]
        table.add(what, *(f"{f(v) * 1e3:.0f}" for v in (values, others) for f in (statistics.median, max)))
    table.add("**`pbo run` → configuration on**", f"**{p50 * 1e3:.0f}**", f"**{worst * 1e3:.0f}**",
              f"{fresh_p50 * 1e3:.0f}", f"{max(marks['on'] for marks in fresh) * 1e3:.0f}")
    table.add("floor: `python -c 'import numpy'`", f"{floor * 1e3:.0f}", f"{max(floors) * 1e3:.0f}", "", "")
    section.tables.append(table)
    cli = Table(["command", "p50 ms", "max ms", "p50 / floor", "goal", "verdict"], numeric=(1, 2, 3),
                caption=f"How long the CLI takes to answer ({rounds} rounds, the commands in turn, bytecode cached):")
    cli_floor = statistics.median(answers[CLI_FLOOR])
    for what, _, _ in CLI_ANSWERS:
        median = statistics.median(answers[what])
        goal = CLI_GOALS.get(what)
        cli.add(what, f"{median * 1e3:.0f}", f"{max(answers[what]) * 1e3:.0f}", fmt_ratio(ratio(median, cli_floor)),
                f"<= {goal * 1e3:.0f} ms" if goal else "", verdict(median, goal) if goal else "")
        if what != CLI_FLOOR and (value := ratio(median, cli_floor)) is not None:
            section.ratios[f"{what.strip('`')} p50 / floor"] = value
        if goal:
            section.targets.append(Target(f"{what} p50 / {goal:g} s", median / goal, 1.0,
                                          note=f"p50 {median:.3f} s, {fmt_ratio(ratio(median, cli_floor))} the floor "
                                               f"`python -c pass` of the same rounds ({cli_floor:.3f} s)"))
    cli.add("`pbo run` → configuration on (above)", f"{p50 * 1e3:.0f}", f"{worst * 1e3:.0f}", fmt_ratio(ratio(p50, cli_floor)),
            f"<= {GOAL * 1e3:.0f} ms", verdict(p50, GOAL))
    section.tables.append(cli)
    section.ratios["configuration on p50 / goal"] = p50 / GOAL
    for name, value in (("configuration on p50 / floor p50", ratio(p50, floor)),
                        ("configuration on p50, fork server / fresh interpreters", ratio(p50, fresh_p50))):
        if value is not None:
            section.ratios[name] = value
    section.notes.append(f"configuration on: p50 {p50:.3f} s, max {worst:.3f} s over {rounds} runs; "
                         f"goal <= {GOAL:g} s: {verdict(p50, GOAL)}; with fresh interpreters p50 "
                         f"{fresh_p50:.3f} s ({fmt_ratio(ratio(p50, fresh_p50))} of it with the fork server); "
                         f"the floor (an interpreter importing numpy) p50 {floor:.3f} s, "
                         f"the figure {fmt_ratio(ratio(p50, floor))} of it")
    section.targets.append(Target(f"`pbo run` → configuration on, p50 / {GOAL:g} s", p50 / GOAL, 1.0,
                                  note=f"p50 {p50:.3f} s, max {worst:.3f} s; {fmt_ratio(ratio(p50, floor))} the floor "
                                       f"`python -c 'import numpy'` of the same rounds ({floor:.3f} s)"))
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=12)
    args = parser.parse_args()
    print(run(args.rounds).text())


if __name__ == "__main__":
    main()
