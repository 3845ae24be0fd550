"""The end of a run's summary: each task's figures, the final values, and why anything went wrong."""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table

from pbo_runtime.clock.clocks import scheduler_outcome


def _print_summary(console: Console, subsystem: Any, result: Any) -> None:
    table = Table(title=f"run summary: {subsystem.name} · {result.configuration} · {result.duration:.2f} s "
                        f"(stopped by {result.stopped_by})", title_justify="left")
    for column in ("task", "rtpu", "state", "cycles", "rate Hz", "overruns", "missed", "jitter p50 µs", "jitter p99 µs",
                   "jitter max µs", "exec p50 µs", "exec p99 µs"):
        table.add_column(column, justify="left" if column in ("task", "rtpu", "state") else "right")
    for name, t in result.tasks.items():
        if not t.get("cycles") and t.get("state") != "ERROR":
            continue
        rate = t["cycles"] / result.duration if result.duration else 0.0
        table.add_row(name, t["rtpu"], t["state"], str(t["cycles"]), f"{rate:.0f}", str(t["overruns"]), str(t["missed"]),
                      f"{t['jitter_p50'] * 1e6:.0f}", f"{t['jitter_p99'] * 1e6:.0f}", f"{t['jitter_max'] * 1e6:.0f}",
                      f"{t['exec_p50'] * 1e6:.0f}", f"{t['exec_p99'] * 1e6:.0f}")
    console.print(table)
    values = Table(title="final values", title_justify="left")
    values.add_column("variable")
    values.add_column("value")
    values.add_column("writer")
    for name, v in result.variables.items():
        if subsystem.variables[name].size > 12:
            continue
        values.add_row(name, _format_value(v["value"]), v["writer"])
    console.print(values)
    for name, t in result.tasks.items():
        if t.get("error"):
            console.print(f"task '{name}': {t['error']}", markup=False)
    for line in overrun_lines(subsystem, result.tasks, result.realtime):
        console.print(line, markup=False)
    for line in stall_lines(result.stalls):
        console.print(line, markup=False)
    from pbo_runtime.supervisor.restarts import restart_lines

    for line in restart_lines([restart.to_json() for restart in result.restarts]):
        console.print(line, markup=False)
    for line in result.timing_holds:
        console.print(line, markup=False)
    for line in processor_lines(result.tasks):
        console.print(line, markup=False)
    if result.plant:
        console.print(f"plant: {result.plant.get('steps', 0)} steps, {result.plant.get('late', 0)} late", markup=False)
        if result.plant.get("left_fifo_behind"):
            console.print(f"plant: it fell {result.plant['left_fifo_behind']:.2f} s behind real time (a step takes longer "
                          "than its timestep) and left SCHED_FIFO, so as not to hold a CPU above the RTPUs: lengthen "
                          "the timestep or lighten the model", markup=False)
    if result.clock == "sim":
        speed = result.duration / result.wall_seconds if result.wall_seconds else 0.0
        running = result.running_wall_seconds
        ticking = f"; {result.duration / running:.2f}x from the configuration on" if running else ""
        console.print(f"clock: simulated, {result.tick * 1e3:g} ms ticks; {result.duration:.2f} s simulated in "
                      f"{result.wall_seconds:.2f} s of wall time ({speed:.2f}x real time{ticking})", markup=False)
    for rtpu, settings in result.realtime.items():
        if "clock" in settings:
            continue  # simulated: no scheduler settings to report
        console.print(f"{rtpu}: cpu {settings.get('cpu')}, {settings.get('scheduler')}, timer slack {settings.get('timer_slack')}"
                      + (f", spin {settings['spin']}" if "spin" in settings else ""), markup=False)
    _print_switches(console, result)
    from pbo_runtime.supervisor.decisions import decision_lines

    for line in decision_lines(result.decisions):
        console.print(line, markup=False)


def processor_lines(tasks: dict[str, dict[str, Any]]) -> list[str]:
    """Each special-purpose processor's own timing (TR 4.6.3), from the figures its driver gave with its task's."""
    lines = []
    for name, t in tasks.items():
        for device, f in t.get("devices", {}).items():
            if f.get("processor") != "spp":
                continue
            line = (f"special-purpose processor '{device}' (task '{name}', routine {f.get('routine') or 'none'}): "
                    f"{f['items']} work items, service p50 {f['service_p50'] * 1e6:.0f} µs, p99 {f['service_p99'] * 1e6:.0f} µs, "
                    f"max {f['service_max'] * 1e6:.0f} µs; {f['missed']} missed, {f['late_calls']} of {f['calls']} calls late")
            lines.append(line + (f"; {f['fault']}" if f.get("fault") else ""))
    return lines


def stall_lines(stalls: list[dict[str, Any]]) -> list[str]:
    """Each time a task ON finished no cycle for a while (never counted as an overrun: the cycle did not end)."""
    lines = []
    for s in stalls:
        where = f"task '{s['task']}' ({s['rtpu']}) finished no cycle"
        if s["to"] is not None:
            lines.append(f"{where} for {s['to'] - s['from']:.2f} s, from {s['from']:.2f} s into the run")
            continue
        line = f"{where} from {s['from']:.2f} s into the run to the stop: its module's cycle never returned"
        if s["rtpu_killed"]:
            line += f"; {s['rtpu']} did not stop and was killed, so its tasks' figures are the table's last"
        lines.append(line)
    return lines


def _late_release_remedy(scheduler: str) -> str:
    """What helps a late release, given the scheduler its RTPU reported (docs/configuration.md)."""
    outcome = scheduler_outcome(scheduler)
    if outcome == "fifo":
        return "it ran SCHED_FIFO already, so only the kernel or, on a VM, the hypervisor held it"
    if outcome == "refused":
        return "the OS refused SCHED_FIFO (see the RTPU's line below); pinning with rtpus: {cpu: N} helps meanwhile"
    return "SCHED_FIFO (drop --no-fifo) or pinning with rtpus: {cpu: N} help"


def overrun_lines(subsystem: Any, tasks: dict[str, dict[str, Any]], realtime: dict[str, dict[str, str]] | None = None) -> list[str]:
    """Why each task overran. A late release is the machine's (the RTPU got its CPU late); a long
    cycle is the module's (it ran longer than its period): they call for different remedies.
    `realtime`: what each RTPU reported of its scheduler, so the remedy is not one it already has."""
    lines = []
    for name, t in tasks.items():
        overruns = t.get("overruns", 0)
        if not overruns or name not in subsystem.tasks:
            continue
        period = subsystem.tasks[name].period
        late, long = t.get("overruns_late_release", overruns), t.get("overruns_long_cycle", 0)
        parts = []
        if late:
            remedy = _late_release_remedy((realtime or {}).get(t.get("rtpu", ""), {}).get("scheduler", ""))
            parts.append(f"{late} late release{'s' if late > 1 else ''} (started up to {t['jitter_max'] * 1e3:.2f} ms late: "
                         f"the machine held the RTPU's CPU; {remedy})")
        if long:
            parts.append(f"{long} long cycle{'s' if long > 1 else ''} (ran up to {t['exec_max'] * 1e3:.2f} ms: the module "
                         "needs more than its period; lighten its cycle or lengthen its period)")
        kept = t.get("last_overruns", [])
        when = ", ".join(f"{release:.3f} s" for release, _, _ in kept)
        which = "at" if len(kept) == overruns else f"the last {len(kept)} at"
        lines.append(f"overruns of '{name}' ({period * 1e3:g} ms period): " + "; ".join(parts)
                     + (f"; {which} {when} into the run" if kept else ""))
    return lines


def _print_switches(console: Console, result: Any) -> None:
    """Per switch: latency (request to the first cycle of the new configuration); stale reads."""
    import numpy as np

    if not result.switches:
        return
    latency = np.array([s["latency"] for s in result.switches]) * 1e3
    skew = np.array([s["skew"] for s in result.switches]) * 1e3
    longest = np.array([s["longest"] for s in result.switches]) * 1e3
    console.print(
        f"switches: {len(result.switches)}; latency ms p50 {np.median(latency):.2f}, p99 {np.percentile(latency, 99):.2f}, "
        f"max {latency.max():.2f}; RTPU skew ms max {skew.max():.3f}; longest switch on one RTPU {longest.max():.3f} ms",
        markup=False)
    restarted = [f"{s['sequence']} ({', '.join(s['restarted'])})" for s in result.switches if s.get("restarted")]
    if restarted:  # (their latency includes the restart)
        console.print(f"switches through an RTPU's restart: {', '.join(restarted)}", markup=False)
    windows = [s for s in result.switches if s.get("cycles_lost") or s.get("stale_reads")]
    lost_in = [s["sequence"] for s in windows if any(s.get("cycles_lost", {}).values())]
    if lost_in:
        console.print(f"switches after which the critical task lost a cycle: {', '.join(map(str, lost_in[:20]))}"
                      + (" ..." if len(lost_in) > 20 else ""), markup=False)
    critical = [(n, t) for n, t in result.tasks.items() if t.get("critical")]
    for name, t in critical:
        console.print(f"critical task '{name}': {t['cycles_lost_to_switches']} cycles lost to switches (read an output of a "
                      f"task switched out); {t['stale_reads']} stale reads from late writers ({t['stale_reads_at_switches']} "
                      f"within 3 periods of a switch); {t['stable_cycles']} locally stable cycles"
                      + (f"; last lost: {t['last_cycle_lost']}" if t.get("last_cycle_lost") else "")
                      + (f"; last stale: {t['last_stale_read']}" if t.get("last_stale_read") else ""), markup=False)


def _format_value(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(f"{x:+.4f}" if isinstance(x, float) else str(x) for x in value) + "]"
    return f"{value:+.4f}" if isinstance(value, float) else str(value)
