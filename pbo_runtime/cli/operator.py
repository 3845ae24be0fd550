"""The operator's commands on a running subsystem, as the `pbo` CLI calls them from another terminal.

Each function finds the live run (`ipc.control.find_live_run`: by `--subsystem` and `--run ID` when
several are alive; `pbo runs` lists them), sends one request over the run's
control queue, prints the outcome on the console it is given and returns the exit status 0.
Anything that stops a command (no run, no answer, the supervisor refused) raises a PboError
whose message says why; the CLI prints it and exits with 2, as for every other run failure, or
with 1 for a BadRequest (the arguments were wrong: a name, a value; see docs/operator-commands.md).
`svar` alone reads the table directly (`table.svar`), so it works even while the supervisor is busy.

The verbs, their arguments, what the supervisor does and answers, and the status reply are
declared once, in `supervisor.commands`; this module prints the replies (`run_verb`).
"""

from __future__ import annotations

import argparse
import difflib
import functools
import json
import time
from collections.abc import Callable, Sequence
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from pbo_runtime.api.jsonable import jsonable
from pbo_runtime.cli.console import rich_console
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import shm
from pbo_runtime.ipc.control import BadRequest, ControlClient
from pbo_runtime.ipc.runs import live_runs
from pbo_runtime.reports.run_summary import scheduler_outcome
from pbo_runtime.supervisor.command_table import COMMANDS, parse_object_values
from pbo_runtime.supervisor.status_reply import TaskStatusEntry
from pbo_runtime.table.snapshot import TableBusy
from pbo_runtime.table.svar import TableView, open_table, svar_rows, svar_table

__all__ = [
    "event",
    "job",
    "parse_object_values",
    "run_verb",
    "run_verb_json",
    "runs",
    "status",
    "stop",
    "svar",
    "switch",
    "task_signal",
]

WRITER_MAP_TIMEOUT = 0.5  # svar asks for task names, but must not wait long for a busy supervisor
TASK_COMMANDS = ("on", "off", "clear")
_STATE_STYLE = {"ON": "green", "OFF": "yellow", "ERROR": "bold red", "KILLED": "red"}


def _say(console: Console, reply: dict[str, Any], default: str) -> None:
    console.print(str(reply.get("message") or default), markup=False)


def _us(seconds: float | None) -> str:
    return "—" if seconds is None else f"{seconds * 1e6:.0f}"


# --- status ---------------------------------------------------------------------------------


def status(console: Console, subsystem: str | None = None, run: str | None = None) -> int:
    """Print the run's tasks by RTPU (state, rate, jitter, overruns), its configuration and job."""
    reply = ControlClient.connect(subsystem, run).call("status", timeout=COMMANDS["status"].timeout)
    console.print(status_table(reply))
    for flag in reply.get("flags") or []:
        console.print(f"[bold red]flag:[/] {flag}")
    for note in reply.get("gains") or []:
        console.print(note, markup=False)
    for task in map(TaskStatusEntry.from_json, reply.get("tasks") or []):
        if task.error:
            console.print(f"task '{task.row.task}' ({task.row.state}): {task.error}", markup=False)
    return 0


def scheduler_brief(settings: dict[str, str]) -> str:
    """What an RTPU runs under, short enough for the status table: FIFO 50, OTHER (FIFO refused), ..."""
    if "clock" in settings:
        return "sim clock"
    scheduler = settings.get("scheduler", "")
    outcome = scheduler_outcome(scheduler)
    if outcome == "fifo":
        brief = scheduler.replace("SCHED_", "")
    elif outcome == "refused":
        brief = "OTHER (FIFO refused)"
    else:
        brief = "OTHER" if scheduler else "?"
    cpu = settings.get("cpu", "any")
    if cpu != "any":
        brief += f", cpu {cpu}" if cpu.isdigit() else ", not pinned"
    return brief


def restart_brief(restarts: list[dict[str, Any]]) -> str:
    """An RTPU's restarts in its status label: how many, the last one's cause and its time back to ON."""
    last = restarts[-1]
    back = "coming back" if last.get("seconds") is None else f"ON again in {float(last['seconds']) * 1e3:.0f} ms"
    return f"restarted {len(restarts)}x; last {last.get('cause', '?')}, {back}"


def status_table(reply: dict[str, Any]) -> Table:
    """The status reply as a table, one section per RTPU."""
    parts = [f"{reply.get('subsystem', '?')} · run {reply.get('run_id', '?')}",
             f"configuration {reply.get('configuration') or '—'}"]
    if reply.get("path"):  # an application that decides: where it is, `pick > try > reach`
        parts.append(f"path {reply['path']}")
    elif reply.get("application"):
        parts.append(f"application {reply['application']}")
    if reply.get("job") and not reply.get("path"):
        parts.append(f"job {reply['job']}")
    parts.append(f"{float(reply.get('elapsed') or 0.0):.1f} s")
    table = Table(title=" · ".join(parts), title_justify="left")
    for column in ("rtpu", "task", "state", "cycles", "rate Hz", "jitter p50 µs", "jitter p99 µs", "jitter max µs",
                   "exec p50 µs", "exec p99 µs", "overruns", "missed"):
        table.add_column(column, justify="left" if column in ("rtpu", "task", "state") else "right")
    tasks = [TaskStatusEntry.from_json(task) for task in reply.get("tasks") or []]
    realtime = reply.get("realtime") or {}
    stalled = reply.get("stalled") or {}
    restarted: dict[str, list[dict[str, Any]]] = {}
    for restart in reply.get("restarts") or []:
        restarted.setdefault(str(restart.get("rtpu")), []).append(restart)
    by_rtpu: dict[str, list[TaskStatusEntry]] = {}
    for task in tasks:
        by_rtpu.setdefault(task.row.rtpu, []).append(task)
    for n, rtpu in enumerate(sorted(by_rtpu)):
        if n:
            table.add_section()
        for i, task in enumerate(by_rtpu[rtpu]):
            row = task.row
            state = row.state
            style = _STATE_STYLE.get(state, "white")
            if row.task in stalled:  # ON, but its cycle has not returned (see _stall_watch)
                state, style = f"{state}, no cycle for {float(stalled[row.task]):.1f} s", "bold red"
            rate = task.rate
            label = f"{rtpu}\n[dim]{scheduler_brief(realtime.get(rtpu, {}))}[/]" if rtpu in realtime else rtpu
            if rtpu in restarted:
                label += f"\n[yellow]{restart_brief(restarted[rtpu])}[/]"
            table.add_row(label if i == 0 else "", row.task, f"[{style}]{state}[/]",
                          str(row.cycles), "—" if rate is None else f"{rate:.0f}",
                          _us(row.jitter_p50), _us(row.jitter_p99), _us(row.jitter_max),
                          _us(row.exec_p50), _us(row.exec_p99), str(row.overruns), str(row.missed))
    return table


# --- commands -------------------------------------------------------------------------------


def task_signal(console: Console, command: str, task: str, subsystem: str | None = None, run: str | None = None) -> int:
    """Turn a task on or off, or clear its error (TR Figure 11), through job control."""
    if command not in TASK_COMMANDS:
        raise PboError(f"a task command is one of {', '.join(TASK_COMMANDS)}, got: {command!r}")
    verb = COMMANDS[command]
    reply = ControlClient.connect(subsystem, run).call(command, verb.request({"task": task}), timeout=verb.timeout)
    state = reply.get("state")
    _say(console, reply, f"task '{task}' is {state}" if state else f"sent '{command}' to task '{task}'")
    return 0


def switch(console: Console, configuration: str, subsystem: str | None = None, run: str | None = None) -> int:
    """Switch the running subsystem to another configuration (a dynamic reconfiguration, TR §4.4)."""
    verb = COMMANDS["switch"]
    reply = ControlClient.connect(subsystem, run).call(
        "switch", verb.request({"configuration": configuration}), timeout=verb.timeout
    )
    text = f"configuration '{reply.get('configuration', configuration)}' is on"
    if reply.get("entered") or reply.get("left"):
        text += f" (on: {', '.join(reply.get('entered') or []) or '—'}; off: {', '.join(reply.get('left') or []) or '—'})"
    if reply.get("took") is not None:
        text += f" in {float(reply['took']) * 1e3:.1f} ms"
    _say(console, reply, text)
    return 0


def job(console: Console, name: str, object_values: Sequence[str] | None, subsystem: str | None = None,
        run: str | None = None) -> int:
    """Start a job, with its object's values as given on the command line (`pbo job move 0.3 -0.5 ...`)."""
    verb = COMMANDS["job"]
    request = verb.request({"name": name, "values": object_values})
    reply = ControlClient.connect(subsystem, run).call("job", request, timeout=verb.timeout)
    where = f" (configuration '{reply['configuration']}')" if reply.get("configuration") else ""
    _say(console, reply, f"job '{reply.get('job', name)}' started{where}")
    return 0


def event(console: Console, task: str, values: Sequence[str] | None, subsystem: str | None = None,
          run: str | None = None) -> int:
    """Send an event, with the values given on the command line, to an aperiodic task."""
    verb = COMMANDS["event"]
    request = verb.request({"task": task, "values": values})
    reply = ControlClient.connect(subsystem, run).call("event", request, timeout=verb.timeout)
    console.print(str(reply.get("message", f"event sent to '{task}'")), markup=False)
    return 0


def play(console: Console, device: str, values: Sequence[str] | None, subsystem: str | None = None,
         run: str | None = None) -> int:
    """Play a device the operator drives (a trackball with source: hmi) with the values given."""
    verb = COMMANDS["play"]
    request = verb.request({"device": device, "values": values})
    reply = ControlClient.connect(subsystem, run).call("play", request, timeout=verb.timeout)
    console.print(str(reply.get("message", f"device '{device}' played")), markup=False)
    return 0


def stop(console: Console, subsystem: str | None = None, run: str | None = None) -> int:
    """Ask the supervisor to stop the run: tasks off, killed, every object unlinked."""
    client = ControlClient.connect(subsystem, run)
    reply = client.call("stop", timeout=COMMANDS["stop"].timeout)
    _say(console, reply, f"'{client.subsystem}' (run {client.run_id}) is stopping")
    return 0


def live_change(console: Console, name: str, args: argparse.Namespace) -> int:
    """spawn, kill, replace, set, app, save: the request from the command line, the supervisor's message.

    A change the checker refuses comes back as a BadRequest whose text is the checker's located
    messages, as `pbo check` prints them; the CLI prints it and exits 1.
    """
    verb = COMMANDS[name]
    reply = ControlClient.connect(args.subsystem, args.run).call(name, verb.request(vars(args)), timeout=verb.timeout)
    _say(console, reply, f"{name}: done")
    return 0


# --- runs -----------------------------------------------------------------------------------

RUNS_TIMEOUT = 0.5  # per run: `pbo runs` asks each supervisor what it runs, but lists a busy one anyway


def runs(console: Console, subsystem: str | None = None, as_json: bool = False) -> int:
    """List this user's live runs (oldest first): subsystem, run id, pid, start, configuration, job, file."""
    rows = []
    for run in live_runs(subsystem):
        row: dict[str, Any] = {**run.to_json(), "configuration": None, "job": None, "application": None, "file": None,
                               "answered": False}
        try:
            reply = ControlClient(run.subsystem, run.run_id).request("status", timeout=RUNS_TIMEOUT)
        except PboError:
            reply = {}  # starting, stopping, or too busy to answer now: listed all the same
        if reply.get("ok"):
            row.update({key: reply.get(key) for key in ("configuration", "job", "application", "file")}, answered=True)
        rows.append(row)
    if as_json:
        console.out(json.dumps(rows, indent=2))
        return 0
    if not rows:
        console.print(f"no live run{' of ' + repr(subsystem) if subsystem else ''} of yours "
                      "(pbo run FILE starts one)", markup=False)
        return 0
    table = Table(title="live runs", title_justify="left")
    for column in ("subsystem", "run id", "pid", "started", "configuration", "job", "file"):
        table.add_column(column)
    for row in rows:
        started = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(row["started_at"])) if row["started_at"] else "?"
        configuration = row["configuration"] or ("—" if row["answered"] else "(no answer)")
        job = row["job"] or (f"application {row['application']}" if row["application"] else "—")
        table.add_row(row["subsystem"], row["run_id"], str(row["pid"]), started, configuration, job, row["file"] or "—")
    console.print(table)
    return 0


# --- the verbs as the CLI runs them -----------------------------------------------------------

# How each verb of the command table runs from the command line: (parsed arguments, console) -> exit status
_RUNNERS: dict[str, Callable[[argparse.Namespace, Console], int]] = {
    "status": lambda a, c: status(c, a.subsystem, a.run),
    "on": lambda a, c: task_signal(c, "on", a.task, a.subsystem, a.run),
    "off": lambda a, c: task_signal(c, "off", a.task, a.subsystem, a.run),
    "clear": lambda a, c: task_signal(c, "clear", a.task, a.subsystem, a.run),
    "switch": lambda a, c: switch(c, a.configuration, a.subsystem, a.run),
    "job": lambda a, c: job(c, a.name, a.values, a.subsystem, a.run),
    "event": lambda a, c: event(c, a.task, a.values, a.subsystem, a.run),
    "play": lambda a, c: play(c, a.device, a.values, a.subsystem, a.run),
    "svar": lambda a, c: svar(c, a.names, a.watch, a.interval, a.subsystem, run=a.run),
    "stop": lambda a, c: stop(c, a.subsystem, a.run),
}
for _live_verb in ("spawn", "kill", "replace", "set", "app", "save"):
    _RUNNERS[_live_verb] = functools.partial(lambda verb, a, c: live_change(c, verb, a), _live_verb)


def command(args: argparse.Namespace, console: Console, errors: Console) -> int:
    """`pbo VERB ...` for any verb of the command table."""
    return run_verb(args.command, args, console)


def list_runs(args: argparse.Namespace, console: Console, errors: Console) -> int:
    """`pbo runs`."""
    return runs(console, args.subsystem, args.json or args.format == "json")


def run_verb(name: str, args: argparse.Namespace, console: Console) -> int:
    """Run verb `name` of the command table with the command line's arguments; the exit status."""
    if getattr(args, "format", "text") == "json":
        return run_verb_json(name, args, console)
    return _RUNNERS[name](args, console)


def run_verb_json(name: str, args: argparse.Namespace, console: Console) -> int:
    """`pbo VERB --format json`: the reply dict as the supervisor sent it (the API's answer too), or the refusal.

    Any verb of the command table, with no code of its own here: its request is made from the
    command line by the table (`Verb.request`). The exit status is the text form's: 0 done, 1 the
    request was wrong, 2 the run refused it, or no run answered.
    """
    verb = COMMANDS[name]
    try:
        if verb.handler is None:
            reply = _LOCAL_JSON[name](args)
        else:
            request = verb.request(vars(args))
            reply = ControlClient.connect(args.subsystem, args.run).request(name, request, timeout=verb.timeout)
    except BadRequest as exc:
        reply = {"ok": False, "error": str(exc), "bad_request": True}
    except PboError as exc:
        reply = {"ok": False, "error": str(exc)}
    if reply is not None:
        console.out(json.dumps(jsonable(reply), indent=2))
    if reply is None or reply.get("ok"):
        return 0
    return 1 if reply.get("bad_request") else 2


def svar_json(args: argparse.Namespace) -> dict[str, Any] | None:
    """`pbo svar --format json`: the rows pbo svar shows; with --watch, one compact line per refresh (JSON Lines)."""
    view = open_table(args.subsystem, args.run)
    try:
        chosen = _check_names(view, args.names)
        writers = writer_names(view.subsystem, view.run_id)
        head = {"ok": True, "subsystem": view.subsystem, "run_id": view.run_id}
        if not args.watch:
            return {**head, "variables": svar_rows(view, chosen, writers)}
        try:
            while _run_alive(view):
                try:
                    line: dict[str, Any] = {**head, "variables": svar_rows(view, chosen, writers)}
                except TableBusy as exc:
                    line = {**head, "busy": str(exc)}
                print(json.dumps(jsonable(line)), flush=True)
                time.sleep(args.interval)
        except KeyboardInterrupt:
            pass
        return None
    finally:
        view.close()


# How the verbs the supervisor does not serve (handler None) answer --format json
_LOCAL_JSON: dict[str, Callable[[argparse.Namespace], dict[str, Any] | None]] = {"svar": svar_json}


# --- svar -----------------------------------------------------------------------------------


def svar(console: Console, names: Sequence[str], watch: bool, interval: float = 0.5, subsystem: str | None = None,
         updates: int | None = None, run: str | None = None) -> int:
    """Show state variables (all when `names` is empty) with sequence, age and writer; `watch` refreshes until Ctrl-C.

    `updates` bounds the number of refreshes in watch mode (for tests; None: until Ctrl-C or the run ends).
    """
    view = open_table(subsystem, run)
    try:
        chosen = _check_names(view, names)
        writers = writer_names(view.subsystem, view.run_id)
        title = f"{view.subsystem} · run {view.run_id}"
        if not watch:
            console.print(svar_table(svar_rows(view, chosen, writers), title))
            return 0
        with Live(console=rich_console(console), auto_refresh=False, transient=False) as live:
            try:
                count = 0
                rows: list[dict[str, Any]] = []
                while updates is None or count < updates:
                    ended = not _run_alive(view)
                    try:
                        rows, note = svar_rows(view, chosen, writers), " · ended" if ended else ""
                    except TableBusy:  # a writer stopped mid-write: show the last rows, never wait on it
                        note = " · table busy (a writer stopped mid-write), last values shown"
                    live.update(svar_table(rows, title + note), refresh=True)
                    if ended:
                        break
                    count += 1
                    if updates is None or count < updates:
                        time.sleep(interval)
            except KeyboardInterrupt:
                pass
        if not _run_alive(view):
            console.print(f"the run of '{view.subsystem}' has ended", markup=False)
        return 0
    finally:
        view.close()


def writer_names(subsystem: str, run_id: str) -> dict[int, str]:
    """Task index -> name from the supervisor's status reply; {} if it does not answer in time."""
    try:
        reply = ControlClient(subsystem, run_id).request("status", timeout=WRITER_MAP_TIMEOUT)
    except PboError:
        return {}
    if not reply.get("ok"):
        return {}
    names = {}
    for position, task in enumerate(reply.get("tasks") or []):
        if isinstance(task, dict) and "task" in task:
            names[int(task.get("index", position))] = str(task["task"])
    return names


def _check_names(view: TableView, names: Sequence[str]) -> list[str]:
    known = view.variables()
    unknown = [n for n in names if n not in known]
    if unknown:
        hints = [f"did you mean '{close[0]}'?" for n in unknown for close in [difflib.get_close_matches(n, known, 1)] if close]
        raise PboError(f"no variable {', '.join(repr(n) for n in unknown)} in '{view.subsystem}'"
                       f"{' (' + ' '.join(hints) + ')' if hints else ''}; variables: {', '.join(known)}")
    return list(names) or known


def _run_alive(view: TableView) -> bool:
    """The segment is still there and its supervisor alive (a mapping outlives the run: values would freeze)."""
    return (shm.SHM_DIR / view.name.lstrip("/")).exists() and shm.pid_alive(int(view.run_id.split("-")[0]))
