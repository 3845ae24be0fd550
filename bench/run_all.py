"""Run every benchmark and write docs/performance.md from what they measured.

    python -m bench                 # everything, full counts (about 25 minutes); rewrites docs/performance.md
    python -m bench --quick         # everything, small counts (well under a minute); prints only
    python -m bench --only peers,scale --out /tmp/perf.md

Each benchmark is also a module of its own (`python -m bench.peers`, ...) printing its tables.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import (
    api_stream,
    check_scale,
    data_log,
    dora_peer,
    faults,
    helper_threads,
    hmi_latency,
    hmi_load,
    links,
    peers,
    placement,
    realtime,
    restart,
    robot_limits,
    ros2_bridge,
    scale,
    sim_speed,
    startup,
    svar_transfer,
    switching,
    verbs,
    wait,
)
from bench._common import REPO, Section, Table, machine_info, machine_pace

BENCHMARKS: dict[str, Callable[..., Section]] = {
    "svar_transfer": svar_transfer.run,
    "peers": peers.run,
    "scale": scale.run,
    "realtime": realtime.run,
    "wait": wait.run,
    "switching": switching.run,
    "verbs": verbs.run,
    "helper_threads": helper_threads.run,
    "check_scale": check_scale.run,
    "placement": placement.run,
    "links": links.section,
    "dora": dora_peer.run,
    "faults": faults.run,
    "restart": restart.run,
    "data_log": data_log.run,
    "api_stream": api_stream.run,
    "hmi_latency": hmi_latency.run,
    "hmi_load": hmi_load.run,
    "sim_speed": sim_speed.run,
    "startup": startup.run,
    "robot_limits": robot_limits.run,
    "ros2_bridge": ros2_bridge.run,
}

FULL: dict[str, dict[str, Any]] = {
    "svar_transfer": {"rounds": 21, "iterations": 20000, "table_variables": 1000},
    "peers": {"iterations": 10000, "seconds": 2.0, "warmup": 200, "rounds": 3},
    "scale": {"rounds": 15, "iterations": 2000, "rtpu_seconds": 1.5},
    "realtime": {"seconds": 240.0, "rtpus": (1, 2, 4), "rounds": 48, "other_seconds": 60.0, "other_rounds": 12},
    "wait": {"seconds": 1.5, "rounds": 4},
    "switching": {"switches": 1000, "interval": 0.02},
    "verbs": {"window": 0.6, "rounds": 2},
    "helper_threads": {"seconds": 5.0, "rounds": 5},
    "check_scale": {"sizes": (102, 1002, 10002), "repeat": 3},
    "placement": {"tasks": 102, "repeat": 200, "check_repeat": 5},
    "links": {},
    "dora": {"seconds": 5.0, "rounds": 3, "schedulers": ("fifo", "other")},
    "faults": {"stop_seconds": 2.0},
    "restart": {"kills": 20},
    "data_log": {"seconds": 10.0, "rounds": 6},
    "api_stream": {"seconds": 120.0, "rounds": 12},
    "hmi_latency": {"writes": 1000},
    "hmi_load": {"seconds": 120.0, "rounds": 12},
    "sim_speed": {"seconds": 10.0, "rounds": 3},
    "startup": {"rounds": 12},
    "robot_limits": {"cycles": 2000, "rounds": 10},
    "ros2_bridge": {"seconds": 10.0, "rounds": 6},
}

QUICK: dict[str, dict[str, Any]] = {
    "svar_transfer": {"rounds": 3, "iterations": 2000, "table_variables": 1000},
    "peers": {"iterations": 300, "seconds": 0.3, "warmup": 20, "rounds": 1},
    "scale": {"rounds": 2, "iterations": 500, "rtpu_seconds": 0.2},
    "realtime": {"seconds": 1.0, "rtpus": (1, 2, 4), "rounds": 1, "other_seconds": 1.0, "other_rounds": 1},
    "wait": {"seconds": 0.2, "rounds": 1},
    "switching": {"switches": 20, "interval": 0.02},
    "verbs": {"window": 0.4, "configs": verbs.QUICK_CONFIGS},
    "helper_threads": {"seconds": 1.0, "rounds": 1},
    "check_scale": {"sizes": (102, 1002, 10002), "repeat": 1},
    "placement": {"tasks": 102, "repeat": 20, "check_repeat": 1},
    "links": {"quick": True},
    "dora": {"seconds": 1.0, "rounds": 1, "schedulers": ("fifo",)},
    "faults": {"cases": ("controller_stop",), "stop_seconds": 0.5, "run_seconds": 2.0},
    "restart": {"kills": 2},
    "data_log": {"seconds": 2.0, "rounds": 1},
    "api_stream": {"seconds": 2.0, "rounds": 2},
    "hmi_latency": {"writes": 100},
    "hmi_load": {"seconds": 20.0, "rounds": 2},
    "sim_speed": {"seconds": 1.0, "rounds": 2, "goal_seconds": 5.0, "goal_runs": 1},
    "startup": {"rounds": 5},  # each figure a median of 5
    "robot_limits": {"cycles": 500, "rounds": 2},
    "ros2_bridge": {"seconds": 2.0, "rounds": 2},
}

DOC = Path(REPO) / "docs" / "performance.md"

def collect(counts: dict[str, dict[str, Any]], only: tuple[str, ...] = (), plot_path: str | None = None,
            echo: Callable[[str], None] | None = print) -> list[Section]:
    """Run the benchmarks named in `counts` (or `only` of them), printing each as it finishes."""
    sections = []
    for key, run in BENCHMARKS.items():
        if key not in counts or (only and key not in only):
            continue
        kwargs = dict(counts[key])
        if key == "scale" and plot_path:
            kwargs["plot_path"] = plot_path
        t0 = time.monotonic()
        before = machine_pace()
        section = run(**kwargs)
        section.pace = (before, machine_pace())
        if echo:
            echo(section.text() + f"\n({key}: {time.monotonic() - t0:.0f} s; the machine's pace before and after it: "
                 f"{section.pace[0] * 1e3:.1f} and {section.pace[1] * 1e3:.1f} ms)\n")
            sys.stdout.flush()
        sections.append(section)
    return sections


def render(sections: list[Section], info: dict[str, str], command: str, elapsed: float) -> str:
    """docs/performance.md: targets first, then each benchmark's method, tables and limits."""
    lines = [
        "# Performance",
        "",
        f"<!-- Generated by `{command}` from what it measured; edit bench/*.py, not this file. -->",
        "",
        "Every figure below was measured by one run of `make bench` (`.venv/bin/python -m bench`) on the",
        "machine described under [Machine](#machine). Each benchmark measures its baseline in the same",
        "run, interleaved with the contender where it can, and states its result as a ratio: read the",
        "ratios rather than the absolute values, and rerun on your machine rather than trust them.",
        "",
        "## Targets",
        "",
    ]
    targets = Table(["target (issue 6)", "measured", "limit", "verdict"], numeric=(1, 2))
    for s in sections:
        for t in s.targets:
            sign = ">=" if t.at_least else "<="
            verdict = {True: "met", False: "**not met**", None: f"no ratio{': ' + t.note if t.note else ''}"}[t.met]
            targets.add(t.what, "n/a" if t.value is None else f"{t.value:,.2f}x", f"{sign} {t.limit:g}x", verdict)
    lines += [targets.markdown() if targets.rows else "(no target was measured)", ""]
    lines += [
        "## Machine",
        "",
        *(f"- **{k}**: {v}" for k, v in info.items()),
        f"- **load average at the end**: {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
        f"- **run time of the benchmarks**: {elapsed:.0f} s",
        "",
        "This is a shared 2-vCPU KVM guest: other tenants' work runs beside the benchmarks and the",
        "hypervisor steals milliseconds now and then, so tails (p99, max) and overruns vary from run to",
        "run. That is why every comparison is a ratio against a baseline measured in the same run.",
        "",
        *_pace_lines(sections),
        "## How to reproduce",
        "",
        "```",
        "make bench                              # installs the `bench` extra, runs everything, rewrites this file",
        ".venv/bin/python -m bench --quick       # everything with small counts, well under a minute; prints only",
        ".venv/bin/python -m bench --only peers  # a subset (names: " + ", ".join(BENCHMARKS) + ")",
        "```",
        "",
        "Each benchmark also runs alone and prints its tables; the command is given in its section.",
        "The peers are the optional `bench` extra (`pip install -e '.[bench]'`: pyzmq, iceoryx2,",
        "eclipse-zenoh, dora-rs); a peer that is not installed is reported as such.",
        "",
    ]
    for s in sections:
        lines += [s.markdown()]
    return "\n".join(lines).rstrip() + "\n"


def _pace_lines(sections: list[Section]) -> list[str]:
    """How fast the machine was around each benchmark: a goal in seconds or in times real time
    (start-up, simulation speed) moves with it, where a ratio to a baseline of the same run does not."""
    paced = [s for s in sections if s.pace is not None]
    if not paced:
        return []
    fastest = min(min(s.pace) for s in paced if s.pace is not None)
    table = Table(["benchmark", "before, ms", "after, ms", "the slower of the two / the run's fastest"], numeric=(1, 2, 3))
    for s in paced:
        assert s.pace is not None
        table.add(s.key, f"{s.pace[0] * 1e3:.2f}", f"{s.pace[1] * 1e3:.2f}", f"{max(s.pace) / fastest:.2f}x")
    return [
        "The machine's pace through the run: a fixed single-thread workload (small numpy calls, Python",
        "arithmetic, a dict: the kind of work a cycle does), the fastest of 5, timed just before and just",
        "after each benchmark (`bench._common.machine_pace`). Read a figure judged against a goal rather",
        "than a baseline of the same run (simulation speed, start-up) beside the pace of its benchmark.",
        "",
        table.markdown(),
        "",
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small counts: everything in well under a minute")
    parser.add_argument("--only", default="", help=f"comma-separated subset of: {', '.join(BENCHMARKS)}")
    parser.add_argument("--out", default=None,
                        help="write the Markdown here (default: docs/performance.md for a full run of everything; "
                             "nothing for --quick or --only)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    only = tuple(k for k in args.only.split(",") if k)
    unknown = [k for k in only if k not in BENCHMARKS]
    if unknown:
        parser.error(f"unknown benchmark {', '.join(unknown)}; choose from: {', '.join(BENCHMARKS)}")
    out = args.out
    if out is None and not args.quick and not only:
        out = str(DOC)
    if args.no_write:
        out = None
    plot_path = str(Path(out).parent / "scale.png") if out else None
    info = machine_info()
    print("machine: " + "; ".join(f"{k}: {v}" for k, v in info.items()) + "\n")
    t0 = time.monotonic()
    sections = collect(QUICK if args.quick else FULL, only, plot_path)
    elapsed = time.monotonic() - t0
    if out:
        command = "python -m bench" + (" --quick" if args.quick else "") + (f" --only {args.only}" if only else "")
        Path(out).write_text(render(sections, info, command, elapsed))
        plotted = f" and {os.path.relpath(plot_path)}" if plot_path and Path(plot_path).exists() else ""
        print(f"wrote {os.path.relpath(out)}{plotted}")
    missed = [t for s in sections for t in s.targets if t.met is False]
    print(f"{sum(len(s.targets) for s in sections)} targets: {len(missed)} not met; {elapsed:.0f} s")
    return 0
