"""`pbo run FILE`: a subsystem (or every subsystem of an application) run from start to summary.

The supervisor runs it; this loads the file, starts the fork server early, shows the live table,
prints the summary (`cli.summary`) and writes the report where asked.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pbo_runtime.cli import summary
from pbo_runtime.cli.arguments import host_addresses
from pbo_runtime.cli.console import LazyConsole, rich_console
from pbo_runtime.cli.exits import EXIT_CONFIG, EXIT_OK, EXIT_RUN
from pbo_runtime.links.run_link import links_from_json
from pbo_runtime.supervisor.run_options import Alternation, RunOptions, pace_refused

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

    from pbo_runtime.supervisor.fork_server import ForkServer


def run(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from pbo_runtime.config.file_kind import ALLOW_UNSTABLE_LOOPS, is_application_file

    if args.allow_unstable_loops:  # for every process of the run: each loads the file
        os.environ[ALLOW_UNSTABLE_LOOPS] = "1"
    if args.one_process and args.clock != "sim":
        errors.print("error: --one-process runs the plant and the RTPUs in turn in one process, which only the "
                     "simulated clock allows: add --clock sim", markup=False)
        return EXIT_CONFIG
    refused = pace_refused(args.pace, args.clock)
    if refused:
        errors.print(f"error: {refused}", markup=False)
        return EXIT_CONFIG

    if is_application_file(args.file):
        if getattr(args, "fork_server", None) is not None:  # each subsystem of an application is a run of its own
            args.fork_server.close()
        return _run_application(args, console, errors)
    if args.host is not None or args.address:
        errors.print(f"error: --host and --address place an application's subsystems on machines; {args.file} is a "
                     "subsystem file: run it without them, or run the application file that names it", markup=False)
        return EXIT_CONFIG
    with _early_fork_server(args) as fork_server:
        return _load_and_run(args, console, errors, fork_server)


@contextlib.contextmanager
def _early_fork_server(args: argparse.Namespace) -> Iterator[ForkServer | None]:
    """The run's fork server, started before the file is loaded (by `cli.main`, before the CLI's own
    imports; else here): it imports what the children need on the other CPU meanwhile
    (supervisor.fork_server), and is handed the loaded file. The supervisor ends it once the
    children are started; this ends it on the paths where no supervisor took it (a bad file, a
    refused run). On the simulated clock the supervisor starts its own, in the clock's environment."""
    from pbo_runtime.ipc.shm import new_run_id
    from pbo_runtime.supervisor.fork_server import RUN_PRELOAD, ForkServer, forking_enabled

    server: ForkServer | None = getattr(args, "fork_server", None)
    if server is None and args.clock == "real" and forking_enabled():  # (--one-process is on the simulated clock)
        try:
            server = ForkServer.start(None, list(RUN_PRELOAD), run_id=new_run_id())  # the run's id, which the supervisor takes
        except OSError:
            server = None  # the supervisor tries again, and says why if it cannot
    elif server is not None and args.clock != "real":
        server.close()
        server = None
    try:
        yield server
    finally:
        if server is not None:
            server.close()


def _load_and_run(args: argparse.Namespace, console: Console, errors: Console, fork_server: ForkServer | None) -> int:
    from pbo_runtime.config.loader import load_subsystem

    subsystem = load_subsystem(args.file)
    args.loaded = time.monotonic()
    if fork_server is not None:
        fork_server.hand_over(subsystem)
    live = not args.no_live and console.is_terminal
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
                         one_process=args.one_process, pace=args.pace,
                         out_dir=str(args.out), links=links_from_json(args.links) if args.links else None, turn=args.turn,
                         stages=args.stages, startup=startup)
    refused = _check_output_paths(args)
    if refused:
        errors.print(f"error: {refused}", markup=False)
        return EXIT_CONFIG
    say = _sayer(console)
    # refuses a bad request here
    supervisor = Supervisor(subsystem, args.config, duration, say=say, options=options, fork_server=fork_server)
    what = (f"application '{args.app}'" if args.app else f"{args.switches} switches" if alternate
            else "Ctrl-C stops it" if duration is None else f"runs {duration:g} s, Ctrl-C stops it sooner")
    rtpus = f"{len(subsystem.rtpus)} RTPU{'s' if len(subsystem.rtpus) != 1 else ''}"
    say(f"starting subsystem '{subsystem.name}' ({rtpus}, plant: "
        f"{subsystem.plant.model if subsystem.plant else 'none'}); {what}")
    for note in subsystem.robot_notes:
        say(note)
    with _results_outlive_a_second_stop():
        if live:
            from rich.live import Live

            with Live(console=rich_console(console), refresh_per_second=4, transient=True) as view:
                supervisor.on_tick = lambda s: view.update(_status_table(s))
                result = supervisor.run()
        else:
            result = supervisor.run()
        summary._print_summary(console, subsystem, result)  # first: whatever fails below, the operator has seen the run
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
def _removed_if_empty(made: Path | None) -> Iterator[None]:
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

    listed = [Path(p).resolve() for t in result.tasks.values() for p in t.statistics.outputs]
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
def _results_outlive_a_second_stop() -> Iterator[None]:
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

    addresses = host_addresses(args)
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
    code = ApplicationRunner(app, duration, say, clock=args.clock, out_dir=args.out, fifo=args.fifo, host=args.host,
                             one_process=args.one_process, pace=args.pace).run()
    if code:
        errors.print(f"error: application '{app.name}' stopped: a subsystem failed (exit {code}); see its lines above",
                     markup=False)
    console.print(f"run directory: {args.out}", markup=False)
    return code


def _status_table(supervisor: Any) -> Table:
    from rich.table import Table

    elapsed = supervisor.now() - supervisor.started_at if supervisor.started_at is not None else 0.0
    table = Table(title=f"{supervisor.subsystem.name} · {supervisor.configuration} · {elapsed:5.1f} s", title_justify="left")
    for column in ("task", "rtpu", "state", "cycles", "overruns", "exec µs", "max jitter µs"):
        table.add_column(column, justify="right" if column not in ("task", "rtpu", "state") else "left")
    for row in supervisor.status_rows():
        if row.state == "NOT_CREATED":
            continue
        colour = {"ON": "green", "ERROR": "bold red", "OFF": "yellow"}.get(row.state, "white")
        table.add_row(row.task, row.rtpu, f"[{colour}]{row.state}[/]", str(row.cycles), str(row.overruns),
                      f"{row.exec_last * 1e6:.0f}", f"{row.jitter_max * 1e6:.0f}")
    return table


def _sayer(console: Console) -> Callable[[str], None]:
    """How a run's lines are printed: one line each however long (a log is read by line, and
    grepped), and the text as written, brackets included (not taken for markup); off a terminal,
    before rich is made, written as they are (`cli.console`)."""
    def say(text: str) -> None:
        if isinstance(console, LazyConsole) and console.write_plainly(f"pbo: {text}"):
            return
        from rich.markup import escape

        console.print(f"[dim]pbo:[/dim] {escape(text)}", markup=True, soft_wrap=True)
    return say
