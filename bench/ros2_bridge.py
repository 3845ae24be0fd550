"""What the ROS 2 bridge costs the RTPUs it runs on: the demo arm with and without it, in paired rounds.

    pbo run configs/ros2_bridge.yaml --duration D --report FILE     (with: JointState at 100 Hz, a goal subscription)
    the same file less its two ROS 2 tasks                         (without)

With the bridge, a separate process (a Cyclone DDS participant, as a ROS 2 node) subscribes to
`/joint_states` for the whole run, so every message is really sent; it counts them. Each round
runs the two back to back in alternating order, on a DDS domain of its own; a round's ratio is
taken within the round, the verdict is the median. Figures from the run report: the missed
releases and overruns of the tasks both variants run (`robot`, `traj`, `pid`), the release jitter
(p99, max) of `pid` (1 kHz, on rtpu0 beside the bridge's tasks) and of `robot` (1 kHz, rtpu1), and
the cycle time of the bridge's `joint_states` task.

    python -m bench.ros2_bridge [--seconds 10] [--rounds 4]
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
from typing import Any

import yaml

from bench._common import REPO, Section, Table, Target, fmt_ratio, ratio, us

CONFIG = Path(REPO) / "configs" / "ros2_bridge.yaml"
VARIANTS = ("without", "with")
BRIDGE_TASKS = ("goal", "joint_states")
TASKS = ("pid", "robot")  # their jitter
COMMON = ("robot", "traj", "pid")  # the tasks both variants run: their missed releases and overruns


def variant_file(variant: str, folder: Path, index: int) -> Path:
    """The bridge's file under a subsystem name of its own; `without`: less its ROS 2 tasks."""
    config = yaml.safe_load(CONFIG.read_text())
    config["subsystem"] = f"bench_ros2_{os.getpid()}_{index}_{variant}"
    if variant == "without":
        for name in BRIDGE_TASKS:
            del config["tasks"][name]
        config["configurations"] = {name: [t for t in tasks if t not in BRIDGE_TASKS]
                                    for name, tasks in config["configurations"].items()}
    path = folder / f"{variant}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def listen(domain: int, seconds: float) -> None:
    """In the child: subscribe to /joint_states as a ROS 2 node for `seconds`; print how many came."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from pbo_runtime.links import ros2_messages as ros2

    participant = DomainParticipant(domain)
    reader = DataReader(participant, Topic(participant, "rt/joint_states", ros2.JointState, qos=ros2.ros2_qos()),
                        qos=ros2.ros2_qos())
    count, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        count += sum(isinstance(s, ros2.JointState) for s in reader.take(N=64))
        time.sleep(0.005)
    print(json.dumps({"count": count}))


def run_variant(variant: str, seconds: float, folder: Path, index: int) -> dict[str, Any]:
    """One `pbo run` of the variant (with a listening peer for `with`); the tasks' figures."""
    folder.mkdir(parents=True, exist_ok=True)
    report = folder / f"{variant}.json"
    domain = 1 + (os.getpid() + index) % 232
    environment = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    listener = None
    if variant == "with":
        listener = subprocess.Popen([sys.executable, "-m", "bench.ros2_bridge", "--listen", str(domain), "--seconds",
                                     f"{seconds + 30:g}"], cwd=REPO, stdout=subprocess.PIPE, text=True, env=environment)
    command = [sys.executable, "-m", "pbo_runtime.cli", "run", str(variant_file(variant, folder, index)), "--duration",
               f"{seconds:g}", "--report", str(report), "--no-live", "--out", str(folder / variant)]
    try:
        done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=seconds + 180, env=environment)
    finally:
        if listener is not None:
            listener.terminate()
            listener.wait()
    if not report.exists():
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:]
        raise RuntimeError(f"`pbo run` of {variant} failed (exit {done.returncode}): {' / '.join(tail)}")
    tasks = json.loads(report.read_text())["tasks"]
    figures = {f"{name} jitter_{q}": tasks[name][f"jitter_{q}"] for name in TASKS for q in ("p99", "max")}
    figures["missed"] = sum(tasks[name]["missed"] + tasks[name]["overruns"] for name in COMMON)
    figures["published"] = tasks["joint_states"]["cycles"] if variant == "with" else 0
    figures["bridge exec"] = (tasks["joint_states"]["exec_p99"], tasks["joint_states"]["exec_max"]) if variant == "with" else None
    return figures


def count_ratio(with_bridge: int, without: int) -> float:
    """Missed releases and overruns with the bridge against without it (at least one, so that none
    against none is 0x and some against none is a ratio, not a division by zero)."""
    return with_bridge / max(without, 1)


def run(seconds: float = 10.0, rounds: int = 4) -> Section:
    section = Section(
        key="ros2_bridge",
        title="The ROS 2 bridge's cost to its RTPUs: the demo arm with and without it",
        command=f"python -m bench.ros2_bridge --seconds {seconds:g} --rounds {rounds}",
        method=f"""
`configs/ros2_bridge.yaml` on the real clock for {seconds:g} s (`with`: JointState published at
100 Hz by a task on rtpu0, a goal subscription there too, and a separate Cyclone DDS process
subscribed to `/joint_states` all along), against the same file less its two ROS 2 tasks
(`without`). {rounds} rounds, each running the two back to back in alternating order; each ratio
is taken within a round, and the table gives the median over the rounds with their range. The
figures, from the run report: the missed releases and overruns of the tasks both run (`robot`,
`traj`, `pid`; a count with the bridge against at least one without), the p99 and largest release
jitter of `pid` (1 kHz, rtpu0, the bridge's RTPU) and `robot` (1 kHz, rtpu1), and the cycle time of
`joint_states` (its copy into the record its publisher process reads, and the wake).
""",
        limits="""The JointState publisher (encoding and DDS write) and the goal's subscriber are
processes of their own at SCHED_OTHER: no DDS thread runs in rtpu0. They, the listening process and
Cyclone DDS's threads run on the same two CPUs as the RTPUs and the plant: on this 2-core machine
shared with other work, round-to-round swings of the counts and the jitter can be larger than the
bridge's cost.""",
    )
    per_round: list[dict[str, dict[str, Any]]] = []
    failures: list[str] = []
    with tempfile.TemporaryDirectory() as folder:
        for index in range(rounds):
            order = VARIANTS if index % 2 == 0 else VARIANTS[::-1]
            round_figures: dict[str, dict[str, Any]] = {}
            for variant in order:
                try:
                    round_figures[variant] = run_variant(variant, seconds, Path(folder) / f"round{index}", index)
                except (RuntimeError, subprocess.TimeoutExpired) as exc:
                    failures.append(f"round {index + 1}, {variant}: {exc}")
            if len(round_figures) == len(VARIANTS):
                per_round.append(round_figures)
    figures = Table(["variant", "missed + overruns (sum)", "pid jitter p99 / max, µs (median)",
                     "robot jitter p99 / max, µs (median)", "joint_states cycle p99 / max, µs (median)",
                     "JointStates published (sum)"],
                    numeric=(1, 2, 3, 4, 5), caption=f"{len(per_round)} rounds of {seconds:g} s each; missed releases and "
                    f"overruns of {', '.join(COMMON)}:")
    for variant in VARIANTS:
        runs = [r[variant] for r in per_round]
        if runs:
            jitter = [f"{us(statistics.median(r[f'{name} jitter_p99'] for r in runs))} / "
                      f"{us(statistics.median(r[f'{name} jitter_max'] for r in runs))}" for name in TASKS]
            bridge = (f"{us(statistics.median(r['bridge exec'][0] for r in runs))} / "
                      f"{us(statistics.median(r['bridge exec'][1] for r in runs))}" if variant == "with" else "-")
            figures.add(variant, sum(r["missed"] for r in runs), *jitter, bridge, f"{sum(r['published'] for r in runs):,}")
    section.tables.append(figures)
    ratios = Table(["ratio with / without (within each round)", "median", "range"], numeric=(1, 2),
                   caption="Ratios taken within each round (missed + overruns: against at least one):")
    medians: dict[str, float | None] = {}
    for key, of_round in [("overrun_rate (missed + overruns)",
                           lambda r: count_ratio(r["with"]["missed"], r["without"]["missed"])),
                          *[(f"{name} jitter_p99", lambda r, k=f"{name} jitter_p99": ratio(r["with"][k], r["without"][k]))
                            for name in TASKS]]:
        values = [v for r in per_round if (v := of_round(r)) is not None]
        medians[key] = statistics.median(values) if values else None
        ratios.add(key, fmt_ratio(medians[key]), f"{fmt_ratio(min(values))} - {fmt_ratio(max(values))}" if values else "-")
    section.tables.append(ratios)
    section.ratios.update({f"with/without {key}": value for key, value in medians.items() if value is not None})
    for failure in failures:
        section.notes.append(f"failed: {failure}")
    section.targets.append(Target("ROS 2 bridge on: the RTPUs' missed releases and overruns against without it",
                                  medians.get("overrun_rate (missed + overruns)"), 1.05))
    section.targets.append(Target("ROS 2 bridge on: the RTPUs' p99 release jitter against without it (pid, rtpu0)",
                                  medians.get("pid jitter_p99"), 1.05))
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--listen", type=int, default=None, help=argparse.SUPPRESS)
    arguments = parser.parse_args()
    if arguments.listen is not None:
        listen(arguments.listen, arguments.seconds)
        return
    print(run(arguments.seconds, arguments.rounds).text())


if __name__ == "__main__":
    main()
