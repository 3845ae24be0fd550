"""Bus utilisation beside a run: measured loads, combined modules' saving, and the report's forms.

The prediction, TR eq. 1-2, is `config.bus_model` (with it the checker refuses a configuration
over the bandwidth). Here a run's figures are set beside it: `measured` from a run's report,
`measured_live` from a running subsystem's status. Combined modules (TR §4.5) run several objects
as one task with one local table: the group runs at its fastest member's period, reads each
outside variable once, and keeps variables that only link members local; `combined_saving` shows
what that would save on the bus. `as_table`, `as_json`, `as_csv` and `plot` are what `pbo bus`,
the API and the HMI's monitor show.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pbo_runtime.config.bus_model import (
    LOCKS_PER_CYCLE,
    PER_CYCLE_IN,
    PER_CYCLE_OUT,
    BusModelError,
    BusReport,
    TaskLoad,
    bus_report,
    interval_of,
    members_of,
    predict,
    task_load,
    transfer_bytes,
)
from pbo_runtime.config.model import PortBinding, Subsystem, TaskSpec
from pbo_runtime.objects.ports import PortKind

if TYPE_CHECKING:
    from rich.table import Table

__all__ = ["as_csv", "as_json", "as_table", "combined_saving", "describe_saving", "measured", "measured_live", "plot"]


def measured(subsystem: Subsystem, report_json: Mapping[str, Any], configuration: str | None = None) -> BusReport:
    """Z_j as a run saw it: cycles x (bytes per cycle + 2Δ) / duration, for every task of the run's configuration.

    `report_json` is what `pbo run --report` writes (RunResult.to_json): its `duration`, and per
    task `cycles` and `bytes_moved_per_cycle` (what the table really moved per cycle: the data,
    each variable's writer word and the task's status block; older reports: `bytes_per_cycle`). A task the
    report does not list ran no cycle. `period` of a measured load is the mean interval the run
    saw (duration / cycles; inf for a task that never ran).
    """
    configuration = configuration or report_json.get("configuration") or next(iter(subsystem.configurations), "")
    names = members_of(subsystem, configuration)
    duration = float(report_json.get("duration") or 0.0)
    if not duration > 0:
        raise BusModelError(f"the run report of '{configuration}' has duration {duration!r}: no rate can be measured")
    rows = report_json.get("tasks") or {}
    lock = LOCKS_PER_CYCLE * subsystem.bus.lock_overhead
    loads = []
    for name in names:
        row = rows.get(name) or {}
        spec = subsystem.tasks[name]
        predicted = task_load(subsystem, spec)
        cycles = int(row.get("cycles") or 0)
        # What the table really moved per cycle (data + writer words + status block) where the
        # run reports it; otherwise the data alone.
        moved = row.get("bytes_moved_per_cycle", row.get("bytes_per_cycle"))
        data = row.get("bytes_per_cycle")
        predicted_bytes = (predicted.bytes_in or 0) + (predicted.bytes_out or 0)  # a prediction always splits them
        moved = float(moved) if moved is not None else float(predicted_bytes)
        bytes_in: int | None
        bytes_out: int | None
        if "bytes_in" in row and "bytes_out" in row:
            bytes_in, bytes_out = int(row["bytes_in"]), int(row["bytes_out"])
        elif data is not None and predicted_bytes == float(data):  # same bindings, same split
            bytes_in, bytes_out = predicted.bytes_in, predicted.bytes_out
        else:
            bytes_in = bytes_out = None
        per_cycle = moved + lock
        interval = duration / cycles if cycles else math.inf
        loads.append(TaskLoad(name, str(row.get("rtpu") or spec.rtpu), interval, bytes_in, bytes_out, per_cycle,
                              cycles * per_cycle / duration, predicted.aperiodic, cycles))
    return bus_report(subsystem, configuration, loads, "measured", duration)


def measured_live(subsystem: Subsystem, status: Mapping[str, Any]) -> BusReport:
    """Z_j of a running configuration, now: each task's measured rate x (bytes per cycle + 2Δ).

    `status` is the status reply of a live run (`supervisor.commands`): its `configuration`, and
    per task its measured `rate` (Hz) and `state`. A task not ON moves nothing now (rate 0); a
    task of the configuration the reply does not list ran no cycle. The bytes per cycle are what
    `measured` takes when a report does not say what the table moved: the data of the task's
    per-cycle bindings, from the file. `period` is the measured mean interval (inf when not running).
    """
    configuration = str(status.get("configuration") or next(iter(subsystem.configurations), ""))
    names = members_of(subsystem, configuration)
    rows = {str(row.get("task")): row for row in status.get("tasks") or ()}
    loads = []
    for name in names:
        predicted = task_load(subsystem, subsystem.tasks[name])
        row = rows.get(name) or {}
        rate = float(row.get("rate") or 0.0) if row.get("state") == "ON" else 0.0
        if not (math.isfinite(rate) and rate > 0):
            rate = 0.0
        interval = 1.0 / rate if rate > 0 else math.inf
        loads.append(TaskLoad(name, str(row.get("rtpu") or predicted.rtpu), interval, predicted.bytes_in, predicted.bytes_out,
                              predicted.per_cycle_bytes, rate * predicted.per_cycle_bytes, predicted.aperiodic,
                              int(row.get("cycles") or 0)))
    return bus_report(subsystem, configuration, loads, "measured")


# --- combined modules (TR §4.5) ----------------------------------------------------------------


def combined_saving(subsystem: Subsystem, configuration: str, members: list[str]) -> tuple[BusReport, BusReport]:
    """(before, after): the configuration as it is, and with `members` combined into one task.

    The combined task runs at the fastest member's period (for aperiodic members: the shortest
    minimum inter-arrival time) on the members' RTPU, with one local table: it reads every
    outside variable once however many members read it, and writes every member output once. A
    variable that only links members (written by members only, read per cycle by members and
    by no other task of the configuration) stays local: it is neither read nor written on the
    bus. A variable written by a member but also read by another task is still written; the
    member that reads it takes it from the local table.
    """
    names = members_of(subsystem, configuration)
    if not members:
        raise BusModelError("combined_saving needs at least one member task")
    if len(set(members)) != len(members):
        raise BusModelError(f"combined_saving: a member is named twice in {members}")
    missing = [m for m in members if m not in names]
    if missing:
        raise BusModelError(f"task(s) {', '.join(missing)} not in configuration '{configuration}' ({', '.join(names)})")
    specs = [subsystem.tasks[m] for m in members]
    rtpus = sorted({t.rtpu for t in specs})
    if len(rtpus) > 1:
        raise BusModelError(
            f"tasks {', '.join(members)} run on {', '.join(rtpus)}: a combined module is one task and cannot be "
            "distributed among RTPUs (TR §4.5); move them to one RTPU first"
        )
    before = predict(subsystem, configuration)

    group = set(members)
    outsiders = [subsystem.tasks[n] for n in names if n not in group]

    def per_cycle(task: TaskSpec, kinds: tuple[PortKind, ...]) -> dict[str, PortBinding]:
        return {b.variable: b for b in task.bindings if b.port.kind in kinds}

    member_in: dict[str, PortBinding] = {}
    member_out: dict[str, PortBinding] = {}
    for task in specs:
        for var, b in per_cycle(task, PER_CYCLE_IN).items():
            member_in.setdefault(var, b)
        for var, b in per_cycle(task, PER_CYCLE_OUT).items():
            member_out.setdefault(var, b)
    outside_readers = {v for t in outsiders for v in per_cycle(t, PER_CYCLE_IN)}
    outside_writers = {v for t in outsiders for v in per_cycle(t, PER_CYCLE_OUT)}
    # produced inside and not also joined from outside: members read it from their one local table
    internal = {v for v in member_out if v not in outside_writers}
    local_only = {v for v in internal if v in member_in and v not in outside_readers}
    bytes_in = sum(transfer_bytes(subsystem, b) for v, b in member_in.items() if v not in internal)
    bytes_out = sum(transfer_bytes(subsystem, b) for v, b in member_out.items() if v not in local_only)

    intervals = [interval_of(t) for t in specs]
    interval = min(i for i, _ in intervals)
    aperiodic = all(a for _, a in intervals)
    per_cycle_bytes = bytes_in + bytes_out + LOCKS_PER_CYCLE * subsystem.bus.lock_overhead
    combined = TaskLoad("+".join(members), rtpus[0], interval, bytes_in, bytes_out, per_cycle_bytes,
                        per_cycle_bytes / interval, aperiodic)
    # the combined task takes the place of its first member in the configuration's order
    first = next(n for n in names if n in group)
    loads = [combined if load.task == first else load for load in before.tasks if load.task not in group or load.task == first]
    after = bus_report(subsystem, f"{configuration} ({combined.task} combined)", loads, "combined")
    return before, after


def describe_saving(before: BusReport, after: BusReport) -> str:
    """One line: what combining saves (or costs) on the bus."""
    saved = before.total - after.total
    ratio = saved / before.total if before.total else 0.0
    verb = "saves" if saved >= 0 else "costs"
    return (f"{after.configuration}: B {before.total / 1e3:,.1f} → {after.total / 1e3:,.1f} kB/s, "
            f"{verb} {abs(saved) / 1e3:,.1f} kB/s ({abs(ratio):.1%} of B, {abs(saved) / before.bandwidth:.3%} of the bandwidth)")


# --- output ------------------------------------------------------------------------------------

NO_VALUE = "–"  # noqa: RUF001 - an en dash, deliberately: what a table shows in a cell with no figure


def _seconds(value: float) -> str:
    if not math.isfinite(value):
        return NO_VALUE
    if value >= 1:
        return f"{value:g} s"
    if value >= 1e-3:
        return f"{value * 1e3:.4g} ms"
    return f"{value * 1e6:.4g} µs"


def _period_text(load: TaskLoad) -> str:
    return ("≥ " if load.aperiodic else "") + _seconds(load.period)


def _bytes(value: float | None) -> str:
    return "?" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:g}"


def _kbs(rate: float) -> str:
    return f"{rate / 1e3:,.1f}"


def _pct(share: float) -> str:
    return f"{share * 100:.3f} %"


def as_table(report: BusReport, measured: BusReport | None = None) -> Table:
    """The report as a rich table: one row per task and a total row; measured values beside the predicted ones."""
    from rich.table import Table  # here: loading a file (every process of a run) does not need rich

    title = (f"bus load · {report.configuration} · bandwidth {report.bandwidth / 1e6:g} MB/s · "
             f"Δ = {report.lock_overhead:g} B")
    if report.kind != "predicted":
        title += f" · {report.kind}"
    table = Table(title=title, title_justify="left", caption="Z_j = (Σ S(x) + Σ S(y) + 2Δ) / T_j;  B = Σ Z_j;  kB = 1000 B",
                  caption_justify="left")
    table.add_column("task")
    table.add_column("RTPU")
    table.add_column("period", justify="right")
    table.add_column("bytes in", justify="right")
    table.add_column("bytes out", justify="right")
    table.add_column("lock 2Δ B", justify="right")
    if measured is None:
        table.add_column("Z_j kB/s", justify="right")
        table.add_column("share", justify="right")
    else:
        table.add_column("cycles", justify="right")
        table.add_column("Z_j kB/s predicted", justify="right")
        table.add_column("Z_j kB/s measured", justify="right")
        table.add_column("share predicted", justify="right")
        table.add_column("share measured", justify="right")
    seen = {load.task: load for load in measured.tasks} if measured is not None else {}
    for load in report.tasks:
        row = [load.task, load.rtpu, _period_text(load), _bytes(load.bytes_in), _bytes(load.bytes_out), _bytes(load.lock_bytes)]
        if measured is None:
            row += [_kbs(load.rate_bytes_per_s), _pct(load.rate_bytes_per_s / report.bandwidth)]
        else:
            m = seen.get(load.task)
            row += [
                str(m.cycles) if m is not None and m.cycles is not None else NO_VALUE,
                _kbs(load.rate_bytes_per_s),
                _kbs(m.rate_bytes_per_s) if m is not None else NO_VALUE,
                _pct(load.rate_bytes_per_s / report.bandwidth),
                _pct(m.rate_bytes_per_s / measured.bandwidth) if m is not None else NO_VALUE,
            ]
        table.add_row(*row)
    table.add_section()
    style = "bold red" if report.over else "bold"
    total = ["B (total)", "", "", "", "", ""]
    if measured is None:
        total += [_kbs(report.total), _pct(report.share)]
    else:
        total += ["", _kbs(report.total), _kbs(measured.total), _pct(report.share), _pct(measured.share)]
    table.add_row(*total, style=style)
    return table


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _load_json(load: TaskLoad, bandwidth: float) -> dict[str, Any]:
    out: dict[str, Any] = {
        "task": load.task, "rtpu": load.rtpu, "period": _finite(load.period), "aperiodic": load.aperiodic,
        "bytes_in": load.bytes_in, "bytes_out": load.bytes_out, "lock_bytes": _finite(load.lock_bytes),
        "per_cycle_bytes": load.per_cycle_bytes, "rate_bytes_per_s": load.rate_bytes_per_s,
        "share": load.rate_bytes_per_s / bandwidth if bandwidth > 0 else None,
    }
    if load.cycles is not None:
        out["cycles"] = load.cycles
    return out


def _report_json(report: BusReport) -> dict[str, Any]:
    out: dict[str, Any] = {
        "configuration": report.configuration, "kind": report.kind,
        "tasks": [_load_json(load, report.bandwidth) for load in report.tasks],
        "total": report.total, "bandwidth": report.bandwidth, "share": _finite(report.share),
        "lock_overhead": report.lock_overhead, "over_bandwidth": report.over,
    }
    if report.duration is not None:
        out["duration"] = report.duration
    return out


def as_json(report: BusReport, measured: BusReport | None = None) -> dict[str, Any]:
    """The report as plain data (json.dumps-able): {"predicted": {...}, "measured": {...} or None}.

    Rates are bytes per second, sizes bytes per cycle, periods seconds (None for a task that never
    ran), shares are fractions; each part's "kind" says whether it is predicted, measured or combined.
    """
    return {"predicted": _report_json(report), "measured": _report_json(measured) if measured is not None else None}


CSV_HEADER = ("configuration", "task", "rtpu", "period_s", "aperiodic", "bytes_in", "bytes_out", "lock_bytes",
              "per_cycle_bytes", "rate_bytes_per_s", "share")


def as_csv(report: BusReport, measured: BusReport | None = None) -> str:
    """The report as CSV: a header, one line per task, and a TOTAL line (B); measured columns when given."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    header = list(CSV_HEADER)
    if measured is not None:
        header += ["measured_cycles", "measured_rate_bytes_per_s", "measured_share"]
    writer.writerow(header)
    seen = {load.task: load for load in measured.tasks} if measured is not None else {}

    def num(value: float | None) -> str:
        return "" if value is None or not math.isfinite(value) else repr(float(value)) if isinstance(value, float) else str(value)

    for load in report.tasks:
        row = [report.configuration, load.task, load.rtpu, num(load.period), str(load.aperiodic).lower(),
               num(load.bytes_in), num(load.bytes_out), num(load.lock_bytes), num(load.per_cycle_bytes),
               num(load.rate_bytes_per_s), num(load.rate_bytes_per_s / report.bandwidth)]
        if measured is not None:
            m = seen.get(load.task)
            row += [num(m.cycles), num(m.rate_bytes_per_s), num(m.rate_bytes_per_s / measured.bandwidth)] if m else ["", "", ""]
        writer.writerow(row)
    total = [report.configuration, "TOTAL", "", "", "", "", "", "", "", num(report.total), num(report.share)]
    if measured is not None:
        total += ["", num(measured.total), num(measured.share)]
    writer.writerow(total)
    return buffer.getvalue()


def plot(reports: BusReport | Iterable[BusReport] | Mapping[str, BusReport], path: str | Path,
         measured: Mapping[str, BusReport] | Iterable[BusReport] | None = None) -> Path:
    """A PNG of Z_j per task, grouped by configuration, with B and the bandwidth as a line.

    Bars are grouped (one per task, and a hatched one for B); the y axis is logarithmic when the
    bandwidth line is far above the bars, as it usually is. Measured rates, if given (keyed by
    configuration), are drawn as black markers on the bars of the same task.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if isinstance(reports, BusReport):
        reports = [reports]
    elif isinstance(reports, Mapping):
        reports = list(reports.values())
    reports = list(reports)
    if not reports:
        raise BusModelError("plot needs at least one bus report")
    if measured is not None and not isinstance(measured, Mapping):
        measured = {m.configuration: m for m in measured}
    measured = measured or {}

    width_slots = max(len(r.tasks) for r in reports) + 1  # the tasks and B
    bar = 0.8 / width_slots
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 + 1.1 * len(reports) * width_slots * 0.6), 4.5), dpi=120)
    cmap = plt.get_cmap("tab10")
    colours: dict[str, Any] = {}
    labelled: set[str] = set()
    highest = 0.0
    lowest = math.inf
    for g, report in enumerate(reports):
        m = measured.get(report.configuration)
        m_rates = {load.task: load.rate_bytes_per_s for load in m.tasks} if m is not None else {}
        bars = [(load.task, load.rate_bytes_per_s) for load in report.tasks] + [("B (total)", report.total)]
        for k, (name, rate) in enumerate(bars):
            x = g + (k - (len(bars) - 1) / 2) * bar
            is_total = k == len(bars) - 1
            colour = "0.55" if is_total else colours.setdefault(name, cmap(len(colours) % 10))
            label = name if name not in labelled else None
            labelled.add(name)
            ax.bar(x, rate / 1e3, bar * 0.95, color=colour, hatch="//" if is_total else None, edgecolor="0.2",
                   linewidth=0.5, label=label)
            ax.annotate(f"{rate / 1e3:,.0f}", (x, rate / 1e3), ha="center", va="bottom", fontsize=7,
                        xytext=(0, 2), textcoords="offset points")
            measured_rate = (m.total if is_total else m_rates.get(name)) if m is not None else None
            if measured_rate is not None:
                ax.plot([x], [measured_rate / 1e3], marker="D", color="black", markersize=4, linestyle="none",
                        label="measured" if "measured" not in labelled else None)
                labelled.add("measured")
            if rate > 0:
                highest, lowest = max(highest, rate), min(lowest, rate)
    bandwidth = max(r.bandwidth for r in reports)
    ax.axhline(bandwidth / 1e3, color="red", linestyle="--", linewidth=1.2,
               label=f"bus bandwidth {bandwidth / 1e6:g} MB/s")
    if highest > 0 and bandwidth / highest > 20:
        ax.set_yscale("log")
        ax.set_ylim(max(lowest / 1e3 / 3, 1e-3), bandwidth / 1e3 * 3)
        ax.set_ylabel("bus load Z_j (kB/s, log scale)")
    else:
        ax.set_ylim(0, max(bandwidth, highest) / 1e3 * 1.15)
        ax.set_ylabel("bus load Z_j (kB/s)")
    ax.set_xticks(range(len(reports)))
    ax.set_xticklabels([f"{r.configuration}\nB = {r.share:.2%} of bus" for r in reports], fontsize=8)
    ax.set_xlabel("configuration")
    delta = reports[0].lock_overhead
    ax.set_title(f"Bus load per task (TR eq. 1-2, Δ = {delta:g} B, kB = 1000 B)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    plt.close(fig)
    return path
