"""What a data logger costs the other tasks of its RTPU: none, `.npy` and MCAP, in paired rounds.

    pbo run bench/data_log.yaml --config {none,logged} --duration D --report FILE

One RTPU (pinned to CPU 0) hosts a trivial 1 kHz task, `watch`; in `logged` a 1 kHz logger of
four 6-vectors runs beside it, writing MCAP, or `.npy` in a copy of the file that differs only in
the logger's path. The three variants spawn the same tasks in the same order (in `none` the
logger stays OFF). Each round runs the three in a rotated order, back to back, so the machine's slow minutes
fall on all three alike; a round's ratio is taken within the round, the verdict is the median.

Figures for `watch`, from the run report: its release jitter and its execution time (p99), and
its overruns. The target is on the execution time: the p99 release jitter is a few microseconds
in every variant (the spin's precision), and ratios of such small figures swing with the machine.
The logger's cycle itself (a copy of 24 values into its chunk buffer) is the same in both formats,
so `mcap / npy` is the cost of encoding MCAP on the cycles of the RTPU's other tasks, which this
benchmark exists to watch.

    python -m bench.data_log [--seconds 10] [--rounds 6]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from bench._common import REPO, Section, Table, Target, fmt_ratio, ratio, us

CONFIG = "bench/data_log.yaml"
VARIANTS = ("none", "npy", "mcap")
FIGURES = ("jitter_p99", "exec_p99")


def variant_file(variant: str, folder: Path) -> tuple[str, str]:
    """The file and configuration a variant runs: the benchmark's file, or for `npy` a copy logging to log.npy."""
    if variant != "npy":
        return CONFIG, "none" if variant == "none" else "logged"
    text = (Path(REPO) / CONFIG).read_text()
    copy = folder / "data_log_npy.yaml"
    copy.write_text(text.replace("path: log.mcap}", "path: log.npy}"))
    return str(copy), "logged"


def run_variant(variant: str, seconds: float, folder: Path) -> dict[str, Any]:
    """One `pbo run` of the variant; the watch task's figures and the log's size."""
    folder.mkdir(parents=True, exist_ok=True)
    out, report = folder / variant, folder / f"{variant}.json"
    path, configuration = variant_file(variant, folder)
    command = [sys.executable, "-m", "pbo_runtime.cli", "run", path, "--config", configuration, "--duration", f"{seconds:g}",
               "--report", str(report), "--no-live", "--out", str(out)]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=seconds + 180)
    if done.returncode != 0 or not report.exists():
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:]
        raise RuntimeError(f"`pbo run` of {variant} failed (exit {done.returncode}): {' / '.join(tail)}")
    result = json.loads(report.read_text())
    watch = result["tasks"]["watch"]
    logger = result["tasks"]["log"]
    log = out / f"log.{variant}"
    return {"jitter_p99": watch["jitter_p99"], "exec_p99": watch["exec_p99"], "overruns": watch["overruns"],
            "cycles": watch["cycles"], "logged": logger.get("cycles", 0), "log_bytes": log.stat().st_size if log.exists() else 0}


def run(seconds: float = 10.0, rounds: int = 6) -> Section:
    section = Section(
        key="data_log",
        title="A data logger's cost to the other tasks of its RTPU: none, .npy and MCAP",
        command=f"python -m bench.data_log --seconds {seconds:g} --rounds {rounds}",
        method=f"""
`pbo run {CONFIG} --config none|logged --duration {seconds:g}`: one RTPU pinned to CPU 0 with a
trivial 1 kHz task (`watch`), alone (`none`, the logger spawned but off) or beside a 1 kHz data
logger of four 6-vectors writing MCAP (4,000 JSON messages a second, zstd chunks, encoded by the
logger's own process) or, in a copy of the file that differs only in the path, `.npy` (a copy per
chunk). The three variants spawn the same tasks in the same order. {rounds} rounds, each running
the three back to back in a rotated order; each ratio is taken within a round, and the table gives
the median over the rounds, with the rounds' range. The figures are `watch`'s release jitter and execution time, p99, from the run
report: what the logger does to a task it shares an RTPU with. The target is on the execution
time: the p99 release jitter is a few microseconds in every variant (the spin's precision), so
its ratios swing with the machine and are shown, not judged. This benchmark, run once on the code
before (MCAP encoded by a thread of the RTPU, until 2026-11-26; 2 rounds of 5 s), read 1.22x on
the execution time and 15.8x on the jitter.
""",
        limits="""The logger's own cycle runs on the RTPU's one thread, before or after
`watch` at each millisecond, whatever the format: that is the `npy / none` ratio. MCAP's encoding
is Python work (JSON, the `mcap` writer) done by a child process at SCHED_OTHER, niced, on the
RTPU's CPU: it runs in the time the executive leaves idle and never holds the RTPU's GIL. What is
left of its cost shows as `mcap / npy`: cache misses after the encoder ran, and the wake-ups of the
logger's writer thread.""",
    )
    per_round: list[dict[str, dict[str, Any]]] = []
    failures: list[str] = []
    with tempfile.TemporaryDirectory() as folder:
        for index in range(rounds):
            order = VARIANTS[index % 3:] + VARIANTS[:index % 3]
            round_figures: dict[str, dict[str, Any]] = {}
            for variant in order:
                try:
                    round_figures[variant] = run_variant(variant, seconds, Path(folder) / f"round{index}")
                except (RuntimeError, subprocess.TimeoutExpired) as exc:
                    failures.append(f"round {index + 1}, {variant}: {exc}")
            if len(round_figures) == len(VARIANTS):
                per_round.append(round_figures)
    figures = Table(["configuration", "watch jitter p99, µs (median)", "watch exec p99, µs (median)", "overruns (sum)",
                     "logger cycles (sum)", "log size (one run)"], numeric=(1, 2, 3, 4, 5),
                    caption=f"The trivial task's figures, {len(per_round)} rounds of {seconds:g} s each:")
    for variant in VARIANTS:
        runs = [r[variant] for r in per_round]
        if not runs:
            continue
        figures.add(variant, us(statistics.median(r["jitter_p99"] for r in runs)),
                    us(statistics.median(r["exec_p99"] for r in runs)),
                    sum(r["overruns"] for r in runs), f"{sum(r['logged'] for r in runs):,}",
                    f"{runs[-1]['log_bytes'] / 1024:,.0f} KiB" if runs[-1]["log_bytes"] else "-")
    section.tables.append(figures)
    ratios = Table(["ratio (within each round)", "jitter p99: median", "range", "exec p99: median", "range"],
                   numeric=(1, 2, 3, 4),
                   caption="Ratios of the trivial task's p99 figures, taken within each round:")
    medians: dict[str, float | None] = {}
    for over, under in (("npy", "none"), ("mcap", "none"), ("mcap", "npy")):
        cells: list[str] = []
        for figure in FIGURES:
            values = [v for r in per_round if (v := ratio(r[over][figure], r[under][figure])) is not None]
            median = statistics.median(values) if values else None
            medians[f"{over}/{under} {figure}"] = median
            cells += [fmt_ratio(median), f"{fmt_ratio(min(values))} - {fmt_ratio(max(values))}" if values else "-"]
        ratios.add(f"{over} / {under}", *cells)
    section.tables.append(ratios)
    section.ratios.update({key: value for key, value in medians.items() if value is not None})
    for failure in failures:
        section.notes.append(f"failed: {failure}")
    section.targets.append(Target("MCAP logger beside a 1 kHz task: the task's p99 execution time against beside a .npy logger",
                                  medians.get("mcap/npy exec_p99"), 1.10))
    return section


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=6)
    args = parser.parse_args()
    print(run(args.seconds, args.rounds).text())


if __name__ == "__main__":
    main()
