"""The operator's verbs, declared once in the command table: the CLI, the docs and the supervisor agree."""

from __future__ import annotations

import argparse
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pbo_runtime.cli import operator
from pbo_runtime.cli.main import _parser
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import BadRequest
from pbo_runtime.objects.ranges import Range
from pbo_runtime.supervisor.commands import COMMANDS, SERVED, VERBS, WHICH_RUN, dispatch, parse_job_object, verb_table
from tests.fake_job_host import FakeJobHost, fake_subsystem
from tests.support import REPO


def subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_the_docs_verb_table_is_the_one_the_command_table_makes():
    text = (REPO / "docs" / "operator-commands.md").read_text()
    assert verb_table() in text, \
        "regenerate it: python -c 'from pbo_runtime.supervisor.command_table import verb_table; print(verb_table())'"


@pytest.mark.parametrize("verb", VERBS, ids=lambda verb: verb.name)
def test_every_verb_is_a_cli_command_with_its_declared_arguments_and_a_runner(verb):
    parser = subparsers()[verb.name]
    declared = [argument.dest for argument in verb.arguments] + ["subsystem", "run", "format"]
    assert [a.dest for a in parser._actions if a.dest != "help"] == declared
    assert verb.name in operator._RUNNERS


@pytest.mark.parametrize("verb", VERBS, ids=lambda verb: verb.name)
def test_every_verb_picks_its_run_with_the_arguments_the_table_declares_once(verb):
    assert [a.name for a in WHICH_RUN] == ["--subsystem", "--run"]
    arguments = {"on": ["x"], "off": ["x"], "clear": ["x"], "switch": ["x"], "job": ["x"], "event": ["x"],
                 "play": ["x"], "spawn": ["x"],
                 "kill": ["x"], "replace": ["x", "y"], "set": ["x", "kp", "1"], "app": ["x"], "save": ["x"]}.get(verb.name, [])
    parsed = _parser().parse_args([verb.name, *arguments, "--run", "1234-ab", "--subsystem", "puma"])
    assert (parsed.run, parsed.subsystem) == ("1234-ab", "puma")


def test_the_cli_runs_no_verb_the_table_does_not_declare():
    assert set(operator._RUNNERS) == set(COMMANDS)


def test_a_verbs_request_takes_its_keys_from_the_table_and_parses_numbers():
    assert COMMANDS["job"].request({"name": "move", "values": ["0.5", "-1"]}) == {"job": "move", "object": [0.5, -1.0]}
    assert COMMANDS["job"].request({"name": "move", "values": []}) == {"job": "move", "object": None}
    assert COMMANDS["on"].request({"task": "pid"}) == {"task": "pid"}
    assert COMMANDS["status"].request({}) == {}


# --- every verb's handler on a fake host, as the supervisor dispatches it ----------------------


@pytest.fixture(scope="module")
def subsystem(tmp_path_factory):
    return fake_subsystem(tmp_path_factory.mktemp("commands"))


@pytest.fixture
def host(subsystem) -> FakeJobHost:
    return FakeJobHost(subsystem, "pid")


def test_status_reports_each_task_with_its_rate_and_only_an_errors_message(host):
    host.clock.advance(2.0)
    host.task_states["traj"], host.task_errors["traj"] = "ERROR", "cycle raised RuntimeError"
    host.task_errors["pid"] = "an old error, cleared since"
    reply = dispatch(host, "status", {})
    rows = {row["task"]: row for row in reply["tasks"]}
    assert (reply["configuration"], reply["elapsed"], reply["flags"]) == ("pid", 2.0, ["ILLEGAL_CONFIGURATION"])
    assert [row["index"] for row in reply["tasks"]] == [0, 1, 2, 3] and rows["robot"]["rate"] == 50.0
    assert rows["traj"]["error"] == "cycle raised RuntimeError" and rows["pid"]["error"] is None


@pytest.mark.parametrize("verb, task, before, after", [("on", "pd", "OFF", "ON"), ("off", "pid", "ON", "OFF")])
def test_on_and_off_signal_the_task_and_answer_its_new_state(subsystem, verb, task, before, after):
    host = FakeJobHost(subsystem, "pd" if verb == "on" else "pid")
    host.task_states[task] = before
    assert dispatch(host, verb, {"task": task}) == {"task": task, "state": after, "message": f"task '{task}' is {after}"}
    assert host.signals == [(task, verb)]


def test_an_on_whose_error_component_turned_the_task_off_says_so_issue_22(subsystem):
    host = FakeJobHost(subsystem, "pid")
    host.task_states["pid"], host.on_leaves, host.task_errors["pid"] = "OFF", "OFF", "on raised RuntimeError: no arm"
    reply = dispatch(host, "on", {"task": "pid"})
    assert reply["state"] == "OFF"
    assert reply["message"] == ("task 'pid' is OFF; its on failed and its error component turned it off "
                                "(on raised RuntimeError: no arm)")


@pytest.mark.parametrize("verb, task, state, refusal", [
    ("on", "pd", "OFF", r"^task 'pd' is not in the running configuration 'pid' \(robot, traj, pid\): turning it on would "
                        r"give its outputs two writers; use pbo switch to a configuration that has it$"),
    ("on", "pid", "ON", r"^task 'pid' is ON: only an OFF task can be turned on$"),
    ("off", "pid", "ERROR", r"^task 'pid' is ERROR: only an ON task can be turned off$"),
    ("clear", "pid", "ON", r"^task 'pid' is ON, not in ERROR: there is nothing to clear$"),
    ("event", "nobody", "", r"^no task 'nobody' \(tasks: robot, traj, pid, pd\)$"),
])
def test_a_task_verb_the_tasks_state_does_not_allow_is_refused_and_nothing_is_sent(host, verb, task, state, refusal):
    if state:
        host.task_states[task] = state
    with pytest.raises(PboError, match=refusal):
        dispatch(host, verb, {"task": task})
    assert host.signals == [] and host.events == []


@pytest.mark.parametrize("fixed, message", [
    (True, "task 'pid' is OFF; cleared: the task is OFF; turn it on with pbo on"),
    (False, "task 'pid' is ERROR; still in ERROR: its clear component found the fault not fixed (gain matrix is singular)"),
])
def test_clear_says_whether_the_tasks_clear_component_fixed_the_fault(host, fixed, message):
    host.task_states["pid"], host.task_errors["pid"] = "ERROR", "gain matrix is singular"
    host.clear_fixes_the_fault = fixed
    assert dispatch(host, "clear", {"task": "pid"})["message"] == message


@pytest.fixture(scope="module")
def goal_subsystem():
    return load_subsystem(str(REPO / "configs" / "operator_goal.yaml"))  # 'goal' is aperiodic


@pytest.fixture
def goal_host(goal_subsystem) -> FakeJobHost:
    return FakeJobHost(goal_subsystem, "operated")


def test_an_event_is_sent_with_its_values(goal_host):
    values = [0.1, -0.5, 0.5, 0, 0.3, 0.1]
    assert dispatch(goal_host, "event", {"task": "goal", "values": values}) == {"task": "goal", "message": "event sent to 'goal'"}
    assert goal_host.events == [("goal", values)]


# issue 18: every one was sent before (a periodic task got an event, an aperiodic one went to ERROR)
@pytest.mark.parametrize("arguments, refusal", [
    ({"task": "pid", "values": [1, 2, 3]}, r"^task 'pid' is periodic: it runs on its own timer and takes no events; "
                                           r"send events to an aperiodic task \(goal\)$"),
    ({"task": "goal", "values": "abc"}, r"^the values of an event for 'goal' must be a list of numbers, got: the text 'abc'$"),
    ({"task": "goal", "values": [0.1, float("nan")]}, r"^the values of an event for 'goal': values must be finite numbers, "
                                                      r"got: \.nan \(not a number\) \(value 2\)$"),
    ({"task": "goal", "values": [float("-inf")]}, r"values must be finite numbers, got: -\.inf \(value 1\)$"),
    ({"task": "goal", "values": [[0.1], [0.2]]}, r"values must be numbers, got: a list \(value 1\)$"),
    ({"task": "goal", "values": [True]}, r"values must be numbers, got: true/false \(true\) \(value 1\)$"),
    ({"task": "goal", "values": [0.0] * 257}, r"must be at most 256 numbers, got: 257$"),
    ({"task": "goal", "values": [0.1, 0.2, 0.3]}, r"^task 'goal' takes events of 6 values \(goal_input's EVENT_SHAPE\), got 3$"),
    ({"task": "goal", "values": None}, r"^task 'goal' takes events of 6 values \(goal_input's EVENT_SHAPE\), got 0$"),
    ({"task": "goal", "values": [0.3, -0.5, 1.0e308, 0.2, 0.4, 0.2]},
     r"^the values of an event for 'goal' must be in \[-100, 100\] \(goal_input's EVENT_RANGE\), got: 1e\+308 \(value 3\)$"),
    ({"task": ["goal"], "values": [0.0]}, r"^task must be named by text, got: a list \(tasks: robot, goal, traj, pid\)$"),
    ({"task": "goal", "values": [0.0], "priority": 1}, r"^'event' takes no argument 'priority' \(its arguments: task, values\)$"),
])
def test_a_malformed_event_is_refused_as_a_bad_request_and_nothing_is_sent(goal_host, arguments, refusal):
    with pytest.raises(BadRequest, match=refusal):
        dispatch(goal_host, "event", arguments)
    assert goal_host.events == []


def test_an_event_for_an_aperiodic_task_that_is_not_on_is_refused_for_the_runs_state(goal_host):
    goal_host.task_states["goal"] = "OFF"
    with pytest.raises(PboError,
                       match=r"^task 'goal' is OFF, not ON: an event would not run it; turn it on with pbo on goal$") as refused:
        dispatch(goal_host, "event", {"task": "goal", "values": [0.0] * 6})
    assert not isinstance(refused.value, BadRequest) and goal_host.events == []


@pytest.mark.parametrize("job_object, refusal", [
    ([float("nan")] + [0.0] * 5,
     r"^job 'reach': object 'q_d': float64 elements must be finite numbers, got: \.nan \(not a number\) \(value 1\)$"),
    ([0.0] * 5 + [float("inf")], r"got: \.inf \(value 6\)$"),
    ([0.0] * 5, r"^job 'reach': object 'q_d': the variable takes 6 values \(shape \[6\]\), got 5$"),
    (["a"] * 6, r"float64 elements must be numbers, got: the text 'a' \(value 1\)$"),
    ([[0.0, 0.0], [0.0]], r"^job 'reach': object 'q_d' is a ragged list; rows must have equal lengths$"),
    ({"q_d": 1}, r"^job 'reach': object 'q_d' must be numbers, got: a mapping$"),
    (10**400, r"float64 elements must be finite numbers, got: an integer of 401 digits, beyond the largest float64$"),
], ids=["nan", "inf", "short", "text", "ragged", "mapping", "huge"])
def test_a_job_object_that_is_not_finite_numbers_of_its_shape_is_refused_before_anything_changes(host, job_object, refusal):
    before = host.values["q_d"].copy()
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, "job", {"job": "reach", "object": job_object})
    assert host.plans == [] and host.job_control.job is None and (host.values["q_d"] == before).all()


def test_a_job_object_outside_its_types_range_is_refused_naming_the_range(subsystem):
    kind = subsystem.object_types["joint_position"]
    ranged = dataclasses.replace(kind, range=Range(-3.2, 3.2, low_open=False, high_open=False))  # range: [-3.2, 3.2]
    host = FakeJobHost(dataclasses.replace(subsystem, object_types={"joint_position": ranged}), "pid")
    with pytest.raises(BadRequest,
                       match=r"^job 'reach': object 'q_d': element 6 must be in \[-3\.2, 3\.2\] \(the range of object "
                             r"type 'joint_position'\), got: 7$"):
        dispatch(host, "job", {"job": "reach", "object": [0.0] * 5 + [7.0]})
    assert host.job_control.job is None
    assert dispatch(host, "job", {"job": "reach", "object": [-3.2] + [0.0] * 4 + [3.2]})["job"] == "reach"  # its ends are in it


@pytest.mark.parametrize("command, arguments, refusal", [
    ("on", {"task": ["pid"]}, r"^task must be named by text, got: a list \(tasks: robot, traj, pid, pd\)$"),
    ("clear", {"task": {"a": 1}}, r"^task must be named by text, got: a mapping"),
    ("off", {}, r"^task must be named by text, got: nothing \(null\)"),
    ("switch", {"configuration": 3}, r"^configuration must be named by text, got: the integer 3 \(configurations: pid, pd\)$"),
    ("switch", {"configuration": "nope"}, r"^no configuration 'nope' \(configurations: pid, pd\)$"),
    ("job", {"job": None}, r"^job must be named by text, got: nothing \(null\)"),
    ("status", {"verbose": True}, r"^'status' takes no argument 'verbose' \(its arguments: none\)$"),
    ("launch", {}, r"^unknown command 'launch'"),
])
def test_a_request_of_the_wrong_shape_is_a_bad_request_with_what_was_expected(host, command, arguments, refusal):
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, command, arguments)
    assert host.signals == [] and host.plans == []


# Anything that can arrive on the control queue (msgpack: None, flags, integers up to 64 bits,
# floats with NaN and Inf, text, lists, maps with text keys): a reply or a refusal, never an
# internal error, and never a non-finite value written or sent.
_ANYTHING = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=7) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=20,
)
_KEYS = st.sampled_from(["task", "values", "job", "object", "configuration", "x"])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(command=st.sampled_from([*SERVED, "nope"]), arguments=st.dictionaries(_KEYS, _ANYTHING | st.sampled_from(
    ["goal", "pid", "robot", "operated", "reach"]) | st.lists(st.floats(), min_size=6, max_size=6), max_size=3))
def test_any_request_shape_is_answered_or_refused_never_an_internal_error(goal_subsystem, command, arguments):
    host = FakeJobHost(goal_subsystem, "operated")
    try:
        reply = dispatch(host, command, arguments)
    except PboError:
        pass
    else:
        assert isinstance(reply, dict) and isinstance(reply.get("message", ""), str)
    for _, values in host.events:
        assert values is None or all(math.isfinite(v) for v in values)
    assert all(np.isfinite(value).all() for value in host.values.values() if value.dtype.kind == "f")


def test_switch_answers_what_went_off_and_on_and_how_long_it_took(host):
    reply = dispatch(host, "switch", {"configuration": "pd"})
    assert (reply["configuration"], reply["entered"], reply["left"]) == ("pd", ["pd"], ["pid"])
    assert reply["message"] == "switched 'pid' -> 'pd' in 1.00 ms: off pid; on pd"


@pytest.mark.parametrize("arguments, refusal", [
    ({"job": "reach", "object": None}, r"^job 'reach' needs its object 'q_d': pbo job reach VALUE \.\.\.$"),
    ({"job": "hold", "object": [1.0]}, r"^job 'hold' takes no object$"),
    ({"job": "jump", "object": None}, r"^no job 'jump' \(jobs: guarded, hold, dwell, reach, settle\)$"),
    ({"job": "guarded", "object": None}, r"^job 'guarded': pre-condition 'max\(abs\(q_m\)\) > 10' does not hold"),
])
def test_a_job_the_run_cannot_start_is_refused_before_anything_changes(host, arguments, refusal):
    with pytest.raises(PboError, match=refusal):
        dispatch(host, "job", arguments)
    assert host.plans == [] and host.job_control.job is None


def test_a_job_with_its_object_starts_in_its_configuration(host):
    reply = dispatch(host, "job", {"job": "settle", "object": [0.0] * 6})
    assert reply == {"job": "settle", "configuration": "pd",
                     "message": "job 'settle' runs in 'pd'; done when max(abs(q_m - q_d)) < 0.01 and max(abs(qd_m)) < 0.01"}
    assert host.configuration == "pd" and host.job_control.job == "settle"


def test_a_job_takes_a_named_object_of_the_file_by_its_name(host):
    reply = dispatch(host, "job", {"job": "reach", "object": "ready"})
    assert reply["job"] == "reach" and host.job_control.job == "reach"
    assert (host.values["q_d"] == host.subsystem.objects["ready"].value).all()


def test_a_named_object_the_file_lacks_is_refused_with_the_ones_of_the_jobs_type(host):
    with pytest.raises(BadRequest, match=r"^no object 'raedy' in the file \(objects of type joint_position: ready\); "
                                         r"give it by name or as numbers: pbo job reach VALUE \.\.\.$"):
        dispatch(host, "job", {"job": "reach", "object": "raedy"})
    assert host.plans == [] and host.job_control.job is None


@pytest.mark.parametrize("texts, parsed", [(["ready"], "ready"), (["0.3", "-1"], [0.3, -1]), (None, None)])
def test_the_command_line_gives_a_job_a_named_object_or_its_numbers(texts, parsed):
    assert parse_job_object(texts) == parsed


@pytest.mark.parametrize("verb, arguments", [("switch", {"configuration": "pd"}), ("job", {"job": "hold", "object": None})])
def test_switch_and_job_are_refused_while_an_application_runs(host, verb, arguments):
    host.application = "tour"
    with pytest.raises(PboError, match=r"^application 'tour' is running its jobs; switch, job, app and live changes are refused "
                                       r"until it ends$"):
        dispatch(host, verb, arguments)
    assert host.plans == []


def test_stop_asks_the_run_to_stop(host):
    assert dispatch(host, "stop", {}) == {"message": "stopping 'puma_switch'"}
    assert host.stopped_by == "pbo stop"


@pytest.mark.parametrize("verb", ["launch", "svar"])
def test_a_verb_the_supervisor_does_not_serve_is_refused_with_the_ones_it_does(host, verb):
    with pytest.raises(PboError, match=rf"^unknown command '{verb}' \(commands: status, on, off, clear, switch, job, event, "
                                       rf"play, spawn, kill, replace, set, app, save, stop\)$"):
        dispatch(host, verb, {})
