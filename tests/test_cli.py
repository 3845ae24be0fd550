"""The `pbo` command as a user meets it: verdicts, exit codes, no tracebacks."""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from rich.console import Console

from pbo_runtime.cli import main
from pbo_runtime.cli.running import _sayer
from tests.support import REPO, assert_nothing_left, demo_copy

DEMO = (REPO / "configs" / "pid_joint.yaml").read_text()


def write(tmp_path: Path, text: str, name: str = "bad.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def three_mistakes() -> str:
    text = DEMO.replace("module: pid_joint", "module: pid_jiont")  # an unknown module
    text = text.replace("period: 2 ms", "period: -2 ms")  # a negative period
    text = text.replace("configurations:\n  joint_pid: [robot, traj, pid, logger]",
                        "configurations:\n  joint_pid: [robot, traj, pid, logger, gripper]")  # an unknown task
    return text


def line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


def test_check_reports_all_three_mistakes_with_their_lines_and_exits_1(tmp_path, capsys):
    text = three_mistakes()
    path = write(tmp_path, text)
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    errors = re.findall(rf"^{re.escape(str(path))}:(\d+):(\d+): error\[E\d+\]: (.*)$", err, re.MULTILINE)
    lines = sorted(int(line) for line, _, _ in errors)
    assert lines == sorted([line_of(text, "pid_jiont"), line_of(text, "-2 ms"), line_of(text, "gripper")])
    assert "did you mean 'pid_joint'" in err
    assert "Traceback" not in err
    assert re.search(r"^3 errors", err, re.MULTILINE)


def test_check_of_the_demo_prints_tasks_by_rtpu_and_the_init_order(capsys):
    assert main(["check", str(REPO / "configs" / "pid_joint.yaml")]) == 0
    out = capsys.readouterr().out
    assert "configuration 'joint_pid': rtpu1: robot; rtpu0: traj, pid, logger" in out
    assert re.search(r"init order: robot -> .*pid", out)


def test_check_json_gives_the_same_verdict_for_tools(tmp_path, capsys):
    assert main(["check", str(write(tmp_path, three_mistakes())), "--format", "json"]) == 1
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["ok"] is False and len(verdict["errors"]) == 3
    assert {"file", "line", "column", "message", "hint"} <= set(verdict["errors"][0])


ISSUE_33_MISTAKES = [  # what an examiner found passing pbo check, then crashing or harming the run
    pytest.param("kp: 400", "kp: .nan", "E308", r"parameter kp of task 'pid' \(module 'pid_joint'\) must be in \[0, 1e\+06\], "
                 r"got: \.nan \(not a number\)", id="kp_nan"),
    pytest.param("kp: 400", "kp: .inf", "E308", r"parameter kp .* got: \.inf", id="kp_inf"),
    pytest.param("kp: 400", "kp: 1.0e+308", "E308", r"parameter kp .* got: 1e\+308", id="kp_huge"),
    pytest.param("max_velocity: 1.0", "max_velocity: .nan", "E308",
                 r"parameter max_velocity of task 'traj' \(module 'joint_trajectory'\) must be in \(0, 100\]",
                 id="max_velocity_nan"),
    pytest.param("subsystem: puma", "subsystem: " + "p" * 300, "E218", r"subsystem name 'p+\.\.\.p+' is 300 characters long",
                 id="a_300_character_name"),
    pytest.param("period: 1 ms, critical", "period: 1e300 s, critical", "E513",
                 r"period of task 'robot' must be between 10 us and 1 h, got: 1e300 s", id="period_1e300_s"),
    pytest.param("period: 1 ms, critical", "rate: 1e-300 Hz, critical", "E513",
                 r"rate of task 'robot' must be between one cycle an hour and 100 kHz, got: 1e-300 Hz", id="rate_1e-300_hz"),
]


@pytest.mark.parametrize(("old", "new", "code", "message"), ISSUE_33_MISTAKES)
def test_check_refuses_a_value_out_of_its_bounds_at_its_line_and_exits_1(tmp_path, capsys, old, new, code, message):
    assert old in DEMO
    text = DEMO.replace(old, new, 1)
    path = write(tmp_path, text)
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    column = text.splitlines()[line_of(text, new) - 1].index(new.split(": ", 1)[1].split(",")[0]) + 1
    assert re.match(rf"^{re.escape(str(path))}:{line_of(text, new)}:{column}: error\[{code}\]: {message}", err), err
    assert "Traceback" not in err and re.search(r"^1 error, 0 warnings$", err, re.MULTILINE)


def test_check_of_a_loop_whose_every_period_is_out_of_bounds_reports_the_periods_only(tmp_path, capsys):
    # the joint loops' check must not analyse a loop whose periods were refused (it divided by them)
    text = DEMO.replace("period: 1 ms", "period: 1e300 s")
    assert main(["check", str(write(tmp_path, text))]) == 1
    err = capsys.readouterr().err
    codes = re.findall(r": error\[(E\d+)\]: ", err)
    assert codes and set(codes) == {"E513"} and "Traceback" not in err, err


def test_check_of_a_missing_file_is_an_error_not_a_traceback(tmp_path, capsys):
    assert main(["check", str(tmp_path / "nowhere.yaml")]) == 1
    err = capsys.readouterr().err
    assert "nowhere.yaml" in err and "Traceback" not in err


@pytest.mark.multiprocess
@pytest.mark.parametrize(("text", "errors"),
                         [(three_mistakes(), 3), (DEMO.replace("subsystem: puma", "subsystem: " + "p" * 300), 1)],
                         ids=["three_mistakes", "a_300_character_name"])
def test_run_refuses_a_file_with_errors_and_starts_nothing(tmp_path, text, errors):
    done = subprocess.run([sys.executable, "-m", "pbo_runtime.cli", "run", str(write(tmp_path, text))],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 1
    assert len(re.findall(r": error\[E\d+\]: ", done.stderr)) == errors and "Traceback" not in done.stderr
    assert "starting subsystem" not in done.stdout


# `pbo run` whose summary is interrupted by SIGTERM and Ctrl-C, as an application runner stopping
# its subsystems, or an impatient operator, sends them to a run that has just ended
STOPPED_WHILE_SUMMARISING = """
import importlib, os, signal, sys
cli = importlib.import_module("pbo_runtime.cli.main")  # the package exports the function of the same name
summary = importlib.import_module("pbo_runtime.cli.summary")

summarise = summary._print_summary

def stopped_twice_while_summarising(*args):
    os.kill(os.getpid(), signal.SIGTERM)
    os.kill(os.getpid(), signal.SIGINT)
    summarise(*args)

summary._print_summary = stopped_twice_while_summarising
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.multiprocess
def test_a_stop_after_the_run_has_ended_does_not_lose_its_summary_or_report(tmp_path):
    config = demo_copy(tmp_path, "second_stop")
    done = subprocess.run([sys.executable, "-c", STOPPED_WHILE_SUMMARISING, "run", str(config), "--clock", "sim",
                           "--duration", "0.2", "--no-live", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "run summary" in done.stdout
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["stopped_by"] == "duration" and not report["faults"]
    assert_nothing_left(report)


def test_lexicon_lists_every_module_with_its_ports_and_params(capsys):
    assert main(["lexicon", "--format", "json"]) == 0
    entries = {e["name"]: e for e in json.loads(capsys.readouterr().out)}
    assert {"robot_torque", "joint_trajectory", "pid_joint", "data_logger", "join"} <= set(entries)
    assert {p["name"]: p["default"] for p in entries["pid_joint"]["params"]}["kp"] == 400.0
    out_consts = {p["variable"] for p in entries["robot_torque"]["ports"] if p["kind"] == "out-const"}
    assert out_consts == {"NDOF", "ARM", "EE"}


def test_bus_prints_each_tasks_load_and_the_total_and_draws_the_plot(tmp_path, capsys):
    plot = tmp_path / "bus.png"
    assert main(["bus", str(REPO / "configs" / "pid_joint.yaml"), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "272.0" in out and "B (total)" in out and "601.6" in out  # pid: (192 + 48 + 32 B) / 1 ms
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bus_csv_has_a_line_per_task_and_a_total(capsys):
    assert main(["bus", str(REPO / "configs" / "pid_joint.yaml"), "--format", "csv"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 + 4 + 1


def test_graph_draws_the_configuration_as_svg_and_as_dot(tmp_path, capsys):
    svg = tmp_path / "fig8.svg"
    assert main(["graph", str(REPO / "configs" / "pid_joint.yaml"), "-o", str(svg)]) == 0
    assert "<svg" in svg.read_text()[:2000]
    capsys.readouterr()
    assert main(["graph", str(REPO / "configs" / "pid_joint.yaml")]) == 0
    assert "digraph" in capsys.readouterr().out


def test_graph_of_an_unknown_configuration_names_the_valid_ones(capsys):
    assert main(["graph", str(REPO / "configs" / "pid_joint.yaml"), "--config", "nope"]) == 1
    assert "joint_pid" in capsys.readouterr().err


def test_the_committed_schema_is_what_pbo_schema_prints(capsys):
    assert main(["schema"]) == 0
    assert capsys.readouterr().out == (REPO / "configs" / "pbo-subsystem.schema.json").read_text()


@pytest.mark.parametrize("config", sorted((REPO / "configs").glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_configuration_passes_the_checker(config, capsys):
    assert main(["check", str(config)]) == 0, capsys.readouterr().err


def test_the_summary_tells_a_late_release_from_a_long_cycle():
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.reports.run_result import RtpuSettings, TaskReport
    from pbo_runtime.reports.run_summary import overrun_lines

    subsystem = load_subsystem(REPO / "configs" / "pid_joint.yaml")
    figures = {
        "robot": {"overruns": 2, "overruns_late_release": 2, "overruns_long_cycle": 0, "jitter_max": 0.0031,
                  "exec_max": 0.00002, "last_overruns": [[0.25, 0.0031, 0.00002], [1.5, 0.0012, 0.00002]]},
        "pid": {"overruns": 9, "overruns_late_release": 0, "overruns_long_cycle": 9, "jitter_max": 0.0,
                "exec_max": 0.0042, "last_overruns": [[0.001 * i, 0.0, 0.0042] for i in range(8)]},
        "traj": {"overruns": 0},
    }
    tasks = {name: TaskReport.from_json(entry) for name, entry in figures.items()}
    robot, pid = overrun_lines(subsystem, tasks)
    assert robot == ("overruns of 'robot' (1 ms period): 2 late releases (started up to 3.10 ms late: the machine held the "
                     "RTPU's CPU; SCHED_FIFO (drop --no-fifo) or pinning with rtpus: {cpu: N} help); at 0.250 s, "
                     "1.500 s into the run")

    def robot_line_under(scheduler: str) -> str:
        on_rtpu1 = {**tasks, "robot": TaskReport.from_json({**figures["robot"], "rtpu": "rtpu1"})}
        line, _ = overrun_lines(subsystem, on_rtpu1, {"rtpu1": RtpuSettings.from_json({"scheduler": scheduler})})
        return line

    assert "(started up to 3.10 ms late: the machine held the RTPU's CPU; it ran SCHED_FIFO already, so only the " \
           "kernel or, on a VM, the hypervisor held it)" in robot_line_under("SCHED_FIFO 50")
    assert "the RTPU's CPU; the OS refused SCHED_FIFO (see the RTPU's line below); pinning with rtpus: {cpu: N} " \
           "helps meanwhile)" in robot_line_under("SCHED_OTHER: SCHED_FIFO refused ([Errno 1] Operation not permitted)")
    assert pid.startswith("overruns of 'pid' (1 ms period): 9 long cycles (ran up to 4.20 ms: the module needs more than "
                          "its period; lighten its cycle or lengthen its period); the last 8 at 0.000 s, 0.001 s,")


def test_pbo_status_names_what_each_rtpu_runs_under():
    from rich.console import Console

    from pbo_runtime.cli.operator import scheduler_brief, status_table

    refused = "SCHED_OTHER: SCHED_FIFO refused ([Errno 1] Operation not permitted); it needs CAP_SYS_NICE"
    assert scheduler_brief({"scheduler": "SCHED_FIFO 50", "cpu": "any"}) == "FIFO 50"
    assert scheduler_brief({"scheduler": refused, "cpu": "1"}) == "OTHER (FIFO refused), cpu 1"
    assert scheduler_brief({"scheduler": "SCHED_OTHER", "cpu": "not pinned: CPU 9: invalid"}) == "OTHER, not pinned"
    assert scheduler_brief({"clock": "simulated, 1 ms ticks"}) == "sim clock"
    reply = {"subsystem": "puma", "run_id": "1-ab", "configuration": "pid", "elapsed": 1.0,
             "tasks": [{"task": "robot", "rtpu": "rtpu0", "state": "ON"}, {"task": "pid", "rtpu": "rtpu1", "state": "ON"}],
             "realtime": {"rtpu0": {"scheduler": "SCHED_FIFO 50", "cpu": "any"}, "rtpu1": {"scheduler": refused, "cpu": "any"}}}
    console = Console(record=True, width=160)
    console.print(status_table(reply))
    text = console.export_text()
    assert "FIFO 50" in text and "OTHER (FIFO refused)" in text
    console = Console(record=True, width=220)
    console.print(status_table({**reply, "stalled": {"pid": 2.04}}))
    assert "ON, no cycle for 2.0 s" in console.export_text()
    console = Console(record=True, width=160)
    console.print(status_table({**reply, "realtime": {}}))  # a supervisor of an older run: no column breaks
    assert "robot" in console.export_text()


def test_pbo_status_shows_each_rtpus_restarts_with_the_last_cause_and_its_time_back_to_on():
    from rich.console import Console

    from pbo_runtime.cli.operator import status_table

    restarts = [{"rtpu": "rtpu1", "pid": 7, "cause": "killed by SIGKILL", "died_at": 1.0, "on_again_at": 1.4, "seconds": 0.4,
                 "tasks_on": ["pid"], "attempts": 1},
                {"rtpu": "rtpu1", "pid": 9, "cause": "killed by SIGABRT", "died_at": 3.0, "on_again_at": None, "seconds": None,
                 "tasks_on": ["pid"], "attempts": 1}]
    reply = {"subsystem": "puma", "run_id": "1-ab", "configuration": "pid", "elapsed": 4.0,
             "tasks": [{"task": "robot", "rtpu": "rtpu0", "state": "ON"},
                       {"task": "pid", "rtpu": "rtpu1", "state": "NOT_CREATED"}],
             "realtime": {}, "restarts": restarts[:1]}
    console = Console(record=True, width=200)
    console.print(status_table(reply))
    assert "restarted 1x; last killed by SIGKILL, ON again in 400 ms" in console.export_text()
    console = Console(record=True, width=200)
    console.print(status_table({**reply, "restarts": restarts}))
    assert "restarted 2x; last killed by SIGABRT, coming back" in console.export_text()


@pytest.mark.parametrize("argv", [["--version"], ["--debug", "--version"]], ids=["alone", "through the parser"])
def test_version_prints_the_version_pyproject_declares(capsys, argv):
    import tomllib

    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    try:
        code = main(argv)  # alone: answered before any parser is built
    except SystemExit as stopped:  # argparse's --version action
        code = stopped.code
    assert code == 0
    assert capsys.readouterr().out == f"pbo {declared}\n"


@pytest.mark.parametrize("argv, said", [
    (["chekc", "x.yaml"], "invalid choice: 'chekc'"),
    (["run", "x.yaml", "--durration", "3"], "unrecognized arguments: --durration 3\n  did you mean '--duration'?"),
    (["run", "x.yaml", "--clokc", "sim", "--statc"], "did you mean '--clock' for '--clokc', '--static' for '--statc'?"),
    (["run", "x.yaml", "--config"], "argument --config: expected one argument"),
    (["log", "export"], "the following arguments are required: RUN_DIR_OR_LOG, --csv"),
    (["set", "pid"], "the following arguments are required: param, values"),
])
def test_a_wrong_argument_exits_1_as_the_readme_says_with_the_closest_verb_or_flag(argv, said, capsys):
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    assert stopped.value.code == 1
    assert said in capsys.readouterr().err


def test_a_misspelt_verb_is_answered_with_the_closest_one(capsys):
    with pytest.raises(SystemExit):
        main(["chekc", "x.yaml"])
    assert capsys.readouterr().err.endswith("  did you mean 'check'?\n")


@pytest.mark.parametrize("argv, said", [
    (["--config", "joint_pdi"],
     "error: no configuration 'joint_pdi' in {file}: did you mean 'joint_pid'? (configurations: joint_pid)"),
    (["--app", "tuor"], "error: no application 'tuor' in {file} (applications: none)"),
])
def test_a_configuration_or_application_the_file_lacks_is_a_wrong_argument_exit_1_with_no_run_started(argv, said, tmp_path,
                                                                                                       capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config = demo_copy(tmp_path, "wrong_argument")
    assert main(["run", str(config), "--clock", "sim", "--no-live", *argv]) == 1
    assert said.format(file=config) in capsys.readouterr().err
    assert list((tmp_path / "runs").glob("*")) == []  # refused before anything started


# --- issue 18: files that are not UTF-8, or too large, are bad input: one line, exit 1 ----------------------


def latin1(text: str) -> bytes:
    return text.encode("latin-1")


@pytest.mark.parametrize("verb", [["check"], ["run", "--clock", "sim", "--duration", "0.01", "--no-live"]], ids=["check", "run"])
@pytest.mark.parametrize("what", ["subsystem", "application"])
def test_a_yaml_file_that_is_not_utf8_is_one_clear_error_with_exit_1(tmp_path, capsys, verb, what):
    application = f"application: demo\n# réglé\nsubsystems: {{a: {REPO / 'configs' / 'pid_joint.yaml'}}}\n"
    text = DEMO + "# réglé\n" if what == "subsystem" else application
    path = tmp_path / "latin.yaml"
    path.write_bytes(latin1(text))
    offset = latin1(text).index(b"\xe9")
    line = text[:offset].count("\n") + 1
    assert main([verb[0], str(path), *verb[1:]]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err
    assert re.search(rf"^{re.escape(str(path))}:{line}:\d+: error\[E100\]: not UTF-8 text: byte 0xe9 at byte offset {offset} "
                     rf"cannot be decoded\n  hint: save the file as UTF-8", err, re.MULTILINE), err


def test_a_file_over_the_size_limit_is_refused_before_it_is_parsed(tmp_path, capsys):
    from pbo_runtime.config.limits import MAX_FILE_BYTES

    path = tmp_path / "huge.yaml"
    with path.open("w") as out:  # a 20 MB YAML list took 3.1 GB and 15.6 s to check
        out.write("subsystem: huge\nx: [" + "0, " * (MAX_FILE_BYTES // 3) + "0]\n")
    size = path.stat().st_size
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"{path}: error[E106]: the file is {size:,} bytes (4 MiB); a configuration file may be at most "
                          f"4,194,304 bytes (4 MiB)\n  hint: ")


def test_a_runs_line_stays_one_line_however_long_and_keeps_its_brackets():
    out = io.StringIO()
    say = _sayer(Console(file=out, width=40, highlight=False))
    line = "RTPU 'rtpu0' died while hosting tasks: traj, pid; restarting it in 'pd' [rtpu0] {max: 3}"
    say(line)
    assert out.getvalue() == f"pbo: {line}\n"
