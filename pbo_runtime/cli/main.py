"""The `pbo` command: check a subsystem file, run it, list the module library, copy out the examples, clean up.

Exit status: 0 done, 1 the file has errors (or an operator command's arguments were refused),
2 the run failed, 3 an internal error (please report it). No traceback reaches the user unless --debug is given.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Callable

from rich.console import Console
from rich.markup import escape
from rich.live import Live
from rich.table import Table

from pbo_runtime.cli import robot, schedule
from pbo_runtime.cli.arguments import ArgumentParser
from pbo_runtime.cli.completion import HIDDEN_VERB, complete
from pbo_runtime.clock.clocks import scheduler_outcome
from pbo_runtime.objects import registry
from pbo_runtime.errors import ConfigErrors, MissingExtra, PboError, require_extra
from pbo_runtime.ipc.control import BadRequest
from pbo_runtime.supervisor.failures import WrongArgument
from pbo_runtime.supervisor.run_options import Alternation, RunOptions
from pbo_runtime.config.decisions import decides, paths
from pbo_runtime.config.transitions import transitions, transitions_of
from pbo_runtime.config.job_dictionary import dictionary_lines, job_dictionary

EXIT_OK, EXIT_CONFIG, EXIT_RUN, EXIT_INTERNAL = 0, 1, 2, 3
FORMAT_HELP = ("json: print the reply as JSON, a refusal too ({\"ok\": false, \"error\": ...}), on stdout; "
               "the exit status is the same")


def main(argv: list[str] | None = None) -> int:
    entered = time.monotonic()  # the start-up's time line (`pbo run`): the CLI's imports end here
    # MuJoCo without its OpenGL context: nothing pbo runs renders, and importing it loads GLFW (0.1-0.3 s
    # per process: the CLI, the plant, each RTPU). A module that renders sets MUJOCO_GL (egl, glfw) itself.
    os.environ.setdefault("MUJOCO_GL", "disable")
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == [HIDDEN_VERB]:  # the shell completing a name at the time of a <TAB>
        return complete(argv[1:])
    parser = _parser()
    args = parser.parse_args(argv)
    args.entered = entered
    console = Console(highlight=False)
    errors = Console(stderr=True, highlight=False, soft_wrap=True)
    if not console.is_terminal:  # logs and CI: wide enough for the summary, no wrapping
        console = Console(highlight=False, width=140)
        errors = Console(stderr=True, highlight=False, width=140, soft_wrap=True)
    try:
        status = args.handler(args, console, errors)
        if status == EXIT_CONFIG:
            _say_where_an_example_is(args, errors)
        return status
    except ConfigErrors as exc:
        errors.print(str(exc), markup=False)
        _say_where_an_example_is(args, errors)
        return EXIT_CONFIG
    except (BadRequest, WrongArgument, MissingExtra) as exc:  # arguments the run refused (an operator's command, `--config nope`): bad input
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    except PboError as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_RUN
    except KeyboardInterrupt:
        return 130
    except (OSError, MemoryError) as exc:  # an OS limit met outside the run (too many open files reading the YAML)
        from pbo_runtime.ipc.limits import explain

        limit = explain(exc, f"pbo {args.command}")
        if limit is None or getattr(args, "debug", False):
            return _internal_error(args, errors)
        errors.print(f"error: {limit}", markup=False)
        return EXIT_RUN
    except Exception:
        return _internal_error(args, errors)


def _say_where_an_example_is(args: argparse.Namespace, errors: Console) -> None:
    """A FILE that is not there but names a shipped example (a command copied from a comment): where it is."""
    from pbo_runtime.cli.examples import missing_example_hint

    hint = missing_example_hint(args.file) if isinstance(getattr(args, "file", None), str) else None
    if hint is not None:
        errors.print(hint, markup=False)


def _internal_error(args: argparse.Namespace, errors: Console) -> int:
    """A bug: the last frames of the traceback and a request to report it (the whole traceback with --debug)."""
    if getattr(args, "debug", False):
        raise
    errors.print("internal error: pbo failed in a way it should not; please report this with the command you ran:", markup=False)
    errors.print(traceback.format_exc(limit=-3).rstrip(), markup=False)
    return EXIT_INTERNAL


def _sayer(console: Console) -> Callable[[str], None]:
    """How a run's lines are printed: one line each however long (a log is read by line, and
    grepped), and the text as written, brackets included (not taken for markup)."""
    def say(text: str) -> None:
        console.print(f"[dim]pbo:[/dim] {escape(text)}", markup=True, soft_wrap=True)
    return say


def _parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="pbo", description="Reconfigurable real-time control from port-based objects.")
    parser.add_argument("--debug", action="store_true", help="show Python tracebacks of internal errors")
    parser.add_argument("--version", action="version", version=f"pbo {registry.installed_version()}",
                        help="print the installed pbo-runtime's version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    check = sub.add_parser("check", help="check a subsystem file like a compiler: every error, with its line")
    check.add_argument("file")
    check.add_argument("--format", choices=("text", "json"), default="text")
    check.add_argument("--profile", metavar="RUN",
                       help="a run's report.json (or its directory): prove or refute each critical deadline with the "
                            "measured execution times (non-preemptive response-time analysis, docs/scheduling.md)")
    schedule.add_arguments(check)
    _address_argument(check)
    check.set_defaults(handler=_check)

    allocate = sub.add_parser("allocate", help="propose the fewest task moves between RTPUs that prove every critical deadline")
    allocate.add_argument("file")
    allocate.add_argument("--profile", metavar="RUN", required=True, help="a run's report.json (or its directory)")
    schedule.add_arguments(allocate)
    allocate.add_argument("--config", help="judge only this configuration (default: every one the profile measured)")
    allocate.add_argument("--pin", action="append", metavar="TASK[,TASK]", help="keep this task on its RTPU (repeat for more)")
    allocate.add_argument("--free", action="append", metavar="TASK[,TASK]",
                          help="let this user of an exclusive device move (by default it keeps its RTPU)")
    allocate.set_defaults(handler=schedule.allocate)

    run = sub.add_parser("run", help="run a subsystem: plant, RTPUs, tasks; prints a summary at the end")
    run.add_argument("file")
    run.add_argument("--duration", type=float, default=5.0, help="seconds to run once the configuration is on (default 5; 0: until Ctrl-C)")
    run.add_argument("--config", help="the configuration to turn on (default: the first in the file)")
    run.add_argument("--report", type=Path, help="write the run report (per task timing, final values) as JSON here")
    run.add_argument("--no-live", action="store_true", help="no live status table (the default when output is not a terminal)")
    run.add_argument("--app", help="run this application's jobs one at a time, then stop")
    run.add_argument("--fifo", action=argparse.BooleanOptionalAction, default=None,
                     help="RTPUs (priority 50) and the plant (60) under SCHED_FIFO where the OS allows it: the default "
                          "with the real clock; the summary says if the OS refused. --no-fifo: SCHED_OTHER")
    run.add_argument("--static", action="store_true",
                     help="static reconfiguration: only the current configuration's tasks exist (kill and spawn between jobs)")
    run.add_argument("--clock", choices=("real", "sim"), default="real",
                     help="sim: simulated time in lockstep ticks, as fast as the machine allows; the run replays bit for bit")
    run.add_argument("--out", type=Path, metavar="DIR",
                     help="the run's output directory: its report (report.json), its data logs and every file it "
                          "writes (default: runs/SUBSYSTEM-DATE-TIME/ in the current directory)")
    run.add_argument("--allow-unstable-loops", action="store_true",
                     help="run even when pbo check finds a joint's position loop unstable (E326): to see what it predicts")
    run.add_argument("--host", metavar="NAME",
                     help="an application placed on hosts: run only the subsystems of this host (default: all, here)")
    _address_argument(run)
    run.add_argument("--links", help=argparse.SUPPRESS)  # set by an application's runner: JSON, see _links
    run.add_argument("--stages", help=argparse.SUPPRESS)  # set by an application's runner: this subsystem's stages
    run.add_argument("--turn", help=argparse.SUPPRESS)  # set by an application's runner on --clock sim (clock.application_lockstep)
    run.add_argument("--alternate", metavar="A,B", help="switch test: alternate between these configurations")
    run.add_argument("--switches", type=int, default=100, help="with --alternate: how many switches (default 100)")
    run.add_argument("--interval", type=float, default=0.05, help="with --alternate: seconds between switches (default 0.05)")
    run.set_defaults(handler=_run)

    plot = sub.add_parser("plot", help="plot a run's logged variables against time, switches and jobs marked")
    plot.add_argument("target", metavar="RUN_DIR_OR_LOG", help="a run's directory (pbo run prints it) or a log file")
    plot.add_argument("variables", nargs="*", metavar="AXIS",
                      help="an axis to plot: a variable (q_m), several overlaid (q_m,q_r), an element (q_m[1]), a "
                           "difference (q_m-q_r); default: every variable logged, one axis each")
    plot.add_argument("-o", "--output", type=Path, help="write the plot to this .png, .svg or .pdf (default: a window)")
    plot.set_defaults(handler=_plot)

    log = sub.add_parser("log", help="a data log for other tools: pbo log info RUN, pbo log export RUN --csv")
    log_verbs = log.add_subparsers(dest="log_command", required=True, metavar="COMMAND")
    export = log_verbs.add_parser("export", help="write a log as CSV for spreadsheets: one column per element, units in the header")
    export.add_argument("log", metavar="RUN_DIR_OR_LOG", help="a run's directory (pbo run prints it) or a .mcap or .npy data log")
    export.add_argument("--csv", action="store_true", required=True, help="as CSV (the one format for now)")
    export.add_argument("-o", "--output", type=Path,
                        help="write it here (default: stdout); a run of several logs: a directory, one LOG.csv each")
    export.set_defaults(handler=_log_export)
    info = log_verbs.add_parser("info", help="what a log holds, as ros2 bag info prints it: size, duration, start, topics")
    info.add_argument("log", metavar="RUN_DIR_OR_LOG", help="a run's directory (every log in it) or a .mcap or .npy data log")
    info.set_defaults(handler=_log_info)

    bus = sub.add_parser("bus", help="bus utilisation of each configuration (TR eq. 1-2), predicted and measured")
    bus.add_argument("file")
    bus.add_argument("--config", help="only this configuration (default: all)")
    bus.add_argument("--run-report", type=Path, help="a run's JSON report (pbo run --report): measured beside predicted")
    bus.add_argument("--combine", help="tasks to evaluate as one combined module (TR §4.5), comma-separated")
    bus.add_argument("--format", choices=("table", "json", "csv"), default="table")
    bus.add_argument("--plot", type=Path, help="draw per-task bars and the bandwidth line into this PNG")
    bus.set_defaults(handler=_bus)

    lexicon = sub.add_parser("lexicon", help="list the module library: every module's ports and parameters")
    lexicon.add_argument("--format", choices=("table", "json"), default="table")
    lexicon.add_argument("--drivers", action="store_true", help="list the device drivers (TR 4.6) instead of the modules")
    lexicon.set_defaults(handler=_lexicon)

    place = sub.add_parser("place", help="which lexicon modules can be placed in a configuration, and why not the rest")
    place.add_argument("file")
    place.add_argument("--config", help="the configuration (default: the first in the file)")
    place.add_argument("--tasks", help="the configuration's tasks instead, comma-separated (a canvas being built)")
    place.add_argument("--rtpu", help="the RTPU the module would run on (default: the first)")
    place.add_argument("--module", action="append", help="only this module (repeat for more; default: every registered one)")
    place.add_argument("--format", choices=("text", "json"), default="text")
    place.set_defaults(handler=_place)

    graph = sub.add_parser("graph", help="draw a configuration as a block diagram (.svg, .png or .dot)")
    graph.add_argument("file")
    graph.add_argument("--config", help="the configuration to draw (default: the first)")
    graph.add_argument("-o", "--output", type=Path, help="out.svg, out.png or out.dot (default: DOT text on stdout)")
    graph.set_defaults(handler=_graph)

    schema = sub.add_parser("schema", help="the JSON Schema of the subsystem format, for editors")
    schema.add_argument("-o", "--output", type=Path, help="write it here (default: stdout)")
    schema.set_defaults(handler=_schema)

    examples = sub.add_parser("examples", help="copy the example subsystem files and their JSON Schema into a folder, to run and edit")
    examples.add_argument("dir", nargs="?", type=Path, default=Path("pbo-examples"), metavar="DIR",
                          help="where to put them (default: ./pbo-examples; made if missing)")
    examples.add_argument("--force", action="store_true", help="overwrite files there that differ from the shipped ones")
    examples.set_defaults(handler=_examples)

    robot.add_parser(sub)

    # operator commands on a running subsystem (another terminal), over its 0600 control queue:
    # every verb as the command table declares it
    from pbo_runtime.supervisor.commands import VERBS, WHICH_RUN

    for verb in VERBS:
        command = sub.add_parser(verb.name, help=verb.help)
        for argument in (*verb.arguments, *WHICH_RUN):
            command.add_argument(argument.name, **argument.argparse_options())
        command.add_argument("--format", choices=("text", "json"), default="text", help=FORMAT_HELP)
        command.set_defaults(handler=lambda a, c, e, name=verb.name: _operator().run_verb(name, a, c))

    runs = sub.add_parser("runs", help="list your live runs: subsystem, run id, pid, start, configuration, job, file")
    runs.add_argument("--subsystem", help="only this subsystem's runs")
    runs.add_argument("--format", choices=("text", "json"), default="text", help="json: the runs as a list of objects")
    runs.add_argument("--json", action="store_true", help=argparse.SUPPRESS)  # the older spelling of --format json
    runs.set_defaults(handler=lambda a, c, e: _operator().runs(c, a.subsystem, a.json or a.format == "json"))

    hmi = sub.add_parser("hmi", help="serve the local API (HTTP + WebSocket) for a live run, on 127.0.0.1 with a token")
    hmi.add_argument("file", nargs="?", help="the subsystem file for lexicon, check, bus and graph (default: the run's own)")
    hmi.add_argument("--port", type=int, default=8470, help="TCP port (default 8470; 0: any free port, printed)")
    hmi.add_argument("--host", default="127.0.0.1",
                     help="address to listen on (default 127.0.0.1: this machine only; another needs --allow-remote)")
    hmi.add_argument("--allow-remote", action="store_true",
                     help="accept a --host other machines can reach (the token then crosses the network in clear text)")
    for argument in WHICH_RUN:
        hmi.add_argument(argument.name, **argument.argparse_options())
    hmi.set_defaults(handler=_hmi)

    completion = sub.add_parser("completion", help="print the shell completion script: eval \"$(pbo completion bash)\"")
    completion.add_argument("shell", choices=("bash", "zsh", "tcsh"))
    completion.set_defaults(handler=lambda a, c, e: _completion(parser, a, c))

    clean = sub.add_parser("clean", help="remove your shared memory, semaphores and queues left by dead runs")
    clean.add_argument("--subsystem", help="only this subsystem's leftovers")
    clean.set_defaults(handler=_clean)
    return parser


# --- pbo check -------------------------------------------------------------------------------


def _address_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--address", action="append", default=[], metavar="HOST=ADDRESS",
                        help="an application's host address, over the one in its hosts: (repeat for more)")


def _addresses(args: argparse.Namespace) -> dict[str, str] | str:
    """--address HOST=ADDRESS, repeated: {host: address}, or what is wrong with one."""
    found: dict[str, str] = {}
    for given in getattr(args, "address", None) or []:
        host, mark, address = given.partition("=")
        if not mark or not host or not address:
            return f"--address takes HOST=ADDRESS, e.g. --address arm-b=10.0.0.2; got {given!r}"
        found[host] = address
    return found


def _check(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.config.application import is_application_file
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
            refuted, timing = schedule.check_profile(args, console, errors, result.subsystem)
        console.print_json(json.dumps({**_check_json(result), **({"schedulability": timing} if timing else {})}))
    else:
        text = format_diagnostics(result)
        if result.subsystem is not None and not result.errors:
            text = (text + "\n" if result.warnings else "") + _verdict(result.subsystem) + _inferred_lines(result)
        (errors if result.errors else console).print(text, markup=False)
        if args.profile and result.subsystem is not None and not result.errors:
            refuted, _ = schedule.check_profile(args, console, errors, result.subsystem)
    return EXIT_CONFIG if result.errors or refuted else EXIT_OK


def _check_application(args: argparse.Namespace, console: Console, errors: Console) -> int:
    """An application file: each subsystem's file in full, then its links against their tasks."""
    from pbo_runtime.config.application import check_application
    from pbo_runtime.config.parallel import stage_lines
    from pbo_runtime.config.loader import CheckResult, format_diagnostics

    addresses = _addresses(args)
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
            runs = "".join(f", runs {'application' if k == 'app' else 'configuration'} '{v}'" for k, v in app.run.get(key, {}).items())
            where = f" on {app.placement[key]} ({app.hosts[app.placement[key]]})" if key in app.placement else ""
            lines.append(f"  subsystem {key}: {sub.file} ('{sub.name}', {len(sub.tasks)} task(s){runs}){where}")
        lines.extend(stage_lines(app.stages, app.subsystems))  # run: as parallel stages, joined one after another
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
        lines.append("    " + "  ".join(cell.ljust(width) for cell, width in zip(row, widths)) + "  " + row[3])
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
        out["inferred"] = {name: {"type": variables[name].dtype, "shape": list(variables[name].shape)} for name in result.inferred}
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


# --- pbo run ---------------------------------------------------------------------------------


def _run(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.config.application import is_application_file
    from pbo_runtime.config.loader import ALLOW_UNSTABLE_LOOPS

    if args.allow_unstable_loops:  # for every process of the run: each loads the file
        os.environ[ALLOW_UNSTABLE_LOOPS] = "1"

    if is_application_file(args.file):
        return _run_application(args, console, errors)
    if args.host is not None or args.address:
        errors.print(f"error: --host and --address place an application's subsystems on machines; {args.file} is a "
                     "subsystem file: run it without them, or run the application file that names it", markup=False)
        return EXIT_CONFIG
    with _early_fork_server(args) as fork_server:
        return _load_and_run(args, console, errors, fork_server)


@contextlib.contextmanager
def _early_fork_server(args: argparse.Namespace):
    """The run's fork server, started before the file is loaded: it imports and loads what the children
    need on the other CPU meanwhile (supervisor.fork_server). The supervisor ends it once the children
    are started; this ends it on the paths where no supervisor took it (a bad file, a refused run).
    On the simulated clock the supervisor starts its own, in the clock's environment."""
    from pbo_runtime.ipc.shm import new_run_id
    from pbo_runtime.supervisor.fork_server import ForkServer, forking_enabled

    server = None
    if args.clock == "real" and forking_enabled():
        try:
            server = ForkServer.start(str(Path(args.file).resolve()), ["pbo_runtime.supervisor.plant_host", "rtpu"],
                                      run_id=new_run_id())  # the run's id, which the supervisor takes
        except OSError:
            server = None  # the supervisor tries again, and says why if it cannot
    try:
        yield server
    finally:
        if server is not None:
            server.close()


def _load_and_run(args: argparse.Namespace, console: Console, errors: Console, fork_server: Any) -> int:
    from pbo_runtime.config.loader import load_subsystem

    subsystem = load_subsystem(args.file)
    args.loaded = time.monotonic()
    live = console.is_terminal and not args.no_live
    duration = args.duration if args.duration > 0 else None
    alternate = None
    if args.alternate:
        names = [n.strip() for n in args.alternate.split(",") if n.strip()]
        if len(names) < 2:
            errors.print("error: --alternate takes two or more configurations, e.g. --alternate pid,pd", markup=False)
            return EXIT_CONFIG
        alternate = Alternation(names, args.switches, args.interval)
        args.config = args.config or names[0]
    made = args.out is None
    args.out = args.out or default_run_dir(subsystem.name)
    with _removed_if_empty(args.out if made else None):
        return _run_subsystem(args, console, errors, subsystem, live, duration, alternate, fork_server)


def _run_subsystem(args: argparse.Namespace, console: Console, errors: Console, subsystem: Any, live: bool,
                   duration: float | None, alternate: Alternation | None, fork_server: Any = None) -> int:
    from pbo_runtime.clock.clocks import process_started
    from pbo_runtime.supervisor.supervisor import Supervisor

    startup = {"process": process_started(), "cli": args.entered, "loaded": getattr(args, "loaded", args.entered)}
    options = RunOptions(application=args.app, static=args.static, alternate=alternate, fifo=args.fifo, clock=args.clock,
                         out_dir=str(args.out), links=json.loads(args.links) if args.links else None, turn=args.turn,
                         stages=args.stages, startup=startup)
    refused = _check_output_paths(args)
    if refused:
        errors.print(f"error: {refused}", markup=False)
        return EXIT_CONFIG
    say = _sayer(console)
    supervisor = Supervisor(subsystem, args.config, duration, say=say, options=options, fork_server=fork_server)  # refuses a bad request here
    what = (f"application '{args.app}'" if args.app else f"{args.switches} switches" if alternate
            else "Ctrl-C stops it" if duration is None else f"runs {duration:g} s, Ctrl-C stops it sooner")
    rtpus = f"{len(subsystem.rtpus)} RTPU{'s' if len(subsystem.rtpus) != 1 else ''}"
    say(f"starting subsystem '{subsystem.name}' ({rtpus}, plant: "
        f"{subsystem.plant.model if subsystem.plant else 'none'}); {what}")
    for note in subsystem.robot_notes:
        say(note)
    with _results_outlive_a_second_stop():
        if live:
            with Live(console=console, refresh_per_second=4, transient=True) as view:
                supervisor.on_tick = lambda s: view.update(_status_table(s))
                result = supervisor.run()
        else:
            result = supervisor.run()
        _print_summary(console, subsystem, result)  # first: whatever fails below, the operator has seen the run
        unwritten = _write_reports(args, result.to_json())
        _print_outputs(console, args.out, result)
    for line in [result.failure] if result.failure else []:
        errors.print(f"error: {line}", markup=False)
    for line in result.faults:
        errors.print(f"fault: {line}", markup=False)
    for line in unwritten:
        errors.print(f"error: {line}", markup=False)
    return EXIT_RUN if result.failure or result.faults or unwritten else EXIT_OK


def default_run_dir(name: str) -> Path:
    """runs/NAME-DATE-TIME/ under the current directory, made now (a suffix when two runs start in one second)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for attempt in range(1, 1000):
        candidate = Path("runs") / (f"{name}-{stamp}" + (f"-{attempt}" if attempt > 1 else ""))
        try:
            candidate.mkdir(parents=True)
            return candidate
        except FileExistsError:
            continue
        except OSError:
            return candidate  # check_output_dir says why it cannot be made
    return Path("runs") / f"{name}-{stamp}-{os.getpid()}"


@contextlib.contextmanager
def _removed_if_empty(made: Path | None):
    """The default run directory made for a run that was refused before it wrote anything goes again."""
    try:
        yield
    finally:
        if made is not None:
            with contextlib.suppress(OSError):
                made.rmdir()  # only if empty: a run that ran has its report there at least


def _print_outputs(console: Console, out: Path, result: Any) -> None:
    """Where every log of the run went (path and rows), then the run's directory."""
    from pbo_runtime.reports.data_log import LogError, find_logs, log_rows

    listed = [Path(p).resolve() for t in result.tasks.values() for p in t.get("outputs", [])]
    paths = list(dict.fromkeys([*listed, *(p.resolve() for p in find_logs(out))]))  # a killed RTPU's logs: found
    here = Path.cwd().resolve()
    for path in paths:
        shown = path.relative_to(here) if path.is_relative_to(here) else path  # as the operator would type it
        try:
            console.print(f"log: {shown} ({log_rows(path)} rows)", markup=False)
        except (LogError, OSError) as exc:
            console.print(f"log: {shown} (unreadable: {exc})", markup=False)
    console.print(f"run directory: {out}", markup=False)


@contextlib.contextmanager
def _results_outlive_a_second_stop():
    """Once the run has ended, Ctrl-C and SIGTERM no longer cut its summary and report short.

    The supervisor handles both while the run lasts and puts these back when it ends. An
    application runner stopping its subsystems sends SIGTERM to one that has just ended on its
    own, and an operator presses Ctrl-C twice: either would otherwise lose the report.
    """
    stops = (signal.SIGINT, signal.SIGTERM)
    previous = {stop: signal.signal(stop, signal.SIG_IGN) for stop in stops}
    try:
        yield
    finally:
        for stop, handler in previous.items():
            signal.signal(stop, handler)


def _check_output_paths(args: argparse.Namespace) -> str:
    """Why --out or --report cannot take the run's results ("" if they can): tried before anything starts."""
    from pbo_runtime.cli.output_paths import OutputPathError, check_output_dir, check_report_path

    try:
        if args.out:
            check_output_dir(args.out)
        if getattr(args, "report", None):
            check_report_path(args.report)
    except OutputPathError as exc:
        return str(exc)
    return ""


def _write_reports(args: argparse.Namespace, report: dict[str, Any]) -> list[str]:
    """Write the run report where asked; one line per path that could not take it."""
    from pbo_runtime.cli.output_paths import OutputPathError, write_report

    text = json.dumps(report, indent=2)
    failed = []
    for path in ([args.report] if args.report else []) + ([args.out / "report.json"] if args.out else []):
        try:
            write_report(path, text)
        except OutputPathError as exc:
            failed.append(str(exc))
    return failed


def _run_application(args: argparse.Namespace, console: Console, errors: Console) -> int:
    """Every subsystem of an application file at once, joined by its links (see _application_runner)."""
    from pbo_runtime.config.application import check_application
    from pbo_runtime.config.loader import CheckResult, format_diagnostics

    addresses = _addresses(args)
    if isinstance(addresses, str):
        errors.print(f"error: {addresses}", markup=False)
        return EXIT_CONFIG
    result = check_application(args.file, addresses)
    if result.application is None:
        errors.print(format_diagnostics(CheckResult(None, result.errors, result.warnings)), markup=False)
        return EXIT_CONFIG
    app = result.application
    if args.host is not None and args.host not in app.hosts:
        from pbo_runtime.config.application import did_you_mean

        errors.print(f"error: --host {args.host}: application '{app.name}' has no such host; "
                     f"{did_you_mean(args.host, app.hosts, 'its hosts')}", markup=False)
        return EXIT_CONFIG
    if args.host is not None and not app.on_host(args.host):
        errors.print(f"error: --host {args.host}: no subsystem of application '{app.name}' is placed on it "
                     "(place one with {config: FILE, host: NAME})", markup=False)
        return EXIT_CONFIG
    made = args.out is None
    args.out = args.out or default_run_dir(app.name)  # each subsystem's files in a directory of its own below it
    with _removed_if_empty(args.out if made else None):
        return _run_linked_subsystems(args, console, errors, app)


def _run_linked_subsystems(args: argparse.Namespace, console: Console, errors: Console, app: Any) -> int:
    from pbo_runtime.supervisor.application_runner import ApplicationRunner, unreplayable_links

    refused = _check_output_paths(args) or (unreplayable_links(app) if args.clock == "sim" else "")
    if refused:
        errors.print(f"error: {refused}", markup=False)
        return EXIT_CONFIG
    say = _sayer(console)
    duration = args.duration if args.duration > 0 else None
    here = app.subsystems if args.host is None else app.on_host(args.host)
    say(f"starting application '{app.name}'" + ("" if args.host is None else f" on host '{args.host}'")
        + f": {', '.join(here)}; "
        + ("Ctrl-C stops it" if duration is None else f"runs {duration:g} s, Ctrl-C stops it sooner"))
    code = ApplicationRunner(app, duration, say, clock=args.clock, out_dir=args.out, fifo=args.fifo, host=args.host).run()
    if code:
        errors.print(f"error: application '{app.name}' stopped: a subsystem failed (exit {code}); see its lines above",
                     markup=False)
    console.print(f"run directory: {args.out}", markup=False)
    return code


def _status_table(supervisor: Any) -> Table:
    elapsed = supervisor.now() - supervisor.started_at if supervisor.started_at is not None else 0.0
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


# --- operator commands -------------------------------------------------------------------------


def _operator() -> Any:
    from pbo_runtime.cli import operator

    return operator


# --- pbo hmi, pbo completion --------------------------------------------------------------------


def _hmi(args: argparse.Namespace, console: Console, errors: Console) -> int:
    if args.file is not None and not os.path.isfile(args.file):
        errors.print(f"error: no subsystem file '{args.file}': give the YAML file of the subsystem, or none", markup=False)
        return EXIT_CONFIG
    if not 0 <= args.port <= 65535:
        errors.print(f"error: --port must be 0 to 65535, got: {args.port}", markup=False)
        return EXIT_CONFIG
    for module in ("fastapi", "uvicorn", "websockets"):
        require_extra(module, "pbo hmi")
    from pbo_runtime.api.server import serve

    def say(text: str) -> None:
        console.print(text, markup=False, soft_wrap=True)  # the URL stays on one line
        console.file.flush()  # at once, when a script reads the URL from a pipe

    def warn(text: str) -> None:
        errors.print(text, markup=False)
        errors.file.flush()

    with contextlib.suppress(KeyboardInterrupt):
        return serve(os.path.abspath(args.file) if args.file else None, args.host, args.port, args.subsystem, args.run,
                     say, warn, args.allow_remote)
    return EXIT_OK


def _completion(parser: argparse.ArgumentParser, args: argparse.Namespace, console: Console) -> int:
    from pbo_runtime.cli.completion import script

    console.out(script(parser, args.shell), end="")
    return EXIT_OK


# --- pbo plot, pbo log export ------------------------------------------------------------------


def _plot(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.data_log import LogError
    from pbo_runtime.reports.run_plot import figure, load_run, plot_axes, save

    require_extra("matplotlib", "pbo plot")
    try:
        run = load_run(args.target)
        plot_axes(run, args.variables)  # an unknown variable is refused before anything is drawn
        if args.output is None and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise LogError("no display to show the plot on: write it to a file with -o plot.png (or .svg)")
        if args.output is not None:
            save(figure(run, args.variables), args.output)
            console.print(f"wrote {args.output}", markup=False)
            return EXIT_OK
    except (LogError, OSError) as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    import matplotlib.pyplot as plt

    figure(run, args.variables, new=plt.figure)  # the same figure, in a window of the interactive backend
    plt.show()
    return EXIT_OK


def _log_export(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.data_log import LogError, open_log
    from pbo_runtime.reports.run_plot import csv_text, logs_to_export

    try:
        logs = logs_to_export(Path(args.log), args.output)
        if args.output is None:
            sys.stdout.write(csv_text(open_log(logs[0])))
            return EXIT_OK
        for log in logs:
            output = args.output / f"{log.stem}.csv" if len(logs) > 1 else args.output
            text = csv_text(open_log(log))
            output.write_text(text)
            console.print(f"wrote {output} ({text.count(chr(10)) - 1} rows)", markup=False)
    except (LogError, OSError) as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    return EXIT_OK


def _log_info(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.data_log import LogError
    from pbo_runtime.reports.log_info import infos, text

    try:
        found = infos(Path(args.log))
    except (LogError, OSError) as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    console.out("\n\n".join(text(log) for log in found), highlight=False)
    return EXIT_OK


# --- pbo bus ---------------------------------------------------------------------------------


def _bus(args: argparse.Namespace, console: Console, errors: Console) -> int:
    if args.plot:
        require_extra("matplotlib", "pbo bus --plot")
    from pbo_runtime.config import bus
    from pbo_runtime.config.loader import load_subsystem

    subsystem = load_subsystem(args.file)
    if args.config and args.config not in subsystem.configurations:
        errors.print(f"error: no configuration '{args.config}' in {args.file} "
                     f"(configurations: {', '.join(subsystem.configurations)})", markup=False)
        return EXIT_CONFIG
    names = [args.config] if args.config else list(subsystem.configurations)
    reports = {name: bus.predict(subsystem, name) for name in names}
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


# --- pbo lexicon, pbo clean --------------------------------------------------------------------


def _lexicon(args: argparse.Namespace, console: Console, errors: Console) -> int:
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


def _place(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.config.placement import placement_report

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


def _graph(args: argparse.Namespace, console: Console, errors: Console) -> int:
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


def _schema(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.reports.schema import schema_text, write_schema

    if args.output:
        write_schema(args.output)
        console.print(f"wrote {args.output}", markup=False)
    else:
        console.out(schema_text(), end="")
    return EXIT_OK


def _examples(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.cli.examples import ExamplesRefused, copy_examples, summary

    try:
        copied = copy_examples(args.dir, force=args.force)
    except ExamplesRefused as exc:
        errors.print(f"error: {exc}", markup=False)
        return EXIT_CONFIG
    console.print("\n".join(summary(copied)), markup=False, soft_wrap=True)
    return EXIT_OK


def _clean(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.supervisor.cleanup import remove_dead_runs

    cleanup = remove_dead_runs(args.subsystem)
    removed = cleanup.removed
    console.print(f"removed {len(removed)} object(s) left by dead runs" + (": " + ", ".join(removed) if removed else ""),
                  markup=False)
    if cleanup.live:
        console.print(f"left {len(cleanup.live)} live run(s) alone: {', '.join(cleanup.live)} (pbo runs lists them)",
                      markup=False)
    if cleanup.ignored:
        console.print(f"ignored {len(cleanup.ignored)} object(s) named like a run's but not yours to trust "
                      f"(only uid {os.geteuid()}'s with mode 0600 are): {cleanup.ignored_summary()}; not touched: "
                      f"{', '.join(sorted(cleanup.ignored))}", markup=False)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
