"""The job canvas checked like a file (edit.canvas) and saved as a job (edit.canvas_job): the canvas's
tasks composed onto a file's base, each diagnostic traced back to its task, modifier and pin, the
placement query on unsaved tasks, and the job written into the file with its comments kept.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pbo_runtime.config.loader import check_file
from pbo_runtime.config.yaml_nodes import load_text
from pbo_runtime.edit.canvas import (
    CanvasError,
    Origin,
    Pin,
    check_canvas,
    file_canvas,
    origin_file,
    origin_of,
    pin_of,
    tasks_from_json,
    yaml_text,
)
from pbo_runtime.edit.canvas_job import JobRefused, save_job
from tests.support import FIGURE_8_CANVAS, REPO, canvas_base_file

FIGURE_8 = FIGURE_8_CANVAS
SECOND_WRITER = {"name": "inv", "module": "inverse_dynamics", "fields": {"rtpu": "rtpu0", "period": "1 ms"}}


def base_file(folder: Path) -> Path:
    return canvas_base_file(folder)


def test_figure_8_on_an_empty_canvas_checks_clean_with_every_pin_joined(tmp_path):
    reply = check_canvas(str(base_file(tmp_path)), tasks_from_json(FIGURE_8), "joint_pid")
    assert reply["valid"], reply["diagnostics"]
    assert [d for d in reply["diagnostics"] if d["severity"] == "error"] == []
    pins = {(task, p["port"]): p["variable"] for task, found in reply["pins"].items() for p in found}
    assert pins[("pid", "tau")] == "tau_u" and pins[("robot", "tau_u")] == "tau_u"
    assert pins[("logger", "q_r")] == "q_r"  # a data logger's ports come from its modifiers
    assert reply["job_written"] == ["q_d"]


def test_a_second_writer_is_dimmed_by_the_placement_query_with_the_checkers_reason(tmp_path):
    reply = check_canvas(str(base_file(tmp_path)), tasks_from_json(FIGURE_8))
    verdicts = {v["module"]: v for v in reply["placement"]["modules"]}
    assert verdicts["inverse_dynamics"]["legal"] is False
    assert verdicts["inverse_dynamics"]["code"] == "E401"
    assert "tau_u" in verdicts["inverse_dynamics"]["reason"]
    assert verdicts["pid_joint"]["code"] == "E407"  # a module runs once a configuration
    assert verdicts["gravity_compensation"]["legal"] is True


def test_a_second_writer_placed_anyway_is_located_on_its_block_and_its_pin(tmp_path):
    reply = check_canvas(str(base_file(tmp_path)), tasks_from_json([*FIGURE_8, SECOND_WRITER]))
    assert not reply["valid"]
    e401 = [d for d in reply["diagnostics"] if d["code"] == "E401"]
    assert [(d["task"], d["port"]) for d in e401] == [("inv", "tau")]
    assert e401[0]["message"] == "variable 'tau_u' has two writers in configuration 'canvas': 'pid' and 'inv'"
    # the placement query still answers, from the tasks whose own entries are sound
    assert {v["module"]: v["legal"] for v in reply["placement"]["modules"]}["gravity_compensation"] is True


@pytest.mark.parametrize(("change", "code", "section", "key"), [
    ({"params": {"kp": "[1, 2"}}, "E101", "params", "kp"),  # not YAML
    ({"params": {"kp": "\"soft\""}}, "E308", "params", "kp"),  # the module's own check of its modifiers
    ({"fields": {"rtpu": "rtpu7", "period": "1 ms"}}, None, "rtpu", None),
    ({"ports": {"tau": "tau_x"}}, None, "ports", "tau"),
])
def test_a_diagnostic_of_a_tasks_value_names_the_task_and_the_value(tmp_path, change, code, section, key):
    tasks = [dict(t) for t in FIGURE_8]
    tasks[2] = {**tasks[2], **change}
    reply = check_canvas(str(base_file(tmp_path)), tasks_from_json(tasks))
    mine = [d for d in reply["diagnostics"] if d["task"] == "pid" and d["severity"] == "error"]
    assert mine, reply["diagnostics"]
    assert (mine[0]["section"], mine[0]["key"]) == (section, key)
    if code:
        assert mine[0]["code"] == code
    if section == "ports":
        assert mine[0]["port"] == "tau"


def test_a_task_that_is_off_stays_out_of_the_configuration(tmp_path):
    tasks = [*FIGURE_8, {**SECOND_WRITER, "on": False}]
    reply = check_canvas(str(base_file(tmp_path)), tasks_from_json(tasks))
    assert reply["valid"]
    assert [d["code"] for d in reply["diagnostics"] if d["task"] == "inv"] == ["W201"]  # in no configuration


def test_a_task_turned_off_that_writes_what_another_reads_is_shown_at_the_pin_that_misses_it(tmp_path):
    tasks = [{**t, "on": t["name"] != "pid"} for t in FIGURE_8]  # the PID off: nobody on the canvas writes tau_u
    reply = check_canvas(str(base_file(tmp_path)), tasks_from_json(tasks), "joint_pid")
    e408 = [d for d in reply["diagnostics"] if d["code"] == "E408"]
    assert [(d["task"], d["port"]) for d in e408] == [("robot", "tau_u")]
    assert e408[0]["message"].startswith("configuration 'joint_pid' leaves out task 'pid', which writes 'tau_u'")
    notes = {(n["task"], n["message"]) for n in e408[0]["notes"]}  # the related places, named by their blocks
    assert ("pid", "task 'pid' writes 'tau_u'") in notes and any(task == "robot" for task, _ in notes)


def test_the_base_files_own_errors_keep_their_line_and_no_module_is_placed(tmp_path):
    path = base_file(tmp_path)
    path.write_text(path.read_text().replace("tau_u: {type: float64", "tau_u: {type: float65"))
    reply = check_canvas(str(path), tasks_from_json(FIGURE_8))
    base = [d for d in reply["diagnostics"] if d["task"] is None and d["severity"] == "error"]
    assert base and base[0]["file"] == str(path) and base[0]["line"] > 0
    assert "nothing can be placed" in reply["placement"]["error"]


def test_pins_are_found_by_the_port_or_the_variable_a_message_names():
    pins = [Pin("tau", "out-var", "tau_u", "float64", "[NDOF]"), Pin("q_m", "in-var", "q_m", "float64", "[NDOF]")]
    assert pin_of(Origin("pid"), "variable 'tau_u' has two writers in configuration 'c': 'x' and 'pid'", pins) == "tau"
    assert pin_of(Origin("pid"), "port 'q_m' of module 'pid_joint' is float32", pins) == "q_m"
    assert pin_of(Origin("pid", "ports", "tau"), "anything", pins) == "tau"
    assert pin_of(Origin("pid", "period"), "period of task 'pid' must be > 0", pins) is None
    assert pin_of(Origin("pid"), "task 'pid' has no RTPU", pins) is None


def test_snippet_names_tell_the_task_and_the_value_they_hold():
    assert origin_of(origin_file("pid", "params", "kp")) == Origin("pid", "params", "kp")
    assert origin_of(origin_file("pid")) == Origin("pid")
    assert origin_of("/tmp/x.yaml") is None


@pytest.mark.parametrize(("tasks", "says"), [
    ("robot", "tasks must be a list"),
    ([{"name": "1x", "module": "pid_joint"}], "its name must be an identifier"),
    ([{"name": "a", "module": "pid_joint"}, {"name": "a", "module": "robot_torque"}], "two tasks on the canvas are named 'a'"),
    ([{"name": "a", "module": "pid_joint", "params": {"kp": "1\n  module: x"}}], "one line of YAML"),
    ([{"name": "a", "module": "pid_joint", "fields": {"module": "x"}}], "not one of its fields"),
])
def test_a_malformed_canvas_is_refused_with_what_is_wrong(tasks, says):
    with pytest.raises(CanvasError, match=says):
        tasks_from_json(tasks)


@pytest.mark.parametrize("value", [400, 0.25, True, None, "1 ms", "a: b", "", [1, 2.5], {"a": [1, "x y"]}, float("inf")])
def test_a_value_shown_as_yaml_text_loads_back_to_itself(value):
    assert load_text(f"value: {yaml_text(value)}\n")["value"] == value


def test_the_files_configurations_are_what_a_canvas_starts_from():
    canvas = file_canvas(str(REPO / "configs" / "pid_joint.yaml"))
    assert canvas["configurations"] == {"joint_pid": ["robot", "traj", "pid", "logger"]}
    assert canvas["tasks"]["pid"]["params"]["kp"] == "400"
    assert canvas["tasks"]["pid"]["ports"] == {"tau": "tau_u"}
    assert canvas["tasks"]["robot"]["fields"] == {"rtpu": "rtpu1", "period": "1 ms", "critical": "true", "resources": "[arm]"}


def test_saving_the_canvas_as_a_job_writes_a_file_pbo_check_finds_clean_with_comments_kept(tmp_path):
    path = base_file(tmp_path)
    reply = save_job(str(path), "reach", tasks_from_json(FIGURE_8))
    assert reply["class"] == "action_requiring_object" and reply["object_type"] == "joint_position"
    text = path.read_text()
    assert "# the canvas's jobs go here\ntasks:\n  robot: {module: robot_torque" in text
    assert "# TR Figure 8" in text and "jobs:\n  reach: {configuration: reach}\n" in text
    result = check_file(path)
    assert result.errors == []
    assert result.subsystem.jobs["reach"].configuration == "reach"
    again = save_job(str(path), "hold", tasks_from_json(FIGURE_8), "reach", "none")
    assert (again["class"], again["configuration"], again["tasks"]) == ("action", "reach", [])


@pytest.mark.parametrize(("name", "tasks", "says"), [
    ("2x", FIGURE_8, "a job's name is an identifier"),
    ("reach", [{**t, "on": False} for t in FIGURE_8], "no task that is on"),
    ("reach", [*FIGURE_8, SECOND_WRITER], r"would leave .* with 2 error\(s\), the first: .*E401"),
])
def test_a_job_that_would_not_check_clean_is_refused_and_the_file_left_as_it_was(tmp_path, name, tasks, says):
    path = base_file(tmp_path)
    before = path.read_text()
    with pytest.raises(JobRefused, match=says):
        save_job(str(path), name, tasks_from_json(tasks))
    assert path.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.yaml"]  # no draft left beside it


def test_a_changed_task_that_another_configuration_runs_must_be_renamed(tmp_path):
    path = base_file(tmp_path)
    save_job(str(path), "reach", tasks_from_json(FIGURE_8))
    softer = [dict(t) for t in FIGURE_8]
    softer[2] = {**softer[2], "params": {"kp": "300"}}
    with pytest.raises(JobRefused, match="task 'pid' on the canvas differs from the file's, which configuration"):
        save_job(str(path), "soft", tasks_from_json(softer))
    softer[2]["name"] = "soft_pid"
    assert save_job(str(path), "soft", tasks_from_json(softer))["tasks"] == ["soft_pid"]
    assert check_file(path).errors == []
