"""`pbo check FILE --profile RUN` and `pbo allocate FILE --profile RUN`: measured execution times against deadlines.

The profile is a run's report (report.json in the run's directory, which `pbo run` prints): each
task's longest cycle (`exec_max`) or 99th percentile (`exec_p99`). The analysis itself is
`analysis.schedulability`; the search for an assignment, `analysis.allocation`. docs/scheduling.md
explains the model and how to read the verdicts.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rich.console import Console

from pbo_runtime.analysis.allocation import period_needed, pinned_tasks, propose
from pbo_runtime.analysis.schedulability import (
    MAY_MISS,
    MEETS,
    PROVEN,
    REFUTED,
    UNKNOWN,
    Cost,
    Verdict,
    analyse,
    analyse_configuration,
    measured_configurations,
)
from pbo_runtime.config.model import Subsystem
from pbo_runtime.errors import ConfigError, ConfigErrors

EXEC_TIMES = {"max": "exec_max", "p99": "exec_p99"}
EXEC_MEANING = {"max": "the longest cycle measured: safe", "p99": "the 99th percentile: 1 cycle in 100 may take longer"}
MODEL = "non-preemptive: critical first, then earliest deadline; a cycle runs to its end"


def load_profile(path: Path, subsystem: Subsystem, exec_time: str) -> tuple[dict[str, Cost], list[str], Path]:
    """(costs, notes, the report's path): each task's C from a run report, or its wcet: where it did not run.

    A report that cannot be read, of another subsystem, or with a task the file does not have is
    a ConfigErrors (exit 1): the verdicts would be about some other file.
    """
    report_path = path / "report.json" if path.is_dir() else path

    def refuse(message: str, hint: str) -> ConfigErrors:
        return ConfigErrors([ConfigError(message, str(report_path), hint=hint)])

    run_hint = "give the report of a run of this file: `pbo run FILE` prints its directory (runs/SUBSYSTEM-DATE-TIME/)"
    try:
        report = json.loads(report_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise refuse("no such profile (a run's report.json, or the run's directory)", run_hint) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise refuse(f"cannot read the profile: {exc}", run_hint) from None
    except json.JSONDecodeError as exc:
        raise refuse(f"the profile is not JSON: {exc}", run_hint) from None
    if not isinstance(report, dict) or not isinstance(report.get("tasks"), dict) or "subsystem" not in report:
        raise refuse("the profile is not a run report (it has no 'subsystem' and 'tasks')", run_hint)
    if report["subsystem"] != subsystem.name:
        raise refuse(f"the profile is a run of subsystem '{report['subsystem']}', not of '{subsystem.name}' "
                     f"({subsystem.file})", run_hint)
    unknown = sorted(set(report["tasks"]) - set(subsystem.tasks))
    if unknown:
        raise refuse(f"the profile has task{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} that "
                     f"{subsystem.file} does not have", "the file changed since the run: run it again and profile that run")
    key = EXEC_TIMES[exec_time]
    costs: dict[str, Cost] = {}
    for name, spec in subsystem.tasks.items():
        figures = report["tasks"].get(name)
        figures = figures if isinstance(figures, dict) else {}
        if isinstance(figures.get("cycles"), int) and figures["cycles"] > 0 and isinstance(figures.get(key), (int, float)):
            costs[name] = Cost(float(figures[key]), key)
        elif spec.wcet is not None:
            costs[name] = Cost(spec.wcet, "wcet")
    notes = []
    if report.get("clock") == "sim":
        notes.append("the profile is a run on the simulated clock: its execution times are simulated (a cycle takes "
                     "no simulated time), not measured; profile a run on the real clock for verdicts that mean something")
    return costs, notes, report_path


def _ms(seconds: float | None) -> str:
    if seconds is None:
        return "?"
    if seconds == float("inf"):
        return "unbounded"
    return f"{seconds * 1e3:.3f} ms"


def verdict_lines(results: Mapping[str, Mapping[str, list[Verdict]]]) -> list[str]:
    """Per configuration, per RTPU, per task: C, T = D, R, the verdict, the blocking task (critical tasks starred)."""
    lines = []
    for configuration, by_rtpu in results.items():
        lines.append(f"configuration '{configuration}':")
        for rtpu, verdicts in by_rtpu.items():
            lines.append(f"  {rtpu}:")
            width = max(len(v.task) + v.critical for v in verdicts)
            lines.append(f"    {'task':<{width}}  {'C':>10}  {'T = D':>10}  {'R':>10}  {'verdict':<8}  blocked by")
            for v in verdicts:
                name = v.task + ("*" if v.critical else "")
                source = f" ({v.cost.source})" if v.cost is not None and v.cost.source == "wcet" else ""
                response = v.response
                blocked = f"{response.blocked_by} ({_ms(response.blocking)})" if response and response.blocked_by else "-"
                lines.append(f"    {name:<{width}}  {_ms(v.cost.seconds if v.cost else None):>10}  {_ms(v.period):>10}  "
                             f"{_ms(response.time if response else None):>10}  {v.status:<8}  {blocked}{source}")
    return lines


def diagnostics(subsystem: Subsystem, costs: Mapping[str, Cost], results: Mapping[str, Mapping[str, list[Verdict]]],
                profile: Path) -> tuple[list[ConfigError], list[ConfigError]]:
    """(errors, warnings): a refuted critical deadline is an error at its task, with a remedy; an unproven one a warning."""
    errors: list[ConfigError] = []
    warnings: list[ConfigError] = []
    seen: set[tuple[str, frozenset[str]]] = set()
    kept = pinned_tasks(subsystem)
    for configuration, by_rtpu in results.items():
        for rtpu, verdicts in by_rtpu.items():
            key_tasks = frozenset(v.task for v in verdicts)
            for v in verdicts:
                if (v.task, key_tasks) in seen or v.status in (PROVEN, MEETS):
                    continue
                seen.add((v.task, key_tasks))
                loc = v.spec.loc
                where = f"in configuration '{configuration}'"
                if v.status == REFUTED:
                    assert v.response is not None and v.cost is not None
                    blocked = (f", blocked {_ms(v.response.blocking)} by '{v.response.blocked_by}'"
                               if v.response.blocked_by else "")
                    errors.append(ConfigError(
                        f"critical task '{v.task}' can miss its deadline on RTPU '{rtpu}' {where}: {_late(v, verdicts)} "
                        f"(C = {_ms(v.cost.seconds)}{blocked})",
                        loc.file, loc.line, loc.column,
                        hint=_remedy(subsystem, costs, configuration, v, kept, verdicts, profile)))
                elif v.status == MAY_MISS and v.response is not None:
                    warnings.append(
                        ConfigError(
                            f"task '{v.task}' can miss its deadline on RTPU '{rtpu}' {where}: {_late(v, verdicts)}",
                            loc.file,
                            loc.line,
                            loc.column,
                            hint="not critical: the executive runs it after every critical cycle; it overruns, "
                            "the critical tasks do not",
                            severity="warning",
                        )
                    )
                elif v.status == UNKNOWN and v.critical:
                    missing = [u.task for u in verdicts if u.cost is None]
                    warnings.append(ConfigError(
                        f"critical task '{v.task}' on RTPU '{rtpu}' {where} is not analysed: no execution time for "
                        f"{', '.join(map(repr, missing))}", loc.file, loc.line, loc.column,
                        hint=f"{'they' if len(missing) > 1 else 'it'} did not run in {profile}: profile a run of "
                             f"configuration '{configuration}' (pbo run FILE --config {configuration}), or declare a wcet:",
                        severity="warning"))
    return errors, warnings


def _late(v: Verdict, verdicts: list[Verdict]) -> str:
    """'response time 1.1 ms > deadline 1 ms', or why there is no response time: the load it waits behind."""
    assert v.response is not None
    if v.response.time != float("inf"):
        return f"response time {_ms(v.response.time)} > deadline {_ms(v.period)}"
    waited = [u for u in verdicts if u.critical or not v.critical]  # a critical task waits for critical cycles only
    load = sum(u.cost.seconds / u.period for u in waited if u.cost is not None)
    return (f"its response time is unbounded: the {'critical ' if v.critical else ''}tasks of the RTPU need more than "
            f"it has (U = {load:.2f} > 1)")


def _remedy(subsystem: Subsystem, costs: Mapping[str, Cost], configuration: str, v: Verdict,
            kept: Mapping[str, str], verdicts: list[Verdict], profile: Path) -> str:
    """One move that proves every critical deadline of this configuration, or the period that would do."""
    ways = []
    if all(t in costs for t in subsystem.configurations[configuration].tasks):
        found = propose(subsystem, costs, [configuration], kept, max_moves=1).proposal
        if found is not None and found.moves:
            [(task, (_, to))] = found.moves.items()
            ways.append(f"move task '{task}' to RTPU '{to}'")
    period = period_needed([u.spec for u in verdicts], costs, v.task)
    if period is not None:
        ways.append(f"lengthen the period of '{v.task}' to {_ms(period)}")
    if v.response is not None and v.response.blocked_by:
        ways.append(f"shorten the cycle of '{v.response.blocked_by}'")
    return (", or ".join(ways) or "make fewer tasks critical on this RTPU") + \
        f"; `pbo allocate {subsystem.file} --profile {profile}` proposes an assignment for every configuration"


def check_profile(args: Any, console: Console, errors: Console, subsystem: Subsystem) -> tuple[int, dict[str, Any]]:
    """`pbo check FILE --profile RUN`: print (or return, for --format json) the verdicts; exit 1 on a
    refuted critical deadline."""
    costs, notes, report = load_profile(Path(args.profile), subsystem, args.exec_time)
    results = analyse(subsystem, costs)
    found, warned = diagnostics(subsystem, costs, results, report)
    if args.format == "json":
        return (1 if found else 0), _json(args.exec_time, report, results, found, warned, notes)
    key = EXEC_TIMES[args.exec_time]
    lines = [f"schedulability ({MODEL}), C = {key} of {report} ({EXEC_MEANING[args.exec_time]}):"]
    lines += [f"note: {n}" for n in notes]
    lines += verdict_lines(results)
    console.print("\n".join(lines), markup=False, highlight=False, soft_wrap=True)
    verdicts = [v for by_rtpu in results.values() for vs in by_rtpu.values() for v in vs if v.critical]
    counted = {s: len({v.task for v in verdicts if v.status == s}) for s in (PROVEN, REFUTED, UNKNOWN)}
    summary = (f"critical deadlines: {counted[PROVEN]} task(s) proven, {counted[REFUTED]} refuted, "
               f"{counted[UNKNOWN]} not analysed")
    (errors if found else console).print("\n".join([*(d.format() for d in [*found, *warned]), summary]), markup=False,
                                          highlight=False, soft_wrap=True)
    return (1 if found else 0), {}


def _json(exec_time: str, report: Path, results: Mapping[str, Mapping[str, list[Verdict]]],
          found: list[ConfigError], warned: list[ConfigError], notes: list[str]) -> dict[str, Any]:
    def one(v: Verdict) -> dict[str, Any]:
        r = v.response
        return {"task": v.task, "critical": v.critical, "C": v.cost.seconds if v.cost else None,
                "C_from": v.cost.source if v.cost else None, "T": v.period, "D": v.period,
                "R": (None if r is None or r.time == float("inf") else r.time), "verdict": v.status,
                "blocked_by": r.blocked_by if r else "", "blocking": r.blocking if r else 0.0}

    def diagnostic(d: ConfigError) -> dict[str, Any]:
        return {"file": d.file, "line": d.line, "column": d.column, "severity": d.severity, "message": d.message, "hint": d.hint}

    return {"profile": str(report), "exec_time": EXEC_TIMES[exec_time], "model": MODEL, "notes": notes,
            "configurations": {c: {rtpu: [one(v) for v in vs] for rtpu, vs in by_rtpu.items()} for c, by_rtpu in results.items()},
            "errors": [diagnostic(d) for d in found], "warnings": [diagnostic(d) for d in warned]}


# --- pbo allocate ------------------------------------------------------------------------------


def allocate(args: Any, console: Console, errors: Console) -> int:
    """`pbo allocate FILE --profile RUN`: the fewest moves that prove every critical deadline, as YAML lines to change."""
    from pbo_runtime.config.loader import load_subsystem

    subsystem = load_subsystem(args.file)
    pins = [p.strip() for item in args.pin or [] for p in item.split(",") if p.strip()]
    free = [p.strip() for item in args.free or [] for p in item.split(",") if p.strip()]
    for name in (*pins, *free):
        if name not in subsystem.tasks:
            errors.print(f"error: no task '{name}' in {args.file} (tasks: {', '.join(subsystem.tasks)})", markup=False)
            return 1
    costs, notes, report = load_profile(Path(args.profile), subsystem, args.exec_time)
    judged = measured_configurations(subsystem, costs)
    if args.config:
        if args.config not in subsystem.configurations:
            errors.print(f"error: no configuration '{args.config}' in {args.file} "
                         f"(configurations: {', '.join(subsystem.configurations)})", markup=False)
            return 1
        judged = [c for c in judged if c == args.config]
    skipped = [c for c in (subsystem.configurations if not args.config else [args.config]) if c not in judged]
    for c in skipped:
        missing = [t for t in subsystem.configurations[c].tasks if t not in costs]
        notes.append(f"configuration '{c}' is not judged: no execution time for {', '.join(map(repr, missing))} "
                     f"(profile a run of it, or declare a wcet:); its tasks only move where another configuration moves them")
    key = EXEC_TIMES[args.exec_time]
    out = [f"allocation ({MODEL}), C = {key} of {report} ({EXEC_MEANING[args.exec_time]}):"]
    out += [f"note: {n}" for n in notes]
    if not judged:
        errors.print("\n".join([*out, f"error: no configuration of {args.file} has an execution time for every task"]),
                     markup=False, soft_wrap=True)
        return 1
    kept = pinned_tasks(subsystem, pins, free)
    search = propose(subsystem, costs, judged, kept)
    if search.proposal is None:
        why = (f"the search gave up after {search.tried:,} partial assignments" if search.gave_up else
               "no assignment of the tasks to the RTPUs proves every critical deadline")
        held = "; ".join(f"'{t}' {reason}" for t, reason in kept.items() if t in subsystem.tasks)
        errors.print("\n".join([
            *out,
            f"error: {why} of configuration(s) {', '.join(map(repr, judged))} on {len(subsystem.rtpus)} RTPU(s)"
            + (f" (kept: {held})" if held else ""),
            "  hint: lengthen a period, shorten a cycle, add an RTPU to `rtpus:`, or free a kept task (--free TASK)"]),
            markup=False, soft_wrap=True)
        return 1
    proposal = search.proposal
    if not proposal.moves:
        out.append(f"{args.file}: the given assignment already proves every critical deadline"
                   + ("" if proposal.every_deadline else " (some non-critical tasks may miss theirs: no assignment avoids it)")
                   + "; nothing to change")
    else:
        out.append(f"{args.file}: move {len(proposal.moves)} task(s) to prove every critical deadline"
                   + (" (and every other deadline)" if proposal.every_deadline else
                      " (some non-critical tasks may still miss theirs: no assignment avoids it)") + ":")
        for task, (before, after) in proposal.moves.items():
            out += _yaml_change(subsystem, task, before, after)
    out += verdict_lines({c: analyse_configuration(subsystem, c, costs, proposal.placement) for c in judged})
    console.print("\n".join(out), markup=False, highlight=False, soft_wrap=True)
    return 0


def _yaml_change(subsystem: Subsystem, task: str, before: str, after: str) -> list[str]:
    """The line of the task's `rtpu:` as it is and as it should be, or where the task is when that line is not found."""
    loc = subsystem.tasks[task].loc
    pattern = re.compile(rf"(\brtpu:\s*)['\"]?{re.escape(before)}['\"]?(?=[\s,}}]|$)")
    try:
        lines = Path(loc.file).read_text(encoding="utf-8").splitlines()
    except OSError:
        lines = []
    for number in range(loc.line, min(loc.line + 8, len(lines)) + 1):
        text = lines[number - 1]
        if pattern.search(text):
            return [f"  {loc.file}:{number}: task '{task}': rtpu {before} -> {after}",
                    f"    - {text.strip()}", f"    + {pattern.sub(lambda m: m.group(1) + after, text, count=1).strip()}"]
    return [f"  {loc}: task '{task}': set rtpu: {after} (now {before})"]
