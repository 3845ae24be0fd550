"""The machine's own latency, beside a benchmark: when did it hold a CPU from the highest priority?

One probe process per CPU, pinned to it at SCHED_FIFO 99 (above every RTPU and the plant), wakes
every millisecond and records each wake-up later than its sleep by more than a threshold: a gap
in which only the kernel or, on a virtual machine, the hypervisor ran that CPU. A hold of a
critical task that begins during such a gap is the machine's doing, whatever the run did then;
benchmarks report those apart (as cyclictest measures a platform's latency apart from the
application). Where SCHED_FIFO is refused the probe runs at SCHED_OTHER, and its gaps are only
other processes taking the CPU: `realtime` is then False and no hold is blamed on the machine.

    python -m bench.platform_probe [--seconds 10]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from types import FrameType, TracebackType

PROBE_PRIORITY = 99
WAKE_EVERY = 0.001  # s: the probe's sleep; its own cost is a few microseconds a wake-up
GAP_BEYOND = 0.0005  # s: a wake-up this much later than its sleep is a gap


@dataclass(frozen=True)
class Gap:
    cpu: int
    start: float  # CLOCK_MONOTONIC, s: the probe's last wake-up before the gap
    length: float  # s: from that wake-up to the next, less the sleep asked


@dataclass
class Gaps:
    gaps: list[Gap] = field(default_factory=list)
    realtime: bool = False  # every probe ran at SCHED_FIFO 99 (else gaps say nothing about the machine)
    seconds: float = 0.0

    def during(self, start: float, end: float) -> Gap | None:
        """A gap that overlaps [start, end] (the longest), or None; none while the probes were not real-time."""
        if not self.realtime:
            return None
        found = [g for g in self.gaps if g.start <= end and g.start + g.length + WAKE_EVERY >= start]
        return max(found, key=lambda g: g.length, default=None)

    def summary(self) -> str:
        if not self.gaps:
            return f"no gap over {GAP_BEYOND * 1e3:g} ms in {self.seconds:.0f} s"
        longest = max(self.gaps, key=lambda g: g.length)
        return (f"{len(self.gaps)} gaps over {GAP_BEYOND * 1e3:g} ms in {self.seconds:.0f} s, the longest "
                f"{longest.length * 1e3:.2f} ms (CPU {longest.cpu})")


class PlatformProbe:
    """`with PlatformProbe() as probe: ...`, then `probe.gaps`: the machine's gaps while the block ran."""

    def __init__(self) -> None:
        self.processes: list[subprocess.Popen[str]] = []
        self.gaps = Gaps()
        self.started = 0.0

    def __enter__(self) -> PlatformProbe:
        for cpu in sorted(os.sched_getaffinity(0)):
            self.processes.append(subprocess.Popen([sys.executable, "-m", "bench.platform_probe", "--cpu", str(cpu)],
                                                   stdout=subprocess.PIPE, text=True))
        for process in self.processes:  # each says when it probes: a gap before that is not seen
            assert process.stdout is not None
            process.stdout.readline()
        self.started = time.monotonic()
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None, trace: TracebackType | None) -> None:
        realtime = bool(self.processes)
        for process in self.processes:
            process.send_signal(signal.SIGTERM)
        for process in self.processes:
            try:
                out, _ = process.communicate(timeout=10)
                found = json.loads(out or "{}")
            except (subprocess.TimeoutExpired, ValueError):
                process.kill()
                process.communicate()
                found = {}
            realtime = realtime and bool(found.get("realtime"))
            self.gaps.gaps += [Gap(found["cpu"], start, length) for start, length in found.get("gaps", [])]
        self.gaps.realtime = realtime
        self.gaps.seconds = time.monotonic() - self.started


def probe(cpu: int) -> None:
    """Wake every WAKE_EVERY on `cpu` until SIGTERM; print the gaps as JSON."""
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PROBE_PRIORITY))
        realtime = True
    except OSError:
        realtime = False
    stopping = []

    def stop(signum: int, frame: FrameType | None) -> None:
        stopping.append(signum)

    signal.signal(signal.SIGTERM, stop)
    print("probing", flush=True)
    gaps: list[tuple[float, float]] = []
    last = time.monotonic()
    while not stopping:
        time.sleep(WAKE_EVERY)
        now = time.monotonic()
        late = now - last - WAKE_EVERY
        if late > GAP_BEYOND:
            gaps.append((last, late))
        last = now
    print(json.dumps({"cpu": cpu, "realtime": realtime, "gaps": gaps}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cpu", type=int, default=None, help="(internal) be the probe of this CPU")
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    if args.cpu is not None:
        probe(args.cpu)
        return
    with PlatformProbe() as running:
        time.sleep(args.seconds)
    gaps = running.gaps
    print(("SCHED_FIFO 99" if gaps.realtime else "SCHED_OTHER (SCHED_FIFO refused)") + ": " + gaps.summary())
    for gap in sorted(gaps.gaps, key=lambda g: -g.length)[:10]:
        print(f"  CPU {gap.cpu}: {gap.length * 1e3:.2f} ms at {gap.start - running.started:.3f} s")


if __name__ == "__main__":
    main()
