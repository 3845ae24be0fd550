"""The CLI's conventions: `--format json` on every operator verb, `pbo runs --format json`, and shell
completion generated from the parser.

The run the verbs talk to is a real table named like a run of this process and a real control
queue, served from a thread by `commands.dispatch` on the fake job host of the command tests: the
CLI finds it, sends, and prints exactly as it does for a live run.
"""

from __future__ import annotations

import json
import os
import threading
import uuid
from collections.abc import Iterator
from typing import Any

import pytest

from pbo_runtime.api.jsonable import jsonable
from pbo_runtime.cli import operator
from pbo_runtime.cli.main import _parser, main
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.control import ControlServer, answer
from pbo_runtime.supervisor.commands import COMMANDS, VERBS, dispatch
from pbo_runtime.table.table import StateTable, TableLayout
from tests.fake_job_host import FakeJobHost, fake_subsystem
from tests.support import variables


class ServedFakeRun:
    """A live run as the CLI finds it (table and control queue), whose supervisor is a thread
    answering with `dispatch` on a fake job host."""

    def __init__(self, host: FakeJobHost) -> None:
        self.host = host
        self.subsystem = f"cli{uuid.uuid4().hex[:6]}"
        self.run_id = f"{os.getpid()}-{uuid.uuid4().hex[:6]}"
        layout = TableLayout.build(variables(("q_m", "float64", (3,)), ("n", "int32", ())), 2)
        self.table = StateTable.create(layout, messages.table_name(self.subsystem, self.run_id))
        self.server = ControlServer(self.subsystem, self.run_id)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            self.server.poll(lambda command, arguments: dispatch(self.host, command, arguments))
            self._stop.wait(0.001)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.server.close()
        self.table.close()


@pytest.fixture(scope="module")
def subsystem(tmp_path_factory):
    return fake_subsystem(tmp_path_factory.mktemp("cli"))


@pytest.fixture
def fake_run(subsystem) -> Iterator[ServedFakeRun]:
    run = ServedFakeRun(FakeJobHost(subsystem, "pid"))
    yield run
    run.close()


def pbo_json(capsys, *arguments: str) -> tuple[int, Any]:
    status = main([*arguments, "--format", "json"])
    return status, json.loads(capsys.readouterr().out)


def test_every_operator_verb_and_runs_take_format_json():
    subparsers = next(a for a in _parser()._actions if a.dest == "command").choices
    for name in [*COMMANDS, "runs"]:
        formats = [a for a in subparsers[name]._actions if a.dest == "format"]
        assert formats and formats[0].choices == ("text", "json") and formats[0].default == "text", name
    assert set(operator._LOCAL_JSON) == {verb.name for verb in VERBS if verb.handler is None}


@pytest.mark.parametrize(("arguments", "status"), [
    (["status"], 0),
    (["off", "pid"], 0),
    (["on", "pd"], 2),  # the run's state refuses: not in the running configuration
    (["on", "nope"], 1),  # the request is wrong: no such task
    (["switch", "pd"], 0),
    (["job", "hold"], 0),
    (["job", "move", "1", "x"], 1),  # refused on the command line already, before anything is sent
    (["stop"], 0),
])
def test_a_verb_with_format_json_prints_the_reply_dict_the_supervisor_sent_with_the_text_forms_exit_status(
        capsys, subsystem, fake_run, arguments, status):
    exit_status, printed = pbo_json(capsys, *arguments, "--subsystem", fake_run.subsystem)
    assert exit_status == status
    verb = COMMANDS[arguments[0]]
    try:
        request = verb.request(vars(_parser().parse_args(arguments)))
    except Exception as exc:  # the command line's own refusal
        expected = {"ok": False, "error": str(exc), "bad_request": True}
    else:
        expected = jsonable(answer(lambda c, a: dispatch(FakeJobHost(subsystem, "pid"), c, a), verb.name, request))
    if arguments[0] == "switch":  # how long the switch took is the host's
        printed.pop("took"), expected.pop("took")
        printed["message"] = printed["message"].split(" in ")[0]
        expected["message"] = expected["message"].split(" in ")[0]
    assert printed == expected
    if arguments[0] == "status":
        assert printed["configuration"] == "pid" and [t["task"] for t in printed["tasks"]] == ["robot", "traj", "pid", "pd"]


def test_format_json_without_the_run_prints_the_error_as_json_and_exits_2(capsys):
    status, printed = pbo_json(capsys, "status", "--subsystem", "no_such_subsystem_here")
    assert status == 2 and printed["ok"] is False
    assert printed["error"].startswith("subsystem 'no_such_subsystem_here' is not running")


def test_svar_with_format_json_prints_the_rows_pbo_svar_shows(capsys, fake_run):
    fake_run.table.write("q_m", [0.5, -0.25, 1.0], when=1.0)
    status, printed = pbo_json(capsys, "svar", "q_m", "--subsystem", fake_run.subsystem)
    assert status == 0 and (printed["ok"], printed["subsystem"], printed["run_id"]) == (True, fake_run.subsystem, fake_run.run_id)
    [row] = printed["variables"]
    assert (row["name"], row["value"], row["sequence"], row["writer"]) == ("q_m", "[+0.5000, -0.2500, +1.0000]", 1, "job control")
    status, printed = pbo_json(capsys, "svar", "q_mes", "--subsystem", fake_run.subsystem)
    assert status == 2 and printed["error"].startswith("no variable 'q_mes' in ") and "did you mean 'q_m'?" in printed["error"]


def test_runs_with_format_json_lists_the_live_run(capsys, fake_run):
    status = main(["runs", "--subsystem", fake_run.subsystem, "--format", "json"])
    [run] = json.loads(capsys.readouterr().out)
    assert status == 0 and (run["subsystem"], run["run_id"], run["configuration"]) == (fake_run.subsystem, fake_run.run_id, "pid")
    main(["runs", "--subsystem", fake_run.subsystem, "--json"])  # the older spelling still works
    assert json.loads(capsys.readouterr().out)[0]["run_id"] == fake_run.run_id


@pytest.mark.parametrize("shell", ["bash", "zsh"])
def test_the_completion_script_is_generated_from_the_parser_and_knows_every_verb(capsys, shell):
    assert main(["completion", shell]) == 0
    script = capsys.readouterr().out
    assert ("#compdef pbo" in script) if shell == "zsh" else script.rstrip().endswith("complete -o bashdefault -F _shtab_pbo pbo")
    for name in [*COMMANDS, "check", "run", "runs", "hmi", "completion"]:
        assert name in script, name
    assert "--format" in script and "--subsystem" in script


def test_names_complete_from_the_file_on_the_command_line_its_includes_too(tmp_path):
    from pbo_runtime.cli.completion import names

    (tmp_path / "jobs.yaml").write_text("jobs: {home: {configuration: a}, reach: {configuration: b}}\n")
    file = tmp_path / "arm.yaml"
    file.write_text("include: [jobs.yaml]\ntasks: {robot: {}, pid: {}}\nconfigurations: {a: [robot], b: [pid]}\n"
                    "applications: {tour: [home]}\n")
    words = ["pbo", "run", str(file), "--config", ""]
    assert names("task", words) == ["pid", "robot"]
    assert names("configuration", words) == ["a", "b"]
    assert names("job", words) == ["home", "reach"]
    assert names("application", words) == ["tour"]
    assert names("variable", words) == []
    assert names("task", ["pbo", "run", str(tmp_path / "missing.yaml")]) == []  # never an error at a <TAB>


def test_a_live_verbs_task_names_come_from_the_live_run(fake_run, capsys):
    assert main(["__complete", "task", "pbo", "off", "--subsystem", fake_run.subsystem, ""]) == 0
    assert capsys.readouterr().out.split() == sorted(fake_run.host.subsystem.tasks)


@pytest.mark.multiprocess
def test_bash_completes_a_configuration_from_the_file_typed_before_it(capsys):
    import shutil
    import subprocess
    import sys

    from tests.support import REPO

    if shutil.which("bash") is None:
        pytest.skip("no bash here")
    assert main(["completion", "bash"]) == 0
    script = capsys.readouterr().out
    line = "pbo run configs/switch_joint.yaml --config "
    done = subprocess.run(["bash", "-c", f'{script}\nCOMP_WORDS=({line} ""); COMP_CWORD=4; COMP_LINE="{line}"; '
                                         'COMP_POINT=${#COMP_LINE}; _shtab_pbo pbo "" --config; echo "${COMPREPLY[@]}"'],
                          capture_output=True, text=True, cwd=REPO, timeout=60,
                          env={**os.environ, "PATH": f"{os.path.dirname(sys.executable)}:{os.environ['PATH']}"})
    assert done.stdout.split() == ["pd", "pid"], done.stderr
