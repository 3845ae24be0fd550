"""What every benchmark shares: its result as data, tables as Markdown, the machine it ran on.

A benchmark returns a `Section`: tables (cells already formatted), the targets it checks (a
ratio against a baseline measured in the same run), the ratios it computed, and the prose that
explains its method and what limits it. The runner prints sections and writes them into
`docs/performance.md`; a test checks their structure, never their timing values.
"""

from __future__ import annotations

import datetime
import math
import os
import platform
import subprocess
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib import metadata

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@dataclass
class Table:
    """A Markdown table: headers, formatted rows, and which columns are numbers (right-aligned)."""

    headers: list[str]
    rows: list[list[str]] = field(default_factory=list)
    numeric: tuple[int, ...] = ()  # column indices aligned right
    caption: str = ""

    def add(self, *cells: object) -> None:
        if len(cells) != len(self.headers):
            raise AssertionError(f"row has {len(cells)} cells, table has {len(self.headers)} columns: {cells}")
        self.rows.append([str(c) for c in cells])

    def markdown(self) -> str:
        align = ["---:" if i in self.numeric else "---" for i in range(len(self.headers))]
        lines = [f"| {' | '.join(self.headers)} |", f"|{'|'.join(align)}|"]
        lines += [f"| {' | '.join(r)} |" for r in self.rows]
        return "\n".join(lines)


@dataclass
class Target:
    """A ratio from one run against the issue's limit: `value <= limit` (or `>=` when `at_least`)."""

    what: str
    value: float | None  # None: could not be measured (say why in `note`)
    limit: float
    at_least: bool = False
    note: str = ""

    @property
    def met(self) -> bool | None:
        if self.value is None or not math.isfinite(self.value):
            return None
        return self.value >= self.limit if self.at_least else self.value <= self.limit

    def line(self) -> str:
        sign = ">=" if self.at_least else "<="
        if self.met is None:
            return f"{self.what}: n/a (target {sign} {self.limit:g}x) -> no ratio{': ' + self.note if self.note else ''}"
        verdict = "met" if self.met else "NOT met"
        extra = f" ({self.note})" if self.note else ""
        return f"{self.what}: {self.value:.2f}x (target {sign} {self.limit:g}x) -> {verdict}{extra}"


@dataclass
class Section:
    """One benchmark's outcome, ready to print and to write into docs/performance.md."""

    key: str
    title: str
    command: str  # how to run it alone
    method: str  # Markdown: what is measured and how (static prose)
    limits: str = ""  # Markdown: what limits the figures (static prose)
    tables: list[Table] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # generated findings, one line each
    targets: list[Target] = field(default_factory=list)
    ratios: dict[str, float] = field(default_factory=dict)  # every ratio computed: name -> value
    figure: str = ""  # a plot written by the benchmark, relative to docs/
    pace: tuple[float, float] | None = None  # `machine_pace` just before and just after it ran (the runner's)

    def text(self) -> str:
        """What the benchmark prints when run alone."""
        parts = [f"## {self.title}", ""]
        for t in self.tables:
            if t.caption:
                parts += [t.caption, ""]
            parts += [t.markdown(), ""]
        if self.notes:
            parts += [*self.notes, ""]
        parts += [t.line() for t in self.targets]
        return "\n".join(parts).rstrip() + "\n"

    def markdown(self) -> str:
        parts = [f"## {self.title}", "", f"`{self.command}`", "", self.method.strip(), ""]
        for t in self.tables:
            if t.caption:
                parts += [t.caption, ""]
            parts += [t.markdown(), ""]
        if self.figure:
            parts += [f"![{self.title}]({self.figure})", ""]
        if self.notes:
            parts += [f"- {n}" for n in self.notes] + [""]
        if self.targets:
            parts += ["Targets (issue 6), ratios from this run:", ""]
            parts += [f"- {t.line()}" for t in self.targets] + [""]
        if self.limits:
            parts += ["**What limits it.** " + self.limits.strip(), ""]
        return "\n".join(parts)


def us(seconds_or_ns: float, ns: bool = False) -> str:
    """Microseconds with sensible precision."""
    value = seconds_or_ns / 1e3 if ns else seconds_or_ns * 1e6
    if value >= 100:
        return f"{value:,.0f}"
    if value >= 10:
        return f"{value:.1f}"
    return f"{value:.2f}"


def ratio(numerator: float, denominator: float) -> float | None:
    """numerator / denominator, or None when it is not a finite positive number."""
    if not (denominator > 0 and numerator >= 0) or not math.isfinite(numerator) or not math.isfinite(denominator):
        return None
    value = numerator / denominator
    return value if value > 0 and math.isfinite(value) else None


def fmt_ratio(value: float | None) -> str:
    if value is None:
        return "n/a"
    return f"{value:,.0f}x" if value >= 100 else f"{value:.2f}x"


def percentiles(samples: Iterable[float] | np.ndarray, qs: tuple[float, ...] = (50, 99)) -> list[float]:
    a = np.asarray(samples, dtype=float)
    return [float(np.percentile(a, q)) for q in qs] if a.size else [math.nan] * len(qs)


def package_version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def hypervisor() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=5).stdout
    except (OSError, subprocess.SubprocessError):
        return ""
    for line in out.splitlines():
        if line.startswith("Hypervisor vendor:"):
            return line.split(":", 1)[1].strip()
    return ""


def machine_pace(repeat: int = 5) -> float:
    """Seconds of a fixed single-thread workload, the fastest of `repeat`: the kind of work a cycle does
    (small numpy calls, Python arithmetic, a dict). Timed before and after each benchmark, it says how
    fast the machine was then: a shared machine's speed drifts, and a figure judged against a goal
    (not against a baseline of the same run) moves with it."""
    state, step, out = np.zeros(6), np.full(6, 1e-3), np.empty(6)

    def once() -> float:
        started = time.perf_counter()
        seen: dict[int, float] = {}
        total = 0.0
        for i in range(3000):
            np.add(state, step, out)
            np.multiply(out, 0.5, state)
            total += math.sqrt(i) * 0.5
            seen[i & 255] = total
        return time.perf_counter() - started

    once()  # not counted: it warms what the timed runs use
    return min(once() for _ in range(repeat))


def machine_info() -> dict[str, str]:
    """The facts a reader needs to compare figures across machines."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    virt = hypervisor()
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": f"{cpu_model()}, {os.cpu_count()} CPUs" + (f" ({virt} guest)" if virt else ""),
        "kernel": f"{platform.system()} {platform.release()}",
        "python": f"{platform.python_implementation()} {platform.python_version()}",
        "numpy": np.__version__,
        "peers": ", ".join(f"{p} {package_version(p)}" for p in ("pyzmq", "iceoryx2", "eclipse-zenoh", "dora-rs")),
        "load average at start": " ".join(f"{x:.2f}" for x in load),
        "user": "root" if os.geteuid() == 0 else "not root (SCHED_FIFO needs CAP_SYS_NICE)",
    }
