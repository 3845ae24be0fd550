"""A file that checks clean runs (issue 35): what `pbo run` would refuse at init, `pbo check` refuses
first, located at the node the fix goes to, with a hint; and the places it used to point wrong.

`run:` of an incomplete application is an application file's rule: tests/test_application.py.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pbo_runtime.config.loader import CheckResult, check_file
from pbo_runtime.errors import ConfigError

BASE = """\
subsystem: twins
rtpus: [rtpu0, rtpu1]
plant: {model: puma560, timestep: 1 ms}
devices:
  arm: {driver: mujoco_arm, mode: torque, exclusive: true}
variables:
  q_d:   {type: float64, shape: [NDOF], object: joint_position, initial: 0}
  tau_u: {type: float64, shape: [NDOF]}
tasks:
  robot: {module: robot_torque, rtpu: rtpu1, period: 1 ms, critical: true, resources: [arm]}
  traj:  {module: joint_trajectory, rtpu: rtpu0, period: 2 ms, params: {max_velocity: 1.0}}
  pid:   {module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {kp: 400, kd: 40}, ports: {tau: tau_u}}
configurations:
  joint_pid: [robot, traj, pid]
jobs:
  move: {configuration: joint_pid, object: q_d, post: "max(abs(q_m - q_d)) < 1e-3", timeout: 10 s}
"""

# TR §4.5: the computed torque controller as one combined task, q_r integrated inside `ik`
COMBINED = BASE.replace("""  traj:  {module: joint_trajectory, rtpu: rtpu0, period: 2 ms, params: {max_velocity: 1.0}}
  pid:   {module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {kp: 400, kd: 40}, ports: {tau: tau_u}}
""", """  traj:  {module: joint_trajectory, rtpu: rtpu0, period: 2 ms, params: {max_velocity: 1.0}}
  ctc:   {module: combined, rtpu: rtpu0, period: 1 ms, params: {members: [
            {module: pid_joint, params: {kp: 2500, kd: 100, gravity_feedforward: false}, ports: {tau: qdd_r}},
            {module: inverse_dynamics}]}}
""").replace("[robot, traj, pid]", "[robot, traj, ctc]")


def edited(text: str, *edits: tuple[str, str]) -> str:
    for old, new in edits:
        assert old in text, f"{old!r} is not in the file"
        text = text.replace(old, new, 1)
    return text


def check(tmp_path: Path, text: str) -> CheckResult:
    path = tmp_path / "twins.yaml"
    path.write_text(text)
    return check_file(path)


def at(text: str, needle: str) -> tuple[int, int]:
    """1-based line and column of the first `needle`."""
    offset = text.index(needle)
    return text.count("\n", 0, offset) + 1, offset - (text.rfind("\n", 0, offset) + 1) + 1


def only_error(result: CheckResult) -> ConfigError:
    assert len(result.errors) == 1, [e.format() for e in result.errors]
    return result.errors[0]


def test_both_shipped_bases_check_clean(tmp_path: Path) -> None:
    for text in (BASE, COMBINED):
        result = check(tmp_path, text)
        assert result.errors == [], [e.format() for e in result.errors]


SPP_TASK = "  fk:    {module: fk_jacobian_spp, rtpu: rtpu1, period: 2 ms, params: {device: fpa}}\n"


@pytest.mark.parametrize(("text", "needle", "code", "message", "hint"), [
    pytest.param(edited(BASE, ("  arm: {driver", "  dac0: {driver: dac12}\n  arm: {driver")), "dac12", "E219",
                 r"device 'dac0' uses driver 'dac12', which is not registered", "did you mean 'dac'?",
                 id="a_driver_that_does_not_exist_given_no_options"),
    pytest.param(edited(BASE, ("  arm: {driver", "  cam: {driver: camera}\n  arm: {driver"),
                        ("configurations:", SPP_TASK.replace("fpa}}", "cam}, resources: [cam]}") + "configurations:"),
                        ("[robot, traj, pid]", "[robot, traj, pid, fk]")),
                 "cam}, resources", "E610",
                 r"task 'fk' \(module 'fk_jacobian_spp'\) opens device 'cam', a device of kind camera \(driver camera\), "
                 r"but the module needs a device of kind spp", "drivers of kind spp: spp",
                 id="a_special_purpose_processor_module_on_a_camera"),
    pytest.param(edited(BASE, ("  arm: {driver", "  fpa: {driver: spp}\n  arm: {driver"),
                        ("configurations:", SPP_TASK + "configurations:"),
                        ("[robot, traj, pid]", "[robot, traj, pid, fk]")),
                 "fpa}}", "E608", r"task 'fk' \(module 'fk_jacobian_spp'\) opens device 'fpa' \(params: device\), which is not "
                 r"among its resources", "add 'fpa' to resources:", id="a_special_purpose_processor_not_in_the_resources"),
    pytest.param(edited(BASE, ("  arm: {driver", "  ball: {driver: trackball, source: hmi}\n  arm: {driver"),
                        ("resources: [arm]}", "resources: [ball], params: {device: ball}}")),
                 "ball}}", "E610", r"task 'robot' \(module 'robot_torque'\) opens device 'ball', a device of kind trackball",
                 "drivers of kind arm: mujoco_arm", id="an_arm_module_on_a_trackball"),
    pytest.param(edited(BASE, ('post: "max(abs(q_m - q_d)) < 1e-3"', 'post: "q_m[6] < 1"')), "q_m[6]", "E719",
                 r"post-condition of job 'move': index \[6\] is out of range for shape \(6,\)", "q_m float64 (6,)",
                 id="a_condition_indexing_past_a_variable"),
    pytest.param(edited(BASE, ('post: "max(abs(q_m - q_d)) < 1e-3"', 'post: "max(abs(q_m - EE)) < 1"')),
                 '"max(abs(q_m - EE', "E719",
                 r"post-condition of job 'move' cannot be computed on its variables' shapes: operands could not be broadcast",
                 "EE float64 (8,)", id="a_condition_of_shapes_that_do_not_combine"),
    pytest.param(edited(COMBINED, ("params: {members: [", "params: {export: [qd_r], members: [")), "qd_r], members", "E308",
                 r"params of task 'ctc' \(module 'combined'\): bad parameters for Combined: export names 'qd_r', which is no "
                 r"member-to-member variable", "", id="an_export_naming_no_member_to_member_variable"),
    pytest.param(edited(COMBINED, ("{module: inverse_dynamics}", "{module: inverse_dynamics, parms: {}}")), "parms", "E308",
                 r".*member 2 has unknown key\(s\) 'parms'", "", id="a_member_error_at_the_member"),
    pytest.param(edited(COMBINED, ("ports: {tau: qdd_r}", "ports: {torque: qdd_r}")), "torque: qdd_r", "E308",
                 r".*member 1 \(pid_joint\) has no port\(s\) 'torque'", "", id="a_member_port_error_at_the_port"),
    pytest.param(edited(COMBINED, ("{module: inverse_dynamics}", "{module: pid_joint}"), (", ports: {tau: qdd_r}}", "}")),
                 "{module: pid_joint}]", "E308", r".*members 1:pid_joint and 2:pid_joint both write 'tau_u'", "",
                 id="two_members_writing_one_variable_at_the_second"),
    pytest.param(edited(COMBINED,
                        ("{module: inverse_dynamics}", "{module: inverse_dynamics, params: {kp: 1}}")), "kp: 1}}", "E308",
                 r".*member 2 \(inverse_dynamics\): unknown parameter\(s\) 'kp'", "",
                 id="a_member_parameter_at_that_member_not_the_first_with_the_name"),
    pytest.param(edited(BASE, ("plant: {model: puma560, timestep: 1 ms}\n", "dims: {NDOF: 6}\n")), "robot_torque", "E611",
                 r"task 'robot' \(module 'robot_torque'\) opens device 'arm' \(driver mujoco_arm\), "
                 r"hardware the plant simulates, but the file has no plant:", "add a plant",
                 id="an_arm_with_no_plant_to_serve_it"),
    pytest.param(edited(BASE, ("  arm: {driver", "  cam: {driver: camera}\n  arm: {driver"),
                        ("configurations:", "  fk:    {module: fk_jacobian, rtpu: rtpu1, period: 2 ms}\n"
                                  "  vision: {module: visual_servoing, rtpu: rtpu0, period: 10 ms, params: {device: cam}, "
                                  "resources: [cam]}\nconfigurations:"),
                        ("[robot, traj, pid]", "[robot, traj, pid, fk, vision]")),
                 "cam}, resources", "E611", r"task 'vision' \(module 'visual_servoing'\) opens device 'cam' \(driver camera\), "
                 r"which reads the plant's option target, but plant: does not give it", "give the plant target:",
                 id="a_camera_with_no_target_to_see"),
    pytest.param(edited(BASE,
                        ("configurations:", "  fk:    {module: fk_jacobian, rtpu: rtpu1, period: 2 ms, params: {frame: link9}}\n"
                                  "configurations:"), ("[robot, traj, pid]", "[robot, traj, pid, fk]")),
                 "link9", "E323",
                 r"task 'fk' \(module 'fk_jacobian'\): frame must be one of the arm's frames \(ee, link1 \.\.\. link6",
                 "", id="a_frame_the_arm_has_not"),
    pytest.param(edited(BASE, ("  arm: {driver", "  adc0: {driver: adc}\n  arm: {driver"),
                        ("configurations:", "  aux:   {module: analog_input, rtpu: rtpu0, period: 1 ms, params: {device: adc0}, "
                            "ports: {v: v6}, resources: [{device: adc0, channels: 0-2}]}\nconfigurations:"),
                        ("[robot, traj, pid]", "[robot, traj, pid, aux]"),
                        ("variables:\n", "variables:\n  v6: {type: float64, shape: [6]}\n")),
                 "[{device: adc0, channels: 0-2}]", "E323",
                 r"task 'aux' \(module 'analog_input'\): port 'v' links a variable of 6 "
                 r"elements, but the task opens 3 channels of device 'adc0'", "", id="channels_and_a_variable_of_other_sizes"),
    pytest.param(edited(BASE, ("configurations:",
                               "  diff:  {module: differentiator, rtpu: rtpu0, period: 1 ms, ports: {z: q_d, zd: zd8}}\n"
                 "configurations:"), ("variables:\n", "variables:\n  zd8: {type: float64, shape: [8]}\n")),
                 "zd8}}", "E319",
                 r"task 'diff' \(module 'differentiator'\) needs one shape on ports 'z', 'zd'", "",
                 id="a_derivative_of_another_shape"),
    pytest.param(edited(BASE, ("rtpus: [rtpu0, rtpu1]", "rtpus: {rtpu0: {restart: {withn: 1 s}}, rtpu1: {}}")), "withn", "E111",
                 r"unknown key 'withn' in the restart of RTPU 'rtpu0'", "", id="a_restart_with_an_unknown_key_and_no_max"),
])
def test_what_a_run_would_refuse_is_one_located_error_with_a_hint(tmp_path: Path, text: str, needle: str, code: str,
                                                                  message: str, hint: str) -> None:
    result = check(tmp_path, text)
    if code == "E111":  # the restart lacks max, the one key always required: said too, and nothing of within
        assert sorted(e.code for e in result.errors) == ["E111", "E112"], [e.format() for e in result.errors]
        assert not any("within" in e.message for e in result.errors)
        error = next(e for e in result.errors if e.code == code)
    else:
        error = only_error(result)
    assert error.code == code and re.match(message, error.message), error.format()
    assert (error.line, error.column) == at(text, needle), error.format()
    assert hint in error.hint, error.format()


def test_a_combined_task_s_internal_variable_read_outside_is_told_to_be_exported(tmp_path: Path) -> None:
    text = edited(COMBINED, ("configurations:",
                             "  spy:   {module: data_logger, rtpu: rtpu0, period: 10 ms, "
                             "params: {variables: [tau_u], path: spy.mcap},\n"
                             "          ports: {tau_u: qdd_r}}\nconfigurations:"),
                  ("[robot, traj, ctc]", "[robot, traj, ctc, spy]"), ("variables:\n",
                                                                      "variables:\n  qdd_r: {type: float64, shape: [NDOF]}\n"))
    error = only_error(check(tmp_path, text))
    assert error.code == "E403" and "reads in-var 'qdd_r'" in error.message, error.format()
    assert "export: [qdd_r]" in error.hint and "combined task 'ctc'" in error.hint, error.format()
    assert [n.line for n in error.notes] == [at(text, "ctc:")[0]]


@pytest.mark.parametrize(("value", "needle"), [  # the variable's own mapping is the first level
    ("[" * 20_000 + "1" + "]" * 20_000, "[" * 99),
    ("{a: " * 20_000 + "1" + "}" * 20_000, "{a: " * 98 + "{"),
])
def test_lists_nested_too_deep_are_reported_where_the_nesting_is(tmp_path: Path, value: str, needle: str) -> None:
    text = edited(BASE, ("  tau_u: {type: float64, shape: [NDOF]}\n",
                         f"  tau_u: {{type: float64, shape: [NDOF]}}\n  deep: {{type: float64, initial: {value}}}\n"))
    error = only_error(check(tmp_path, text))
    assert error.code == "E101" and "nested too deeply" in error.message
    line, column = at(text, needle)
    assert (error.line, error.column) == (line, column + len(needle) - 1), error.format()
