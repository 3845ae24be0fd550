"""Who held the CPU at each overrun of a run: `pbo run` under the Linux scheduler's trace.

    sudo .venv/bin/python tools/cpu_trace.py configs/pid_joint.yaml --duration 5 [--keep trace.txt]

The run summary tells a late release (the machine kept the RTPU from running) from a long cycle
(the module itself). This names the machine's part: it records every context switch and
wake-up (tracefs: sched_switch and sched_wakeup, timed on CLOCK_MONOTONIC, the clock the
executive releases on) while `pbo run FILE --report` runs, then, for each overrun the report
kept (the last 8 per task), says when its RTPU was woken and lists what ran on each CPU from the
release to the cycle's end. The RTPU's wait ends its spin (0.2 ms) before the release: woken
later than that, its timer fired late, and nothing inside the machine held it (on a VM: the
host did not run that vCPU); woken on time but started late, something held its CPU. On the
2-vCPU VM this was written on, they were foreign threads taking a CPU for 1-2 ms: the
kernel's memory monitor (kdamond), compaction (kcompactd), the sandbox's agent.

Linux only, as root (tracefs is mounted here if it is not). It changes the trace settings for
the run and puts them back after.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import contextlib
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

TRACEFS = Path("/sys/kernel/tracing")
EVENTS = "sched:sched_switch\nsched:sched_wakeup\n"
BUFFER_KB = 65536  # per CPU; a 1 kHz RTPU makes about 2,000 events a second
IDLE = "idle"
WAKE_WINDOW = 0.0005  # seconds before a release in which an RTPU's wake-up is looked for (its spin is 0.2 ms)

_SWITCH = re.compile(r"\[(\d+)\]\s.*?\s([\d.]+): sched_switch: .*?prev_pid=(\d+) .*?prev_state=(\S+) ==> .*?next_pid=(\d+)")
_WAKEUP = re.compile(r"\s([\d.]+): sched_wakeup: .*?pid=(\d+) .*?target_cpu=(\d+)")


class TraceUnavailable(Exception):
    """The scheduler's trace cannot be used here (not Linux, not root, no tracefs)."""


@dataclass(frozen=True)
class Switch:
    """One context switch: on `cpu` at `time`, `prev` left (its state: R = preempted) and `next` came on."""

    cpu: int
    time: float
    prev: int
    prev_state: str
    next: int


def parse_switches(lines: list[str]) -> list[Switch]:
    """The sched_switch events of a tracefs `trace` text, in time order."""
    switches = []
    for line in lines:
        match = _SWITCH.search(line)
        if match:
            cpu, when, prev, state, following = match.groups()
            switches.append(Switch(int(cpu), float(when), int(prev), state, int(following)))
    switches.sort(key=lambda s: s.time)
    return switches


@dataclass(frozen=True)
class Wakeup:
    """One wake-up: at `time`, `pid` was made runnable, to run on `cpu`."""

    cpu: int
    time: float
    pid: int


def parse_wakeups(lines: list[str]) -> list[Wakeup]:
    """The sched_wakeup events of a tracefs `trace` text, in time order."""
    wakeups = []
    for line in lines:
        match = _WAKEUP.search(line)
        if match:
            when, pid, cpu = match.groups()
            wakeups.append(Wakeup(int(cpu), float(when), int(pid)))
    wakeups.sort(key=lambda w: w.time)
    return wakeups


def occupancy(switches: list[Switch], wakeups: Sequence[Wakeup] = ()) -> dict[int, list[tuple[float, float, int]]]:
    """Per CPU, who ran when: (start, end, pid) from one switch to the next (pid 0 is the idle task).

    Some kernels do not trace every switch: on the 2-vCPU VM this was written on, the switch out
    of the idle task was never traced on CPU 1 (and always on CPU 0). A task then leaves a CPU it
    was never seen to enter; it ran there from its last wake-up to that CPU (or, if none was
    traced, since the switch before), and the CPU idled until then.
    """
    woken: dict[tuple[int, int], list[float]] = collections.defaultdict(list)
    for w in wakeups:
        woken[w.pid, w.cpu].append(w.time)
    spans: dict[int, list[tuple[float, float, int]]] = collections.defaultdict(list)
    running: dict[int, tuple[int, float]] = {}
    for s in switches:
        if s.cpu in running:
            pid, since = running[s.cpu]
            if pid != s.prev:  # the switch into `prev` was not traced
                times = woken.get((s.prev, s.cpu), [])
                last = bisect.bisect_right(times, s.time) - 1  # its last wake-up to this CPU before it left
                entered = times[last] if last >= 0 and times[last] >= since else since
                if entered > since:
                    spans[s.cpu].append((since, entered, pid))
                pid, since = s.prev, entered
            spans[s.cpu].append((since, s.time, pid))
        running[s.cpu] = (s.next, s.time)
    return spans


def holders(spans: dict[int, list[tuple[float, float, int]]], start: float, end: float) -> dict[int, dict[int, float]]:
    """Per CPU, the seconds each pid ran within [start, end]."""
    held: dict[int, dict[int, float]] = {}
    for cpu, runs in spans.items():
        on_cpu: dict[int, float] = collections.defaultdict(float)
        for a, b, pid in runs:
            if b > start and a < end:
                on_cpu[pid] += min(b, end) - max(a, start)
        held[cpu] = dict(on_cpu)
    return held


class ProcessNames:
    """Names pids and thread ids while the run lives (a trace knows only numbers): a thread sampling /proc."""

    def __init__(self, interval: float = 0.2) -> None:
        self.names: dict[int, str] = {0: IDLE}
        self.interval = interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def __enter__(self) -> ProcessNames:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.sample_once()

    def _sample(self) -> None:
        while not self._stop.wait(self.interval):
            self.sample_once()

    def sample_once(self) -> None:
        for entry in os.listdir("/proc"):
            if not entry.isdigit() or int(entry) in self.names:
                continue
            try:
                process = _describe(Path("/proc") / entry)
                for task in os.listdir(f"/proc/{entry}/task"):
                    comm = Path(f"/proc/{entry}/task/{task}/comm").read_text().strip()
                    self.names.setdefault(int(task), process if task == entry else f"{process} / thread {comm}")
            except OSError:
                continue  # gone meanwhile

    def name(self, pid: int) -> str:
        return self.names.get(pid, f"pid {pid}")


def _describe(proc: Path) -> str:
    """A process as a reader knows it: an RTPU or the plant of a run, a kernel thread, or its command."""
    argv = (proc / "cmdline").read_bytes().split(b"\0")
    words = [a.decode(errors="replace") for a in argv if a]
    if not words:
        return f"[{(proc / 'comm').read_text().strip()}]"  # a kernel thread
    if "rtpu" in words and "--rtpu" in words:
        return f"RTPU {words[words.index('--rtpu') + 1]}"
    if "pbo_runtime.supervisor.plant_host" in words:
        return "plant"
    if "run" in words and ("pbo_runtime.cli" in words or any(w.endswith("/pbo") or w == "pbo" for w in words[:2])):
        return "pbo run (job control)"
    return " ".join(Path(words[0]).name if i == 0 else w for i, w in enumerate(words))[:60]


class SchedulerTrace:
    """sched_switch and sched_wakeup on CLOCK_MONOTONIC for the `with` block; the settings are put back after."""

    def __init__(self, tracefs: Path = TRACEFS) -> None:
        self.tracefs = tracefs
        self.saved: dict[str, str] = {}
        self.lines: list[str] = []
        self.mounted_here = False  # unmounted again on exit, so the machine is left as it was

    def __enter__(self) -> SchedulerTrace:
        if not sys.platform.startswith("linux"):
            raise TraceUnavailable("the scheduler trace is Linux's (tracefs)")
        if not (self.tracefs / "trace").exists() and self.tracefs == TRACEFS:
            mounted = subprocess.run(["mount", "-t", "tracefs", "nodev", str(self.tracefs)], capture_output=True)
            self.mounted_here = mounted.returncode == 0
        if not (self.tracefs / "trace").exists():
            raise TraceUnavailable(f"no tracefs at {self.tracefs}: mount it (mount -t tracefs nodev {self.tracefs}) as root")
        try:
            for name in ("trace_clock", "buffer_size_kb", "set_event", "tracing_on"):
                text = (self.tracefs / name).read_text()
                if name == "trace_clock":  # "local global ... [mono] ...": the one in brackets is in use
                    text = re.search(r"\[(\w+)\]", text).group(1)  # type: ignore[union-attr]
                elif name == "buffer_size_kb":  # "7 (expanded: 1408)" before first use
                    text = re.match(r"\d+", text).group(0)  # type: ignore[union-attr]
                self.saved[name] = text
            self._write("tracing_on", "0")
            self._write("trace_clock", "mono")
            self._write("buffer_size_kb", str(BUFFER_KB))
            self._write("trace", "")
            self._write("set_event", EVENTS)
            self._write("tracing_on", "1")
        except (OSError, AttributeError) as exc:
            self._restore()
            raise TraceUnavailable(f"cannot set up the trace in {self.tracefs} ({exc}); run as root") from exc
        return self

    def __exit__(self, *_exc: object) -> None:
        try:
            self._write("tracing_on", "0")
            self.lines = (self.tracefs / "trace").read_text().splitlines()
        finally:
            self._restore()

    def _restore(self) -> None:
        for name in ("set_event", "trace_clock", "buffer_size_kb", "tracing_on"):
            if name in self.saved:
                with contextlib.suppress(OSError):
                    self._write(name, self.saved[name])
        with contextlib.suppress(OSError):
            self._write("trace", "")
        if self.mounted_here:
            subprocess.run(["umount", str(self.tracefs)], capture_output=True)
            self.mounted_here = False

    def _write(self, name: str, value: str) -> None:
        (self.tracefs / name).write_text(value)


def explain(report: dict, switches: list[Switch], names: ProcessNames, wakeups: Sequence[Wakeup] = ()) -> list[dict]:
    """Per overrun the report kept: when, how late, how long it ran, when its RTPU was woken
    (seconds from the release), and who held each CPU meanwhile (seconds)."""
    origin = report.get("started_monotonic") or 0.0
    if not origin:
        raise TraceUnavailable("the run report has no started_monotonic (a simulated-clock run has no overruns to explain)")
    spans = occupancy(switches, wakeups)
    pids = {name: pid for pid, name in names.names.items()}
    woken_at: dict[int | None, list[float]] = collections.defaultdict(list)
    for w in wakeups:  # in time order
        woken_at[w.pid].append(w.time)
    rows = []
    for task, stats in sorted(report["tasks"].items()):
        rtpu_pid = pids.get(f"RTPU {stats.get('rtpu', '?')}")
        for at, late, took in stats.get("last_overruns", []):
            release = origin + at
            held = holders(spans, release, release + late + took)
            # its wait ends `spin` before the release; a wake-up after that is a timer that fired late
            times = woken_at.get(rtpu_pid, [])
            first, last = bisect.bisect_left(times, release - WAKE_WINDOW), bisect.bisect_right(times, release + late)
            woken = [t - release for t in times[first:last]]
            rows.append({"task": task, "rtpu": stats.get("rtpu", "?"), "at": at, "late": late, "took": took, "woken": woken,
                         "cpus": {cpu: {names.name(pid): seconds for pid, seconds in sorted(h.items(), key=lambda kv: -kv[1])}
                                  for cpu, h in sorted(held.items())}})
    return rows


def render(rows: list[dict], report: dict) -> str:
    """The overruns, oldest first, each with its CPUs' holders; then who held the CPUs across all of them."""
    total_overruns = sum(t.get("overruns", 0) for t in report["tasks"].values())
    if not rows:
        return f"no overrun in {report.get('duration', 0):.1f} s ({total_overruns} counted)"
    lines = [f"{len(rows)} overruns explained (the report keeps the last 8 per task; {total_overruns} counted):"]
    across: dict[str, float] = collections.defaultdict(float)
    for row in sorted(rows, key=lambda r: r["at"]):
        woken = row.get("woken", [])
        wake = (f"; its RTPU was woken at {', '.join(f'{w * 1e3:+.2f}' for w in woken)} ms from the release" if woken
                else "; no wake-up of its RTPU traced from 0.5 ms before the release (it was on a CPU, or waiting for one)")
        lines.append(f"  {row['task']} ({row['rtpu']}) at {row['at']:.3f} s: started {row['late'] * 1e3:.2f} ms late, "
                     f"ran {row['took'] * 1e3:.2f} ms{wake}")
        for cpu, held in row["cpus"].items():
            shown = ", ".join(f"{name} {seconds * 1e3:.2f}" for name, seconds in list(held.items())[:4]) or "nothing recorded"
            lines.append(f"      CPU {cpu} (ms): {shown}")
            for name, seconds in held.items():
                if name != IDLE and not name.startswith("RTPU"):
                    across[name] += seconds
    lines.append(
        "Besides the RTPUs, across these overruns (ms): "
        + (", ".join(f"{name} {s * 1e3:.2f}" for name, s in sorted(across.items(), key=lambda kv: -kv[1])[:6]) or "nobody")
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("file", help="the subsystem's YAML file")
    parser.add_argument("--duration", type=float, default=5.0, help="seconds of run (default 5)")
    parser.add_argument("--keep", type=Path, help="also write the raw trace here")
    parser.add_argument("--fifo", action=argparse.BooleanOptionalAction, default=None,
                        help="pass --fifo or --no-fifo to pbo run (default: its own, SCHED_FIFO where allowed)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        report_path = Path(folder) / "report.json"
        command = [sys.executable, "-m", "pbo_runtime.cli", "run", args.file, "--duration", f"{args.duration:g}",
                   "--report", str(report_path), "--no-live"]
        if args.fifo is not None:
            command.append("--fifo" if args.fifo else "--no-fifo")
        try:
            with ProcessNames() as names, SchedulerTrace() as trace:
                done = subprocess.run(command, capture_output=True, text=True)
        except TraceUnavailable as exc:
            print(f"cpu_trace: {exc}", file=sys.stderr)
            return 2
        if not report_path.exists():
            print(f"cpu_trace: pbo run wrote no report (exit {done.returncode}):\n{done.stderr.strip()}", file=sys.stderr)
            return done.returncode or 2
        report = json.loads(report_path.read_text())
    if args.keep:
        args.keep.write_text("\n".join(trace.lines) + "\n")
    try:
        rows = explain(report, parse_switches(trace.lines), names, parse_wakeups(trace.lines))
    except TraceUnavailable as exc:
        print(f"cpu_trace: {exc}", file=sys.stderr)
        return 2
    print(render(rows, report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
