"""`pbo plot` and `pbo log export`: a run's logged variables against time, and as CSV for spreadsheets.

A run's directory holds its logs and report.json; the report says when the configuration came on
(`started_at`) and when each switch and job happened (`marks`), on the run's clock, the clock a
log's rows are stamped with (each cycle's release time). The plot's time axis is seconds since
the configuration came on (since the first row without a report), one subplot per argument
(`plot_terms`: variables overlaid, elements, differences; by default one per variable), one line
per element of a vector, the unit on each axis, and the switches and jobs as labelled vertical lines.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pbo_runtime.reports.data_log import DataLog, LogError, find_logs, open_log
from pbo_runtime.reports.plot_terms import Curves, axis_curves
from pbo_runtime.reports.run_records import Mark

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PLOT_SUFFIXES = (".png", ".svg", ".pdf")
MARK_COLOURS = {"configuration": "tab:green", "switch": "tab:red", "change": "tab:purple", "job": "tab:gray"}


@dataclass
class RunData:
    """What `pbo plot` draws: the logs of a run (or one log) and its report's origin and marks."""

    logs: list[DataLog]
    origin: float  # run-clock seconds shown as 0
    marks: list[Mark] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=dict)  # from the report, for logs that carry none (.npy)

    def columns(self) -> dict[str, DataLog]:
        """Every logged variable and the log that holds it (the first, when two logs hold one)."""
        found: dict[str, DataLog] = {}
        for log in self.logs:
            for name in log.variables:
                found.setdefault(name, log)
        return found

    def unit(self, log: DataLog, name: str) -> str:
        return log.units.get(name) or self.units.get(name, "")


def load_run(target: str | Path) -> RunData:
    """A run's directory (every log in it) or one log file, with the report.json beside it if any."""
    target = Path(target)
    if target.is_dir():
        paths = find_logs(target)
        if not paths:
            raise LogError(f"{target}: no data log in this directory (no *.mcap or *.npy file); "
                           "give a run's directory (pbo run prints it) or a log file")
        report_path = target / "report.json"
    elif target.is_file():
        paths = [target]
        report_path = next((d / "report.json" for d in (target.parent, *target.parents) if (d / "report.json").is_file()),
                           target.parent / "report.json")
    else:
        raise LogError(f"no run directory or log {target}: no such file or directory")
    logs = [open_log(path) for path in paths]
    report = _read_report(report_path)
    started = float(report.get("started_at") or 0.0)
    firsts = [float(log.rows["time"][0]) for log in logs if len(log.rows)]
    origin = started if started else (min(firsts) if firsts else 0.0)
    units = {name: v.get("unit", "") for name, v in report.get("variables", {}).items() if isinstance(v, dict)}
    return RunData(logs, origin, [Mark.from_json(m) for m in report.get("marks", []) if isinstance(m, dict)], units)


def logs_to_export(target: Path, output: Path | None) -> list[Path]:
    """The logs `pbo log export TARGET -o OUTPUT` writes: a log file, or every log of a run's
    directory (several only into a directory, one CSV each); LogError saying what to give instead."""
    if not target.is_dir():
        return [target]  # (a file that is not there is open_log's to say)
    logs = find_logs(target)
    if not logs:
        raise LogError(f"{target}: no data log in this directory (no *.mcap or *.npy file); "
                       "give a run's directory (pbo run prints it) or a log file")
    if len(logs) > 1 and (output is None or not output.is_dir()):
        names = ", ".join(log.name for log in logs)
        raise LogError(f"{target} holds {len(logs)} logs ({names}): give one of them, or -o DIR (an existing "
                       "directory) for one CSV each")
    return logs


def _read_report(path: Path) -> dict[str, Any]:
    try:
        report = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return report if isinstance(report, dict) else {}


def plot_axes(run: RunData, arguments: list[str]) -> list[tuple[str, list[Curves]]]:
    """Each axis asked for (`plot_terms`: `q_m,q_r`, `q_m[1]`, `q_m-q_r`; by default one per logged
    variable) with its curves; LogError naming what is wrong and what was logged."""
    columns = run.columns()
    units = {name: run.unit(log, name) for name, log in columns.items()}
    return [(argument, axis_curves(argument, columns, units, _where(run))) for argument in (arguments or list(columns))]


def _where(run: RunData) -> str:
    return ", ".join(str(log.path) for log in run.logs)


def figure(run: RunData, variables: list[str] | None = None, new: Callable[..., Figure] | None = None) -> Figure:
    """The plot: one subplot per variable against time, marks as labelled vertical lines (gid 'mark').

    `new` makes the figure (pyplot.figure for a window); by default a bare Figure, to be saved."""
    from matplotlib.figure import Figure

    axes_asked = plot_axes(run, list(variables or []))
    fig = (new or Figure)(figsize=(10, 1.2 + 2.2 * len(axes_asked)), dpi=100, layout="constrained")
    axes = fig.subplots(len(axes_asked), 1, sharex=True, squeeze=False)[:, 0]
    marks = [(mark.time - run.origin, mark.label, mark.kind) for mark in run.marks]
    for ax, (argument, curves) in zip(axes, axes_asked, strict=False):
        lines = 0
        for curve in curves:
            for element, label in enumerate(curve.labels):
                ax.plot(curve.time - run.origin, curve.values[:, element], linewidth=1.0, label=label)
                lines += 1
        units = {curve.unit for curve in curves}
        unit = units.pop() if len(units) == 1 else ""
        ax.set_ylabel(f"{argument} [{unit}]" if unit else argument)
        if lines > 1:
            ax.legend(loc="upper right", fontsize="x-small", ncol=min(lines, 6))
        for at, _label, kind in marks:
            line = ax.axvline(at, color=MARK_COLOURS.get(kind, "black"), linestyle="--", linewidth=0.8)
            line.set_gid("mark")
        ax.grid(True, linewidth=0.3)
    top = axes[0]
    for at, label, kind in _side_by_side(marks, top.get_xlim()):
        top.annotate(label, xy=(at, 1.0), xycoords=("data", "axes fraction"), rotation=90, fontsize="x-small",
                     va="bottom", ha="right", color=MARK_COLOURS.get(kind, "black"), gid="mark")
    axes[-1].set_xlabel("time since the configuration came on [s]" if run.marks else "time [s]")
    fig.suptitle(_title(run), fontsize="small")
    return fig


def _side_by_side(marks: list[tuple[float, str, str]], limits: tuple[float, float]) -> list[tuple[float, str, str]]:
    """One label for marks closer than a hundredth of the time axis (a job's end and the next one's
    start are one instant), their texts joined, so labels never print over each other."""
    near = 0.01 * (limits[1] - limits[0])
    joined: list[tuple[float, str, str]] = []
    for at, label, kind in sorted(marks, key=lambda mark: mark[0]):
        if joined and at - joined[-1][0] < near:
            first, text, first_kind = joined[-1]
            joined[-1] = (first, f"{text} / {label}", first_kind)
        else:
            joined.append((at, label, kind))
    return joined


def _title(run: RunData) -> str:
    meta = next((log.metadata for log in run.logs if log.metadata), {})
    parts = [meta.get("subsystem", ""), meta.get("configuration", ""), f"clock {meta['clock']}" if meta.get("clock") else ""]
    return " · ".join(p for p in parts if p) or ", ".join(log.path.name for log in run.logs)


def save(fig: Figure, output: Path) -> None:
    """Write the figure to a .png, .svg or .pdf file; LogError for another extension."""
    if output.suffix.lower() not in PLOT_SUFFIXES:
        raise LogError(f"-o {output}: the plot is written as .png, .svg or .pdf, got '{output.suffix or 'no extension'}'")
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output)


def csv_text(log: DataLog) -> str:
    """The log as CSV: a time column, then one column per element ("q_m[0] [rad]"), a row per cycle."""
    header = ["time [s]"]
    columns = [log.rows["time"].reshape(-1, 1)]
    for name in log.variables:
        shape = log.rows.dtype[name].shape
        unit = log.units.get(name, "")
        for element in range(int(np.prod(shape, dtype=int))):
            label = name + ("".join(f"[{i}]" for i in np.unravel_index(element, shape)) if shape else "")
            header.append(f"{label} [{unit}]" if unit else label)
        columns.append(log.rows[name].reshape(len(log.rows), -1))
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    for row in zip(*(c.tolist() for c in columns), strict=False):
        writer.writerow([value for part in row for value in part])
    return out.getvalue()
