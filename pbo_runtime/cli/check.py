"""`pbo check FILE`: every error of a subsystem or application file, with its line; what the file makes when it has none."""

from __future__ import annotations

import argparse
import json
from typing import Any

from rich.console import Console

from pbo_runtime.cli.arguments import host_addresses
from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_OK
from pbo_runtime.config.decisions import decides, paths
from pbo_runtime.config.transitions import transitions, transitions_of
from pbo_runtime.edit.job_dictionary import dictionary_lines, job_dictionary


def check(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.config.file_kind import is_application_file
    from pbo_runtime.config.loader import check_file, format_diagnostics

    if is_application_file(args.file):
        if args.profile:
            errors.print(f"error: --profile takes a subsystem file, and {args.file} is an application: check each of its "
                         "subsystem files with the report of its own run", markup=False)
            return EXIT_CONFIG
        return _check_application(args, console, errors)
    result = check_file(args.file)
    refuted, timing = EXIT_OK, dict[str, Any]()  # the verdicts of --profile, for --format json
    if args.format == "json":
        if args.profile and result.subsystem is not None and not result.errors:
            from pbo_runtime.cli import schedule

            refuted, timing = schedule.check_profile(args, console, errors, result.subsystem)
        console.print_json(json.dumps({**_check_json(result), **({"schedulability": timing} if timing else {})}))
    else:
        text = format_diagnostics(result)
        if result.subsystem is not None and not result.errors:
            text = (text + "\n" if result.warnings else "") + _verdict(result.subsystem) + _inferred_lines(result)
        (errors if result.errors else console).print(text, markup=False)
        if args.profile and result.subsystem is not None and not result.errors:
            from pbo_runtime.cli import schedule

            refuted, _ = schedule.check_profile(args, console, errors, result.subsystem)
    return EXIT_CONFIG if result.errors or refuted else EXIT_OK


def _check_application(args: argparse.Namespace, console: Console, errors: Console) -> int:
    """An application file: each subsystem's file in full, then its links against their tasks."""
    from pbo_runtime.config.application import check_application
    from pbo_runtime.config.loader import CheckResult, format_diagnostics
    from pbo_runtime.config.parallel import stage_lines

    addresses = host_addresses(args)
    if isinstance(addresses, str):
        errors.print(f"error: {addresses}", markup=False)
        return EXIT_CONFIG
    result = check_application(args.file, addresses)
    if args.format == "json":
        console.print_json(json.dumps({"file": args.file, "ok": result.ok,
                                       "errors": [_diagnostic_json(e) for e in result.errors],
                                       "warnings": [_diagnostic_json(w) for w in result.warnings]}))
        return EXIT_CONFIG if result.errors else EXIT_OK
    text = format_diagnostics(CheckResult(None, result.errors, result.warnings))
    if result.application is not None:
        app = result.application
        lines = [f"{args.file}: ok: application '{app.name}', {len(app.subsystems)} subsystems, {len(app.links)} link(s)"]
        for key, sub in app.subsystems.items():
            runs = "".join(
                f", runs {'application' if k == 'app' else 'configuration'} '{v}'" for k, v in app.run.get(key, {}).items()
            )
            where = f" on {app.placement[key]} ({app.hosts[app.placement[key]]})" if key in app.placement else ""
            lines.append(f"  subsystem {key}: {sub.file} ('{sub.name}', {len(sub.tasks)} task(s){runs}){where}")
        # run: as parallel stages, joined one after another
        lines.extend(stage_lines(app.stages, app.subsystems, _transition_lines))
        for link in app.links.values():
            kind = f"messages, {link.capacity} queued at most" if link.kind == "message" else "periodic"
            lines.append(f"  link {link.name}: {link.sender[0]}.{link.sender[1]} -> {link.receiver[0]}.{link.receiver[1]} "
                         f"({link.dtype} {list(link.shape)}, {kind}, {link.transport})")
        text = (text + "\n" if result.warnings else "") + "\n".join(lines)
    (errors if result.errors else console).print(text, markup=False)
    return EXIT_CONFIG if result.errors else EXIT_OK


def _verdict(subsystem: Any) -> str:
    lines = [f"{subsystem.file}: ok: subsystem '{subsystem.name}', {len(subsystem.variables)} variables, "
             f"{len(subsystem.tasks)} tasks, {len(subsystem.configurations)} configuration(s)"]
    for name, configuration in subsystem.configurations.items():
        by_rtpu: dict[str, list[str]] = {}
        for task in configuration.tasks:
            by_rtpu.setdefault(subsystem.tasks[task].rtpu, []).append(task)
        placed = "; ".join(f"{rtpu}: {', '.join(tasks)}" for rtpu, tasks in by_rtpu.items())
        lines.append(f"  configuration '{name}': {placed}")
    lines.append(f"  init order: {' -> '.join(subsystem.init_order)}")
    for application in subsystem.applications:
        lines.append(f"  application '{application}':")
        if not decides(subsystem, application):
            lines.extend(_transition_lines(transitions(subsystem, application), "    "))
            continue
        listed, every = paths(subsystem, application)
        for number, path in enumerate(listed, 1):
            lines.append(f"    path {number}: {path.label}")
            lines.extend(_transition_lines(transitions_of(subsystem, path.jobs), "      "))
        if every > len(listed):
            lines.append(f"    ... and {every - len(listed)} more path(s)")
    if subsystem.jobs:
        lines.append("  job dictionary:")
        lines.extend(f"    {line}" for line in dictionary_lines(subsystem))
    return "\n".join(lines)


def _transition_lines(steps: list[Any], indent: str) -> list[str]:
    """The switch table of one path: what each job turns off and on."""
    lines = []
    for t in steps:
        if t.before is None:
            lines.append(f"{indent}{t.step}. {t.job}: configuration '{t.after}' on: {', '.join(t.on) or 'nothing'}")
        elif t.before == t.after:
            lines.append(f"{indent}{t.step}. {t.job}: stays in '{t.after}' (new object only)")
        else:
            lines.append(f"{indent}{t.step}. {t.job}: '{t.before}' -> '{t.after}': off {', '.join(t.off) or 'nothing'}; "
                         f"on {', '.join(t.on) or 'nothing'}")
    return lines


def _inferred_lines(result: Any) -> str:
    """What the file left out and the check worked out: dims from the plant's robot, variables from their ports."""
    lines = []
    sub = result.subsystem
    if result.robot_dims:
        model = sub.plant.model if sub.plant is not None else "?"
        lines.append(f"  dims from the plant's robot '{model}': " + ", ".join(f"{k} = {v}" for k, v in result.robot_dims.items()))
    lines += [f"  {note}" for note in result.robot_notes]
    lines += limit_lines(result.robot_limits)
    if result.inferred:
        lines.append(f"  inferred from their ports: {len(result.inferred)} variable(s)")
        width = max(len(name) for name in result.inferred)
        for name in result.inferred:
            v = sub.variables[name]
            lines.append(f"    {name:<{width}}  {v.dtype:<7}  {list(v.shape)}")
    return "".join("\n" + line for line in lines)


def limit_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The robot's limits, a joint a line: what the robot interface clips commands to and brakes past."""
    if not rows:
        return []
    cells = [(str(r["joint"]), f"{r['effort']:g} {'N' if r['unit'] == 'm' else 'N m'}",
              f"{r['velocity']:g} {r['unit']}/s" if r["velocity"] is not None else "none given",
              f"[{r['lower']:.4g}, {r['upper']:.4g}] {r['unit']}" if r["lower"] is not None else "none (continuous)")
             for r in rows]
    widths = [max(len(row[i]) for row in [("joint", "effort", "velocity", "range"), *cells]) for i in range(3)]
    lines = ["  the robot's limits (commands are clipped to them; a joint past them is a fault):"]
    for row in [("joint", "effort", "velocity", "range"), *cells]:
        lines.append("    " + "  ".join(cell.ljust(width) for cell, width in zip(row[:3], widths, strict=True)) + "  " + row[3])
    return lines


def _inferred_json(result: Any) -> dict[str, Any]:
    """The same, for --format json: present only when the file relies on it."""
    out: dict[str, Any] = {}
    if result.robot_dims:
        out["robot_dims"] = dict(result.robot_dims)
    if result.robot_notes:
        out["robot_notes"] = list(result.robot_notes)
    if result.robot_limits:
        out["robot_limits"] = list(result.robot_limits)
    if result.inferred:
        variables = result.subsystem.variables
        out["inferred"] = {
            name: {"type": variables[name].dtype, "shape": list(variables[name].shape)} for name in result.inferred
        }
    return out


def _diagnostic_json(d: Any) -> dict[str, Any]:
    return {"file": d.file, "line": d.line, "column": d.column, "severity": d.severity, "code": d.code,
            "message": d.message, "hint": d.hint,
            "notes": [{"file": n.file, "line": n.line, "column": n.column, "message": n.message} for n in d.notes]}


def _check_json(result: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"ok": not result.errors, "errors": [_diagnostic_json(e) for e in result.errors],
                           "warnings": [_diagnostic_json(w) for w in result.warnings]}
    sub = result.subsystem
    if sub is not None and not result.errors:
        out["subsystem"] = sub.name
        out["init_order"] = list(sub.init_order)
        out["configurations"] = {
            name: {t: sub.tasks[t].rtpu for t in c.tasks} for name, c in sub.configurations.items()
        }
        dictionary = job_dictionary(sub)  # Onika's job dictionary: classes, object types and edges
        out["object_types"] = dictionary["object_types"]
        out["objects"] = dictionary["objects"]
        out["jobs"] = dictionary["jobs"]
        out["applications"] = dictionary["applications"]
        for app, entry in out["applications"].items():
            entry["transitions"] = [
                {"step": t.step, "job": t.job, "from": t.before, "to": t.after, "off": list(t.off), "on": list(t.on)}
                for t in transitions(sub, app)]
            if decides(sub, app):
                entry["paths"] = [{"label": path.label, "jobs": list(path.jobs), "transitions": [
                    {"step": t.step, "job": t.job, "from": t.before, "to": t.after, "off": list(t.off), "on": list(t.on)}
                    for t in transitions_of(sub, path.jobs)]} for path in paths(sub, app)[0]]
        out.update(_inferred_json(result))
    return out
