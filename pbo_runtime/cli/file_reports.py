"""`pbo bus`, `lexicon`, `place`, `graph`, `schema`: what pbo tells about a file, or the module library, offline."""

from __future__ import annotations

import argparse
import json

from rich.console import Console

from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_OK
from pbo_runtime.errors import require_extra


def bus(args: argparse.Namespace, console: Console, errors: Console) -> int:
    if args.plot:
        require_extra("matplotlib", "pbo bus --plot")
    from pbo_runtime.analysis import bus
    from pbo_runtime.config import bus_model
    from pbo_runtime.config.loader import load_subsystem

    subsystem = load_subsystem(args.file)
    if args.config and args.config not in subsystem.configurations:
        errors.print(f"error: no configuration '{args.config}' in {args.file} "
                     f"(configurations: {', '.join(subsystem.configurations)})", markup=False)
        return EXIT_CONFIG
    names = [args.config] if args.config else list(subsystem.configurations)
    reports = {name: bus_model.predict(subsystem, name) for name in names}
    seen = None
    if args.run_report:
        seen = bus.measured(subsystem, json.loads(args.run_report.read_text()))
    documents = []
    for name, report in reports.items():
        measured = seen if seen is not None and seen.configuration == name else None
        if args.format == "table":
            console.print(bus.as_table(report, measured))
        elif args.format == "json":
            documents.append(bus.as_json(report, measured))
        else:
            console.out(bus.as_csv(report, measured), end="")
    if args.format == "json":
        console.out(json.dumps(documents[0] if len(documents) == 1 else documents, indent=2))
    if args.combine:
        members = [m.strip() for m in args.combine.split(",") if m.strip()]
        before, after = bus.combined_saving(subsystem, names[0], members)
        if args.format == "table":
            console.print(bus.as_table(after))
        console.print(bus.describe_saving(before, after), markup=False)
    if args.plot:
        bus.plot(reports, args.plot, measured=[seen] if seen is not None else None)
        console.print(f"wrote {args.plot}", markup=False)
    over = [name for name, report in reports.items() if report.over]
    if over:
        errors.print(f"error: over the bus bandwidth: {', '.join(over)}", markup=False)
        return EXIT_CONFIG
    return EXIT_OK


def lexicon(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.lexicon import as_table, drivers, drivers_table, lexicon

    entries = drivers() if args.drivers else lexicon()
    if args.format == "json":
        console.out(json.dumps(entries, indent=2, default=str))
    elif args.drivers:
        console.print(drivers_table(entries))
    else:
        console.print(as_table(entries))
        console.print("device drivers: pbo lexicon --drivers", markup=False)
    return EXIT_OK


def place(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.analysis.placement import placement_report
    from pbo_runtime.config.loader import load_subsystem

    subsystem = load_subsystem(args.file)
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()] if args.tasks is not None else None
    try:
        report = placement_report(subsystem, args.config, tasks=tasks, rtpu=args.rtpu, modules=args.module)
    except ValueError as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    if args.format == "json":
        console.out(json.dumps(report, indent=2))
        return EXIT_OK
    where = f"configuration '{report['configuration']}'" if report["configuration"] else "tasks " + ", ".join(report["tasks"])
    lines = [f"{args.file}: {where} on {report['rtpu']}: {report['legal']} of {len(report['modules'])} modules can be placed"]
    width = max((len(m["module"]) for m in report["modules"]), default=0)
    for m in report["modules"]:
        if m["legal"]:
            notes = []
            if m["new_variables"]:
                notes.append("new variables: " + ", ".join(m["new_variables"]))
            if m["open_inputs"]:
                notes.append("inputs nobody writes yet: " + ", ".join(m["open_inputs"]))
            lines.append(f"  ok  {m['module']:<{width}}" + (f"  ({'; '.join(notes)})" if notes else ""))
        else:
            lines.append(f"  no  {m['module']:<{width}}  [{m['code']}] {m['reason']}")
    console.print("\n".join(lines), markup=False, highlight=False, soft_wrap=True)
    return EXIT_OK


def graph(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.reports.graph import draw, to_dot

    subsystem = load_subsystem(args.file)
    try:
        if args.output:
            if args.output.suffix.lower() != ".dot":
                require_extra("matplotlib", f"pbo graph -o {args.output.name}")
            draw(subsystem, args.config, args.output)
            console.print(f"wrote {args.output}", markup=False)
        else:
            console.out(to_dot(subsystem, args.config), end="")
    except ValueError as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    return EXIT_OK


def schema(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.schema import schema_text, write_schema

    if args.output:
        write_schema(args.output)
        console.print(f"wrote {args.output}", markup=False)
    else:
        console.out(schema_text(), end="")
    return EXIT_OK
