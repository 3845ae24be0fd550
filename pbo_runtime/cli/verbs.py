"""The `pbo` verbs that need no running subsystem, declared once: name, help, arguments, handler.

The parser (`cli.parser`), shell completion and the docs' table of these verbs are made from this
table; the operator's verbs come from `supervisor.command_table`. A handler is named, not imported
("module:function", imported when its verb runs), so `pbo --help` loads none of the wings behind them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pbo_runtime.supervisor.command_table import WHICH_RUN, Argument


@dataclass(frozen=True)
class Command:
    """A verb of `pbo`: what the help says, what it takes, which function runs it (or its own verbs)."""

    name: str
    help: str
    arguments: tuple[Argument, ...] = ()
    handler: str = ""  # "module:function(args, console, errors) -> exit status"; "" when it has verbs of its own
    verbs: tuple[Command, ...] = ()  # `pbo log export`, `pbo log info`


_FILE = Argument("file")
_ADDRESS = Argument("--address", help="an application's host address, over the one in its hosts: (repeat for more)",
                    append=True, default=(), metavar="HOST=ADDRESS")
_EXEC_TIME = Argument("--exec-time", choices=("max", "p99"), default="max",
                      help="with --profile: each task's execution time C is its longest cycle (max, the default: safe) "
                           "or its 99th percentile (p99)")
_RUN_DIR = "a run's directory (pbo run prints it) or a .mcap or .npy data log"
_OUTPUT = Argument("--output", short="-o", help="write it here (default: stdout)", type=Path)

OFFLINE: tuple[Command, ...] = (
    Command("check", "check a subsystem file like a compiler: every error, with its line", (
        _FILE,
        Argument("--format", choices=("text", "json"), default="text"),
        Argument("--profile", metavar="RUN",
                 help="a run's report.json (or its directory): prove or refute each critical deadline with the "
                      "measured execution times (non-preemptive response-time analysis, docs/scheduling.md)"),
        _EXEC_TIME, _ADDRESS), "pbo_runtime.cli.check:check"),
    Command("allocate", "propose the fewest task moves between RTPUs that prove every critical deadline", (
        _FILE,
        Argument("--profile", metavar="RUN", required=True, help="a run's report.json (or its directory)"),
        _EXEC_TIME,
        Argument("--config", help="judge only this configuration (default: every one the profile measured)",
                 complete="configuration"),
        Argument("--pin", append=True, metavar="TASK[,TASK]", help="keep this task on its RTPU (repeat for more)"),
        Argument("--free", append=True, metavar="TASK[,TASK]",
                 help="let this user of an exclusive device move (by default it keeps its RTPU)")),
        "pbo_runtime.cli.schedule:allocate"),
    Command("run", "run a subsystem: plant, RTPUs, tasks; prints a summary at the end", (
        _FILE,
        Argument("--duration", type=float, default=5.0,
                 help="seconds to run once the configuration is on (default 5; 0: until Ctrl-C)"),
        Argument("--config", help="the configuration to turn on (default: the first in the file)", complete="configuration"),
        Argument("--report", type=Path, help="write the run report (per task timing, final values) as JSON here"),
        Argument("--no-live", flag=True, help="no live status table (the default when output is not a terminal)"),
        Argument("--app", help="run this application's jobs one at a time, then stop", complete="application"),
        Argument("--fifo", negatable=True,
                 help="RTPUs (priority 50) and the plant (60) under SCHED_FIFO where the OS allows it: the default "
                      "with the real clock; the summary says if the OS refused. --no-fifo: SCHED_OTHER"),
        Argument("--static", flag=True,
                 help="static reconfiguration: only the current configuration's tasks exist (kill and spawn between jobs)"),
        Argument("--clock", choices=("real", "sim"), default="real",
                 help="sim: simulated time in lockstep ticks, as fast as the machine allows; the run replays bit for bit"),
        Argument("--one-process", flag=True,
                 help="with --clock sim: the plant and every RTPU in this one process, taking their turns in the "
                      "same order: the same run (logs and report), without a process hand-over per tick"),
        Argument("--pace", type=float, metavar="FACTOR",
                 help="with --clock sim: at most FACTOR simulated seconds per wall second (1: real time, to watch "
                      "the run in the HMI; 0.01 to 1000); the same run, only no faster"),
        Argument("--out", type=Path, metavar="DIR",
                 help="the run's output directory: its report (report.json), its data logs and every file it "
                      "writes (default: runs/SUBSYSTEM-DATE-TIME/ in the current directory)"),
        Argument("--allow-unstable-loops", flag=True,
                 help="run even when pbo check finds a joint's position loop unstable (E326): to see what it predicts"),
        Argument("--host", metavar="NAME",
                 help="an application placed on hosts: run only the subsystems of this host (default: all, here)"),
        _ADDRESS,
        # set by an application's runner: its links (JSON), this subsystem's stages, its turn on --clock sim
        Argument("--links", hidden=True),
        Argument("--stages", hidden=True),
        Argument("--turn", hidden=True),
        Argument("--alternate", metavar="A,B", help="switch test: alternate between these configurations"),
        Argument("--switches", type=int, default=100, help="with --alternate: how many switches (default 100)"),
        Argument("--interval", type=float, default=0.05, help="with --alternate: seconds between switches (default 0.05)")),
        "pbo_runtime.cli.running:run"),
    Command("plot", "plot a run's logged variables against time, switches and jobs marked", (
        Argument("target", metavar="RUN_DIR_OR_LOG", help="a run's directory (pbo run prints it) or a log file"),
        Argument("variables", nargs="*", metavar="AXIS",
                 help="an axis to plot: a variable (q_m), several overlaid (q_m,q_r), an element (q_m[1]), a "
                      "difference (q_m-q_r); default: every variable logged, one axis each"),
        Argument("--output", short="-o", type=Path, help="write the plot to this .png, .svg or .pdf (default: a window)")),
        "pbo_runtime.cli.logs:plot"),
    Command("log", "a data log for other tools: pbo log info RUN, pbo log export RUN --csv", verbs=(
        Command("export", "write a log as CSV for spreadsheets: one column per element, units in the header", (
            Argument("log", metavar="RUN_DIR_OR_LOG", help=_RUN_DIR),
            Argument("--csv", flag=True, required=True, help="as CSV (the one format for now)"),
            Argument("--output", short="-o", type=Path,
                     help="write it here (default: stdout); a run of several logs: a directory, one LOG.csv each")),
            "pbo_runtime.cli.logs:export"),
        Command("info", "what a log holds, as ros2 bag info prints it: size, duration, start, topics", (
            Argument("log", metavar="RUN_DIR_OR_LOG", help="a run's directory (every log in it) or a .mcap or .npy data log"),),
            "pbo_runtime.cli.logs:info"))),
    Command("bus", "bus utilisation of each configuration (TR eq. 1-2), predicted and measured", (
        _FILE,
        Argument("--config", help="only this configuration (default: all)", complete="configuration"),
        Argument("--run-report", type=Path, help="a run's JSON report (pbo run --report): measured beside predicted"),
        Argument("--combine", help="tasks to evaluate as one combined module (TR §4.5), comma-separated"),
        Argument("--format", choices=("table", "json", "csv"), default="table"),
        Argument("--plot", type=Path, help="draw per-task bars and the bandwidth line into this PNG")),
        "pbo_runtime.cli.file_reports:bus"),
    Command("lexicon", "list the module library: every module's ports and parameters", (
        Argument("--format", choices=("table", "json"), default="table"),
        Argument("--drivers", flag=True, help="list the device drivers (TR 4.6) instead of the modules")),
        "pbo_runtime.cli.file_reports:lexicon"),
    Command("place", "which lexicon modules can be placed in a configuration, and why not the rest", (
        _FILE,
        Argument("--config", help="the configuration (default: the first in the file)", complete="configuration"),
        Argument("--tasks", help="the configuration's tasks instead, comma-separated (a canvas being built)"),
        Argument("--rtpu", help="the RTPU the module would run on (default: the first)"),
        Argument("--module", append=True, help="only this module (repeat for more; default: every registered one)"),
        Argument("--format", choices=("text", "json"), default="text")),
        "pbo_runtime.cli.file_reports:place"),
    Command("graph", "draw a configuration as a block diagram (.svg, .png or .dot)", (
        _FILE,
        Argument("--config", help="the configuration to draw (default: the first)", complete="configuration"),
        Argument("--output", short="-o", type=Path, help="out.svg, out.png or out.dot (default: DOT text on stdout)")),
        "pbo_runtime.cli.file_reports:graph"),
    Command("schema", "the JSON Schema of the subsystem format, for editors", (_OUTPUT,),
            "pbo_runtime.cli.file_reports:schema"),
    Command("examples", "copy the example subsystem files and their JSON Schema into a folder, to run and edit", (
        Argument("dir", nargs="?", type=Path, default=Path("pbo-examples"), metavar="DIR",
                 help="where to put them (default: ./pbo-examples; made if missing)"),
        Argument("--force", flag=True, help="overwrite files there that differ from the shipped ones")),
        "pbo_runtime.cli.examples:copy"),
    Command("robot", "an arm's joints, limits, masses and inertia range; with --bandwidth, its gains", (
        Argument("model", metavar="MODEL|FILE",
                 help="a registered robot (puma560, redundant7), a URDF or MJCF file, or a package:// URI"),
        Argument("--ee", help="the end effector: a link or site of the file (default: the tip of the chain)"),
        Argument("--bandwidth", type=float, metavar="W",
                 help="rad/s: print each joint's gains for this closed-loop bandwidth (as pid_joint's bandwidth: makes them)"),
        Argument("--damping", type=float, default=1.0, metavar="Z", help="damping ratio for --bandwidth (default 1.0)"),
        Argument("--integral-time", type=float, default=0.0, metavar="S",
                 help="s: add integral action ki = kp / S (default: none)"),
        Argument("--step", type=float, default=0.1, metavar="RAD",
                 help="rad (m): the position step whose torque kp * step is compared with the effort limit (default 0.1)"),
        Argument("--period", type=float, default=0.001, metavar="S",
                 help="s: the controller's period for the loop's verdict (default 0.001; one period of delay)"),
        Argument("--format", choices=("text", "json"), default="text")),
        "pbo_runtime.cli.robot:run"),
)

# listed after the operator's verbs in `pbo --help`
HOUSEKEEPING: tuple[Command, ...] = (
    Command("runs", "list your live runs: subsystem, run id, pid, start, configuration, job, file", (
        Argument("--subsystem", help="only this subsystem's runs", complete="subsystem"),
        Argument("--format", choices=("text", "json"), default="text", help="json: the runs as a list of objects"),
        Argument("--json", flag=True, hidden=True)),  # the older spelling of --format json
        "pbo_runtime.cli.operator:list_runs"),
    Command("hmi", "serve the local API (HTTP + WebSocket) for a live run, on 127.0.0.1 with a token", (
        Argument("file", nargs="?", help="the subsystem file for lexicon, check, bus and graph (default: the run's own); "
                                         "an application file: its stages, edited and run from the page"),
        Argument("--port", type=int, default=8470, help="TCP port (default 8470; 0: any free port, printed)"),
        Argument("--host", default="127.0.0.1",
                 help="address to listen on (default 127.0.0.1: this machine only; another needs --allow-remote)"),
        Argument("--allow-remote", flag=True,
                 help="accept a --host other machines can reach (the token then crosses the network in clear text)"),
        *WHICH_RUN), "pbo_runtime.cli.hmi:serve_api"),
    Command("ros2", "a ROS 2 node beside a live run: pbo ros2 jobs reach (needs the ros2 extra)", verbs=(
        Command("jobs", "start a job of the live run with each ROS 2 message's values as its object", (
            Argument("job", help="the job each message starts", complete="job"),
            Argument("--topic", help="the ROS 2 topic (default: /pbo/JOB)"),
            Argument("--type", choices=("trajectory_msgs/msg/JointTrajectory", "std_msgs/msg/Float64MultiArray"),
                     default="trajectory_msgs/msg/JointTrajectory",
                     help="the message type (default: a JointTrajectory, whose last point is the object)"),
            Argument("--joint-names", nargs="+", metavar="NAME",
                     help="the object's joints in its order, for a trajectory that names them (default: joint1..jointN)"),
            Argument("--domain", type=int, default=-1, help="the DDS domain (default: ROS_DOMAIN_ID, else 0)"),
            Argument("--once", flag=True, help="end after the first job started"),
            *WHICH_RUN), "pbo_runtime.cli.ros2_jobs:serve"),)),
    Command("completion", "print the shell completion script: eval \"$(pbo completion bash)\"", (
        Argument("shell", choices=("bash", "zsh", "tcsh")),), "pbo_runtime.cli.completion:print_script"),
    Command("clean", "remove your shared memory, semaphores and queues left by dead runs", (
        Argument("--subsystem", help="only this subsystem's leftovers", complete="subsystem"),),
        "pbo_runtime.cli.cleanup:clean"),
)


def verb_lines(commands: tuple[Command, ...], prefix: str = "pbo") -> list[str]:
    """The verbs as rows of a markdown table, sub-verbs under their verb."""
    lines = []
    for command in commands:
        if command.verbs:
            lines.extend(verb_lines(command.verbs, f"{prefix} {command.name}"))
            continue
        shown = [f"`{_usage(argument).replace('|', '/')}`" for argument in command.arguments if not argument.hidden]
        lines.append(f"| `{prefix} {command.name}` | {' '.join(shown) or '–'} | {command.help.replace('|', '/')} |")  # noqa: RUF001 - an en dash: no arguments
    return lines


def _usage(argument: Argument) -> str:
    if not argument.name.startswith("-"):
        text = (argument.metavar or argument.name.upper()) + (" ..." if argument.nargs in ("*", "+") else "")
        return f"[{text}]" if argument.nargs in ("?", "*") else text
    return argument.name if argument.required else f"[{argument.name}]"


def verb_table() -> str:
    """The verbs on files and the machine as a markdown table, for docs/operator-commands.md."""
    head = ["| verb | arguments | what it does |", "| --- | --- | --- |"]
    return "\n".join(head + verb_lines(OFFLINE + HOUSEKEEPING)) + "\n"
