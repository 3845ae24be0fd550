"""The `pbo` command: check a subsystem file, run it, list the module library, clean up.

Exit status: 0 done, 1 the file has errors, 2 the run failed, 3 an internal error (please
report it). No traceback reaches the user unless --debug is given.
"""

from __future__ import annotations

import argparse
import json
import sys
import traceback
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from pbo_runtime import _registry
from pbo_runtime._errors import ConfigErrors, PboError

EXIT_OK, EXIT_CONFIG, EXIT_RUN, EXIT_INTERNAL = 0, 1, 2, 3


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    console = Console(highlight=False)
    errors = Console(stderr=True, highlight=False)
    if not console.is_terminal:  # logs and CI: wide enough for the summary, no wrapping
        console = Console(highlight=False, width=140)
        errors = Console(stderr=True, highlight=False, width=140)
    try:
        return args.handler(args, console, errors)
    except ConfigErrors as exc:
        errors.print(str(exc), markup=False)
        return EXIT_CONFIG
    except PboError as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_RUN
    except KeyboardInterrupt:
        return 130
    except Exception:
        if getattr(args, "debug", False):
            raise
        errors.print("internal error: pbo failed in a way it should not; please report this with the command you ran:", markup=False)
        errors.print(traceback.format_exc(limit=-3).rstrip(), markup=False)
        return EXIT_INTERNAL


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pbo", description="Reconfigurable real-time control from port-based objects.")
    parser.add_argument("--debug", action="store_true", help="show Python tracebacks of internal errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    check = sub.add_parser("check", help="check a subsystem file like a compiler: every error, with its line")
    check.add_argument("file")
    check.add_argument("--format", choices=("text", "json"), default="text")
    check.set_defaults(handler=_check)

    run = sub.add_parser("run", help="run a subsystem: plant, RTPUs, tasks; prints a summary at the end")
    run.add_argument("file")
    run.add_argument("--duration", type=float, default=5.0, help="seconds to run once the configuration is on (default 5; 0: until Ctrl-C)")
    run.add_argument("--config", help="the configuration to turn on (default: the first in the file)")
    run.add_argument("--report", type=Path, help="write the run report (per task timing, final values) as JSON here")
    run.add_argument("--no-live", action="store_true", help="no live status table (the default when output is not a terminal)")
    run.set_defaults(handler=_run)

    lexicon = sub.add_parser("lexicon", help="list the module library with every module's ports")
    lexicon.set_defaults(handler=_lexicon)

    clean = sub.add_parser("clean", help="remove shared memory, semaphores and queues left by dead runs")
    clean.add_argument("--subsystem", help="only this subsystem's leftovers")
    clean.set_defaults(handler=_clean)
    return parser


# --- pbo check -------------------------------------------------------------------------------


def _check(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime._config_loader import check_file, format_diagnostics

    result = check_file(args.file)
    if args.format == "json":
        console.print_json(json.dumps(_check_json(result)))
    else:
        text = format_diagnostics(result)
        if result.subsystem is not None and not result.errors:
            text = (text + "\n" if result.warnings else "") + _verdict(result.subsystem)
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
    return "\n".join(lines)


def _check_json(result: Any) -> dict[str, Any]:
    def diagnostic(d: Any) -> dict[str, Any]:
        return {"file": d.file, "line": d.line, "column": d.column, "severity": getattr(d, "severity", "error"),
                "message": d.message, "hint": d.hint}

    out: dict[str, Any] = {"ok": not result.errors, "errors": [diagnostic(e) for e in result.errors],
                           "warnings": [diagnostic(w) for w in result.warnings]}
    sub = result.subsystem
    if sub is not None and not result.errors:
        out["subsystem"] = sub.name
        out["init_order"] = list(sub.init_order)
        out["configurations"] = {
            name: {t: sub.tasks[t].rtpu for t in c.tasks} for name, c in sub.configurations.items()
        }
    return out


# --- pbo run ---------------------------------------------------------------------------------


def _run(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime._config_loader import load_subsystem
    from pbo_runtime._supervisor import Supervisor

    subsystem = load_subsystem(args.file)
    live = console.is_terminal and not args.no_live
    duration = args.duration if args.duration > 0 else None
    say = lambda text: console.print(f"[dim]pbo:[/dim] {text}", markup=True)  # noqa: E731
    say(f"starting subsystem '{subsystem.name}' ({len(subsystem.rtpus)} RTPUs, plant: "
        f"{subsystem.plant.model if subsystem.plant else 'none'}); "
        f"{'Ctrl-C stops it' if duration is None else f'runs {duration:g} s, Ctrl-C stops it sooner'}")
    if live:
        with Live(console=console, refresh_per_second=4, transient=True) as view:
            supervisor = Supervisor(subsystem, args.config, duration, on_tick=lambda s: view.update(_status_table(s)), say=say)
            result = supervisor.run()
    else:
        supervisor = Supervisor(subsystem, args.config, duration, say=say)
        result = supervisor.run()
    if args.report:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        args.report.write_text(json.dumps(result.to_json(), indent=2))
    _print_summary(console, subsystem, result)
    if result.failure:
        errors.print(f"error: {result.failure}", markup=False)
        return EXIT_RUN
    return EXIT_OK


def _status_table(supervisor: Any) -> Table:
    import time

    elapsed = time.monotonic() - supervisor.started_at if supervisor.started_at else 0.0
    table = Table(title=f"{supervisor.subsystem.name} · {supervisor.configuration} · {elapsed:5.1f} s", title_justify="left")
    for column in ("task", "rtpu", "state", "cycles", "overruns", "exec µs", "max jitter µs"):
        table.add_column(column, justify="right" if column not in ("task", "rtpu", "state") else "left")
    for row in supervisor.status_rows():
        if row["state"] == "NOT_CREATED":
            continue
        colour = {"ON": "green", "ERROR": "bold red", "OFF": "yellow"}.get(row["state"], "white")
        table.add_row(row["task"], row["rtpu"], f"[{colour}]{row['state']}[/]", str(row["cycles"]), str(row["overruns"]),
                      f"{row['exec_last'] * 1e6:.0f}", f"{row['jitter_max'] * 1e6:.0f}")
    return table


def _print_summary(console: Console, subsystem: Any, result: Any) -> None:
    table = Table(title=f"run summary: {subsystem.name} · {result.configuration} · {result.duration:.2f} s "
                        f"(stopped by {result.stopped_by})", title_justify="left")
    for column in ("task", "rtpu", "state", "cycles", "rate Hz", "overruns", "jitter p50 µs", "jitter p99 µs",
                   "exec p50 µs", "exec p99 µs"):
        table.add_column(column, justify="left" if column in ("task", "rtpu", "state") else "right")
    for name, t in result.tasks.items():
        if not t.get("cycles") and t.get("state") != "ERROR":
            continue
        rate = t["cycles"] / result.duration if result.duration else 0.0
        table.add_row(name, t["rtpu"], t["state"], str(t["cycles"]), f"{rate:.0f}", str(t["overruns"]),
                      f"{t['jitter_p50'] * 1e6:.0f}", f"{t['jitter_p99'] * 1e6:.0f}",
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
    if result.plant:
        console.print(f"plant: {result.plant.get('steps', 0)} steps, {result.plant.get('late', 0)} late", markup=False)


def _format_value(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(f"{x:+.4f}" if isinstance(x, float) else str(x) for x in value) + "]"
    return f"{value:+.4f}" if isinstance(value, float) else str(value)


# --- pbo lexicon, pbo clean --------------------------------------------------------------------


def _lexicon(args: argparse.Namespace, console: Console, errors: Console) -> int:
    table = Table(title="module library (entry points 'pbo.modules')", title_justify="left")
    for column in ("module", "port", "kind", "variable", "dtype", "shape"):
        table.add_column(column)
    for name in _registry.names(_registry.MODULES):
        cls = _registry.module_class(name)
        first = True
        for port in cls.ports():
            shape = "as variable" if port.shape is None else "[" + ", ".join(map(str, port.shape)) + "]"
            table.add_row(name if first else "", port.name, port.kind.value, port.variable, port.dtype, shape)
            first = False
        if first:
            table.add_row(name, "(ports from params)", "", "", "", "")
        doc = (cls.__doc__ or "").strip().splitlines()
        table.add_row("", f"[dim]{doc[0] if doc else ''}[/dim]", "", "", "", "", end_section=True)
    console.print(table)
    return EXIT_OK


def _clean(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime._supervisor import remove_dead_runs

    removed = remove_dead_runs(args.subsystem) if args.subsystem else remove_dead_runs_all()
    console.print(f"removed {len(removed)} object(s) left by dead runs" + (": " + ", ".join(removed) if removed else ""), markup=False)
    return EXIT_OK


def remove_dead_runs_all() -> list[str]:
    from pbo_runtime import _shm
    from pbo_runtime._supervisor import remove_dead_runs

    subsystems = {name[1:].split(".")[1] for _, name in _shm.stale_objects(None)}
    return sorted(r for s in subsystems for r in remove_dead_runs(s))


if __name__ == "__main__":
    sys.exit(main())
