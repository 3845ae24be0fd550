"""The end-of-run summary `pbo run` prints: each task's figures, the final values, and one line for
each thing the operator should know (overruns and why, stalls, holds, processors, the plant, the
clock, the RTPUs' scheduling, switches)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from rich.console import Console
from rich.table import Table

from pbo_runtime.config.model import Subsystem
from pbo_runtime.reports.run_result import (
    RtpuSettings,
    RunResult,
    Stall,
    SwitchFigures,
    TaskReport,
)

Value = float | int | list[object]  # a list: one element per entry, or a row of a matrix


def print_summary(console: Console, subsystem: Subsystem, result: RunResult, restart_lines: list[str],
                  decision_lines: list[str]) -> None:
    """The summary of `result`; the supervisor's parts give the lines of RTPU restarts and an application's decisions."""
    table = Table(title=f"run summary: {subsystem.name} · {result.configuration} · {result.duration:.2f} s "
                        f"(stopped by {result.stopped_by})", title_justify="left")
    for column in ("task", "rtpu", "state", "cycles", "rate Hz", "overruns", "missed", "jitter p50 µs", "jitter p99 µs",
                   "jitter max µs", "exec p50 µs", "exec p99 µs"):
        table.add_column(column, justify="left" if column in ("task", "rtpu", "state") else "right")
    for name, task in result.tasks.items():
        t = task.statistics
        if not t.cycles and task.state != "ERROR":
            continue
        rate = t.cycles / result.duration if result.duration else 0.0
        table.add_row(name, task.rtpu, task.state, str(t.cycles), f"{rate:.0f}", str(t.overruns), str(t.missed),
                      f"{t.jitter_p50 * 1e6:.0f}", f"{t.jitter_p99 * 1e6:.0f}", f"{t.jitter_max * 1e6:.0f}",
                      f"{t.exec_p50 * 1e6:.0f}", f"{t.exec_p99 * 1e6:.0f}")
    console.print(table)
    values = Table(title="final values", title_justify="left")
    values.add_column("variable")
    values.add_column("value")
    values.add_column("writer")
    for name, final in result.variables.items():
        if subsystem.variables[name].size > 12:
            continue
        values.add_row(name, format_value(final.value), final.writer)
    console.print(values)
    for name, task in result.tasks.items():
        if task.error:
            console.print(f"task '{name}': {task.error}", markup=False)
    realtime = result.realtime
    for line in [*overrun_lines(subsystem, result.tasks, realtime), *stall_lines(result.stalls), *restart_lines,
                 *result.timing_holds, *processor_lines(result.tasks)]:
        console.print(line, markup=False)
    if result.plant is not None:
        plant = result.plant
        console.print(f"plant: {plant.steps} steps, {plant.late} late", markup=False)
        if plant.left_fifo_behind:
            console.print(f"plant: it fell {plant.left_fifo_behind:.2f} s behind real time (a step takes longer "
                          "than its timestep) and left SCHED_FIFO, so as not to hold a CPU above the RTPUs: lengthen "
                          "the timestep or lighten the model", markup=False)
    if result.clock == "sim":
        speed = result.duration / result.wall_seconds if result.wall_seconds else 0.0
        running = result.running_wall_seconds
        ticking = f"; {result.duration / running:.2f}x from the configuration on" if running else ""
        paced = f", paced at {result.pace:g}x real time at most" if result.pace else ""
        console.print(f"clock: simulated, {result.tick * 1e3:g} ms ticks{paced}; {result.duration:.2f} s simulated in "
                      f"{result.wall_seconds:.2f} s of wall time ({speed:.2f}x real time{ticking})", markup=False)
    for rtpu, settings in realtime.items():
        if settings.simulated:
            continue  # simulated: no scheduler settings to report
        console.print(f"{rtpu}: cpu {settings.cpu}, {settings.scheduler}, timer slack {settings.timer_slack}"
                      + (f", spin {settings.spin}" if settings.spin is not None else ""), markup=False)
    print_switches(console, result)
    for line in decision_lines:
        console.print(line, markup=False)


def processor_lines(tasks: Mapping[str, TaskReport]) -> list[str]:
    """Each special-purpose processor's own timing (TR 4.6.3), from the figures its driver gave with its task's."""
    lines = []
    for name, task in tasks.items():
        for p in task.statistics.processors():
            line = (f"special-purpose processor '{p.device}' (task '{name}', routine {p.routine}): "
                    f"{p.items} work items, service p50 {p.service_p50 * 1e6:.0f} µs, p99 {p.service_p99 * 1e6:.0f} µs, "
                    f"max {p.service_max * 1e6:.0f} µs; {p.missed} missed, {p.late_calls} of {p.calls} calls late"
                    + (f"; ran {p.scheduler}" if p.scheduler else ""))
            lines.append(line + (f"; {p.fault}" if p.fault else ""))
    return lines


def stall_lines(stalls: list[Stall]) -> list[str]:
    """Each time a task ON finished no cycle for a while (never counted as an overrun: the cycle did not end)."""
    lines = []
    for s in stalls:
        where = f"task '{s.task}' ({s.rtpu}) finished no cycle"
        if s.until is not None:
            lines.append(f"{where} for {s.until - s.since:.2f} s, from {s.since:.2f} s into the run")
            continue
        line = f"{where} from {s.since:.2f} s into the run to the stop: its module's cycle never returned"
        if s.rtpu_killed:
            line += f"; {s.rtpu} did not stop and was killed, so its tasks' figures are the table's last"
        lines.append(line)
    return lines


def scheduler_outcome(reported: str) -> str:
    """What the scheduler an RTPU reported (rtpu/_realtime.apply) amounts to: 'fifo', 'refused' or 'other'."""
    if reported.startswith("SCHED_FIFO"):
        return "fifo"
    return "refused" if "SCHED_FIFO refused" in reported else "other"


def late_release_remedy(scheduler: str) -> str:
    """What helps a late release, given the scheduler its RTPU reported (docs/configuration.md)."""
    outcome = scheduler_outcome(scheduler)
    if outcome == "fifo":
        return "it ran SCHED_FIFO already, so only the kernel or, on a VM, the hypervisor held it"
    if outcome == "refused":
        return "the OS refused SCHED_FIFO (see the RTPU's line below); pinning with rtpus: {cpu: N} helps meanwhile"
    return "SCHED_FIFO (drop --no-fifo) or pinning with rtpus: {cpu: N} help"


def overrun_lines(subsystem: Subsystem, tasks: Mapping[str, TaskReport],
                  realtime: Mapping[str, RtpuSettings] | None = None) -> list[str]:
    """Why each task overran. A late release is the machine's (the RTPU got its CPU late); a long
    cycle is the module's (it ran longer than its period): they call for different remedies.
    `realtime`: what each RTPU reported of its scheduler, so the remedy is not one it already has."""
    lines = []
    for name, task in tasks.items():
        t = task.statistics
        if not t.overruns or name not in subsystem.tasks:
            continue
        period = subsystem.tasks[name].period
        late, long = t.overruns_late_release, t.overruns_long_cycle
        parts = []
        if late:
            settings = (realtime or {}).get(task.rtpu)
            remedy = late_release_remedy(settings.scheduler or "" if settings is not None else "")
            parts.append(f"{late} late release{'s' if late > 1 else ''} (started up to {t.jitter_max * 1e3:.2f} ms late: "
                         f"the machine held the RTPU's CPU; {remedy})")
        if long:
            parts.append(f"{long} long cycle{'s' if long > 1 else ''} (ran up to {t.exec_max * 1e3:.2f} ms: the module "
                         "needs more than its period; lighten its cycle or lengthen its period)")
        kept = t.last_overruns
        when = ", ".join(f"{overrun.release:.3f} s" for overrun in kept)
        which = "at" if len(kept) == t.overruns else f"the last {len(kept)} at"
        lines.append(f"overruns of '{name}' ({period * 1e3:g} ms period): " + "; ".join(parts)
                     + (f"; {which} {when} into the run" if kept else ""))
    return lines


def print_switches(console: Console, result: RunResult) -> None:
    """Per switch: latency (request to the first cycle of the new configuration); stale reads."""
    if not result.switches:
        return
    switches = [SwitchFigures.of(s) for s in result.switches]
    latency = np.array([s.latency for s in switches]) * 1e3
    skew = np.array([s.skew for s in switches]) * 1e3
    longest = np.array([s.longest for s in switches]) * 1e3
    console.print(
        f"switches: {len(switches)}; latency ms p50 {np.median(latency):.2f}, p99 {np.percentile(latency, 99):.2f}, "
        f"max {latency.max():.2f}; RTPU skew ms max {skew.max():.3f}; longest switch on one RTPU {longest.max():.3f} ms",
        markup=False)
    restarted = [f"{s.sequence} ({', '.join(s.restarted)})" for s in switches if s.restarted]
    if restarted:  # (their latency includes the restart)
        console.print(f"switches through an RTPU's restart: {', '.join(restarted)}", markup=False)
    lost_in = [s.sequence for s in switches if s.lost_a_cycle]
    if lost_in:
        console.print(f"switches after which the critical task lost a cycle: {', '.join(map(str, lost_in[:20]))}"
                      + (" ..." if len(lost_in) > 20 else ""), markup=False)
    for name, task in result.tasks.items():
        if not task.critical:
            continue
        t = task.statistics
        console.print(f"critical task '{name}': {t.cycles_lost_to_switches} cycles lost to switches (read an output of a "
                      f"task switched out); {t.stale_reads} stale reads from late writers ({t.stale_reads_at_switches} "
                      f"within 3 periods of a switch); {t.stable_cycles} locally stable cycles"
                      + (f"; last lost: {t.last_cycle_lost}" if t.last_cycle_lost else "")
                      + (f"; last stale: {t.last_stale_read}" if t.last_stale_read else ""), markup=False)


def format_value(value: Value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(f"{x:+.4f}" if isinstance(x, float) else str(x) for x in value) + "]"
    return f"{value:+.4f}" if isinstance(value, float) else str(value)
