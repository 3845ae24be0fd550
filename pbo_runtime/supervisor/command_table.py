"""The operator's verbs on a running subsystem, declared once: name, arguments, help, reply, handler's name.

`pbo status`, `pbo on TASK`, `pbo switch CONFIGURATION`, ... come from this table: the CLI builds
its subparsers from it (`cli.parser`), the local API its routes (`api.verbs`), the supervisor
serves the control queue's requests with the handler each verb names (`supervisor.commands`),
and the verb table in docs/operator-commands.md is `verb_table()` (a test keeps them equal).
The table holds declarations only: building `pbo --help` imports none of the handlers' wings.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

STATUS_TIMEOUT = 2.0
COMMAND_TIMEOUT = 5.0  # a switch or a task signal may wait for RTPUs to confirm
LIVE_TIMEOUT = 15.0  # a live change spawns (imports, init) and waits for a cycle boundary
FORMAT_HELP = ("json: print the reply as JSON, a refusal too ({\"ok\": false, \"error\": ...}), on stdout; "
               "the exit status is the same")


@dataclass(frozen=True)
class Argument:
    """One argument of a verb: on the command line (`name`; an option when it starts with --), and in the request (`key`)."""

    name: str
    help: str | None = None
    key: str | None = None  # the request's key; None: the command line's own (not sent)
    nargs: str | None = None
    flag: bool = False  # an option without a value
    type: Callable[[str], Any] | None = None
    extend: bool = False  # an option given several times, or with several values: all of them, in order
    default: Any = None
    parse: Callable[[Any], Any] | None = None  # command-line text to the request's value
    metavar: str | None = None  # how the help shows its value
    choices: tuple[str, ...] | None = None
    required: bool = False  # an option that must be given
    append: bool = False  # an option given several times: each value, in order
    negatable: bool = False  # --x and --no-x (None when neither is given)
    hidden: bool = False  # not in the help (set by a program, or an older spelling)
    complete: str | None = None  # the kind of name the shell completes it with (cli.completion)
    short: str | None = None  # an option's one-letter spelling: -o for --output

    def argparse_options(self) -> dict[str, Any]:
        """The keywords of argparse's add_argument that declare it."""
        options: dict[str, Any] = {}
        if self.flag:
            options["action"] = "store_true"
        if self.extend:
            options["action"] = "extend"
        if self.append:
            options["action"] = "append"
        if self.negatable:
            options["action"] = argparse.BooleanOptionalAction
        if self.nargs is not None:
            options["nargs"] = self.nargs
        if self.type is not None:
            options["type"] = self.type
        if self.choices is not None:
            options["choices"] = self.choices
        if self.required:
            options["required"] = True
        if self.default is not None:
            options["default"] = list(self.default) if self.append else self.default  # append adds to a copy
        if self.hidden:
            options["help"] = argparse.SUPPRESS
        elif self.help is not None:
            options["help"] = self.help
        if self.metavar is not None:
            options["metavar"] = self.metavar
        return options

    @property
    def flags(self) -> tuple[str, ...]:
        """What argparse's add_argument takes first: the name, after the short spelling if any."""
        return (self.short, self.name) if self.short else (self.name,)

    @property
    def dest(self) -> str:
        return self.name.lstrip("-").replace("-", "_")


@dataclass(frozen=True)
class Verb:
    """An operator verb: what the CLI offers, what the supervisor does, what it answers."""

    name: str
    help: str
    arguments: tuple[Argument, ...]
    handler: str | None  # its function in supervisor.commands; None: served by the operator's side alone (svar)
    result: str  # the reply besides "ok": True, as the docs' table shows it
    timeout: float = STATUS_TIMEOUT  # how long the operator waits for the answer

    def request(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """The request's arguments from the command line's values (by argument name)."""
        request = {}
        for argument in self.arguments:
            if argument.key is None:
                continue
            value = values.get(argument.dest)
            request[argument.key] = argument.parse(value) if argument.parse is not None else value
        return request


def parse_object_values(texts: Sequence[str] | None) -> list[int | float] | None:
    """Command-line numbers (None when none are given): integers as written ('3'), others as floats.

    Refused here already when not finite numbers; the supervisor checks them again, with the
    variable's dtype and shape, since a request may come from elsewhere than this command line.
    """
    from pbo_runtime.config.values import INT_RANGE
    from pbo_runtime.ipc.control import BadRequest

    if not texts:
        return None
    values: list[int | float] = []
    for position, text in enumerate(texts, 1):
        try:
            value: int | float = int(text)
            if abs(value) > INT_RANGE["int64"][1]:
                value = float(text)  # beyond any integer variable: a float, refused or not by its dtype
        except ValueError:
            try:
                value = float(text)
            except ValueError:
                raise BadRequest(f"values must be numbers, got: {text!r} (value {position})") from None
        if not math.isfinite(value):
            raise BadRequest(f"values must be finite numbers, got: {text!r} (value {position})")
        values.append(value)
    return values


def parse_job_object(texts: Sequence[str] | None) -> list[int | float] | str | None:
    """A job's object on the command line: a named object (`pbo job reach home`), or its numbers."""
    if texts and len(texts) == 1 and texts[0].isidentifier():
        return texts[0]
    return parse_object_values(texts)


_TASK = Argument("task", help="the task's name", key="task", complete="task")
# what `pbo spawn` and `pbo replace` say of the new task (values are YAML, checked as in the file)
_NEW_TASK = (
    Argument("--module", help="its module (pbo lexicon lists them)", key="module", metavar="M"),
    Argument("--rtpu", help="the RTPU that runs it", key="rtpu", metavar="R"),
    Argument("--period", help="its period, with a unit: 10ms", key="period", metavar="P"),
    Argument("--priority", help="its priority among ready tasks", key="priority", metavar="N"),
    Argument("--critical", help="a critical task (runs first, watches its inputs)", key="critical", flag=True),
    Argument("--aperiodic", help="released by events, not by a timer", key="aperiodic", flag=True),
    Argument("--min-interarrival", help="an aperiodic task's shortest time between releases: 5ms", key="min_interarrival",
             metavar="T"),
    Argument("--param", help="a parameter: --param kp=300 (YAML value)", key="params", nargs="+", extend=True,
             metavar="K=V"),
    Argument("--port", help="a port's variable: --port tau=tau_u", key="ports", nargs="+", extend=True, metavar="P=VAR"),
    Argument("--resources", help="the devices it opens: --resources arm", key="resources", nargs="+", extend=True,
             metavar="DEVICE"),
)
_LIVE_REPLY = '`{"task": str, "state": str, "configuration": str, "entered": [str], "left": [str], "at": seconds}`'
_TASK_REPLY = '`{"task": str, "state": str}`'

VERBS: tuple[Verb, ...] = (
    Verb("status", "a running subsystem: tasks by RTPU with state, rate, jitter, overruns; current job, and where an "
                   "application that decides is (`pick > try > approach`)", (), "status",
         "the status reply: configuration, job, path (and its place: positions in the rows), elapsed, per task state, "
         "rate, jitter, overruns; flags; the gains a bandwidth made", STATUS_TIMEOUT),
    Verb("on", "turn a task on", (_TASK,), "on", _TASK_REPLY, COMMAND_TIMEOUT),
    Verb("off", "turn a task off", (_TASK,), "off", _TASK_REPLY, COMMAND_TIMEOUT),
    Verb("clear", "clear a task's error (its clear component decides: OFF, or still ERROR)", (_TASK,),
         "clear", _TASK_REPLY, COMMAND_TIMEOUT),
    Verb("switch", "switch the running subsystem to another configuration (dynamic, TR 4.4)",
         (Argument("configuration", help="the configuration to switch to", key="configuration",
                   complete="configuration"),), "switch",
         '`{"configuration": str, "entered": [str], "left": [str], "took": seconds}`', COMMAND_TIMEOUT),
    Verb("job", "start a job, with its object: pbo job reach ready, or its values: pbo job reach 0.3 -0.5 0.5 0 0.4 0.2",
         (Argument("name", help="the job's name", key="job", complete="job"),
          Argument("values", help="its object: a named object of the file, or its values", key="object", nargs="*",
                   parse=parse_job_object)),
         "job", '`{"job": str, "configuration": str}`', COMMAND_TIMEOUT),
    Verb("event", "send an event (with values) to an aperiodic task",
         (Argument("task", help="the aperiodic task's name", key="task", complete="task"),
          Argument("values", help="numbers the event carries", key="values", nargs="*", parse=parse_object_values)),
         "event", '`{"task": str}`'),
    Verb("play", "play a device the operator drives (a trackball with source: hmi): pbo play trackball 0.05 0 0 0 0 0",
         (Argument("device", help="the device's name", key="device", complete="device"),
          Argument("values", help="the numbers it reads from now on (a trackball: dx dy dz m, rx ry rz rad)", key="values",
                   nargs="*", parse=parse_object_values)),
         "play", '`{"device": str, "writes": int}`'),
    Verb("spawn", "spawn a task on the live subsystem, checked first, on at a cycle boundary: "
                  "pbo spawn logger --module data_logger --rtpu rtpu0 --period 10ms --param variables=[q_m]",
         (Argument("task", help="the new task's name", key="task", complete="task"), *_NEW_TASK), "spawn", _LIVE_REPLY,
         LIVE_TIMEOUT),
    Verb("kill", "kill a task of the live subsystem, checked first: off at a cycle boundary, then killed", (_TASK,), "kill",
         _LIVE_REPLY, LIVE_TIMEOUT),
    Verb("replace", "replace a task by a new one in one switch, checked first: pbo replace pid pd --param ki=0 "
                    "(the new task is the old one's entry with what is given)",
         (Argument("task", help="the task to replace", key="task", complete="task"),
          Argument("new", help="the new task's name", key="new"), *_NEW_TASK), "replace",
         _LIVE_REPLY + ' and `"replaced": str`', LIVE_TIMEOUT),
    Verb("set", "set a live-tunable parameter of a task, checked as in YAML, applied at a cycle boundary: pbo set pid kp 300",
         (_TASK, Argument("param", help="the parameter (its module declares it tunable); of a combined task, "
                                        "a member's: kp, 1.kp or pid_joint.kp", key="param"),
          Argument("values", help="its value (YAML); several make a list", key="values", nargs="+")),
         "set_parameter", _LIVE_REPLY + ' and `"param": str, "value": any`', LIVE_TIMEOUT),
    Verb("app", "run one of the file's applications on the live subsystem; with --steps, an application given here "
                "(checked first): pbo app tour2 --steps \"[reach: ready, hold]\"",
         (Argument("name", help="the application's name", key="application",
                   complete="application"),
          Argument("--steps", help="its steps as YAML, as the file writes them (replaces an application of that name)",
                   key="steps", metavar="YAML")),
         "app", '`{"application": str, "jobs": [str]}`', LIVE_TIMEOUT),
    Verb("save", "write the live subsystem as YAML: the file with the live changes, comments and order kept",
         (Argument("file", help="where to write it", key="file", parse=lambda path: os.path.abspath(path) if path else path),
          Argument("--force", help="overwrite the file if it exists", key="force", flag=True)),
         "save", '`{"file": str, "edits": int}`', COMMAND_TIMEOUT),
    Verb("svar", "state variables of the running subsystem: value, sequence, age, writer",
         (Argument("names", help="the variables to show (default: all)", nargs="*", complete="variable"),
          Argument("--watch", help="refresh until Ctrl-C", flag=True),
          Argument("--interval", help="seconds between refreshes with --watch (default 0.5)", type=float, default=0.5)),
         None, "read from the table by the operator's side, lock-free: no request"),
    Verb("stop", "stop the running subsystem cleanly", (), "stop", "`{}`", STATUS_TIMEOUT),
)
COMMANDS: dict[str, Verb] = {verb.name: verb for verb in VERBS}

# Every verb acts on one run; these pick it when several are alive (`ipc.runs.find_run`). The CLI
# gives them to every verb, and the docs say so under the verb table.
WHICH_RUN: tuple[Argument, ...] = (
    Argument("--subsystem", help="which running subsystem, by name (needed only when several run)", metavar="NAME",
             complete="subsystem"),
    Argument("--run", help="which run, by its id or a unique prefix of it (pbo runs lists them; needed only when "
                           "a subsystem runs more than once)", metavar="ID", complete="run"),
)
FORMAT = Argument("--format", help=FORMAT_HELP, choices=("text", "json"), default="text")  # every verb's, after WHICH_RUN
SERVED = tuple(verb.name for verb in VERBS if verb.handler is not None)


def verb_table() -> str:
    """The verbs as a markdown table, for docs/operator-commands.md."""
    lines = ["| verb | arguments | what it does | reply (besides `\"ok\": true`) |", "| --- | --- | --- | --- |"]
    for verb in VERBS:
        shown = []
        for argument in verb.arguments:
            text = argument.name.upper() if not argument.name.startswith("-") else argument.name
            text += " ..." if argument.nargs in ("*", "+") else ""
            shown.append(f"`{text}`" if not argument.name.startswith("-") else f"`[{text}]`")
        arguments = " ".join(shown) or "\u2013"  # an en dash: no arguments
        lines.append(f"| `pbo {verb.name}` | {arguments} | {verb.help.replace('|', '/')} | {verb.result} |")
    which = "; ".join(f"`{a.name} {a.metavar}`: {a.help}" for a in WHICH_RUN)
    return "\n".join(lines) + f"\n\nEvery verb also takes {which}.\n"
