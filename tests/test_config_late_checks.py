"""What `pbo check` finds before a run would (issue 22): joins of mixed shapes, devices a module opens
outside its resources or in the wrong mode, plant options; and where each error points: where the fix
goes, with the related places as notes, and no follow-on errors.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from pbo_runtime.cli.main import main
from pbo_runtime.config.loader import CheckResult, check_file
from pbo_runtime.errors import ConfigError, Note

BASE = """\
subsystem: late
rtpus: [rtpu0, rtpu1]
plant: {model: puma560, timestep: 1 ms}
devices:
  arm: {driver: mujoco_arm, mode: torque, exclusive: true}
dims: {NDOF: 6}
variables:
  q_d:   {type: float64, shape: [NDOF], object: joint_position, initial: 0}
  q_r:   {type: float64, shape: [NDOF]}
  qd_r:  {type: float64, shape: [NDOF]}
  tau_u: {type: float64, shape: [NDOF]}
tasks:
  robot: {module: robot_torque, rtpu: rtpu1, period: 1 ms, critical: true, resources: [arm]}
  traj:  {module: joint_trajectory, rtpu: rtpu0, period: 2 ms, params: {max_velocity: 1.0}}
  pid:   {module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {kp: 400, kd: 40}, ports: {tau: tau_u}}
configurations:
  joint_pid: [robot, traj, pid]
"""

# Figure 6: the PID's torque and gravity compensation's, joined into tau_u
JOINED = BASE.replace("""  tau_u: {type: float64, shape: [NDOF]}
""", """  tau_u: {type: float64, shape: [NDOF]}
  tau_pid: {type: float64, shape: [NDOF]}
  tau_g: {type: float64, shape: [NDOF]}
""").replace("ports: {tau: tau_u}}", """params: {gravity_feedforward: false}, ports: {tau: tau_pid}}
  gravity: {module: gravity_compensation, rtpu: rtpu1, period: 1 ms}
  join:  {module: join, rtpu: rtpu1, period: 1 ms, params: {inputs: [tau_pid, tau_g], combine: sum}, \
ports: {out: tau_u}}""").replace(
    "params: {kp: 400, kd: 40}, params:", "params:").replace("[robot, traj, pid]", "[robot, traj, pid, gravity, join]")


def edited(text: str, *edits: tuple[str, str]) -> str:
    for old, new in edits:
        assert old in text, f"{old!r} is not in the file"
        text = text.replace(old, new, 1)
    return text


def check(tmp_path: Path, text: str) -> CheckResult:
    path = tmp_path / "late.yaml"
    path.write_text(text)
    return check_file(path)


def at(text: str, needle: str) -> tuple[int, int]:
    """1-based line and column of the first `needle`."""
    start = text.index(needle)
    return text.count("\n", 0, start) + 1, start - (text.rfind("\n", 0, start) + 1) + 1


def only_error(result: CheckResult) -> ConfigError:
    assert len(result.errors) == 1, "\n".join(e.format() for e in result.errors)
    return result.errors[0]


def expect(tmp_path: Path, text: str, needle: str, code: str, message: str) -> ConfigError:
    """Exactly one error, with `code`, at the first `needle`, its message matching `message` (anchored)."""
    error = only_error(check(tmp_path, text))
    assert (error.code, (error.line, error.column)) == (code, at(text, needle)), error.format()
    assert re.match(f"^{message}$", error.message), error.message
    return error


def test_the_files_these_tests_change_check_clean(tmp_path: Path) -> None:
    for text in (BASE, JOINED):
        result = check(tmp_path, text)
        assert result.errors == [] and result.warnings == [], [e.format() for e in [*result.errors, *result.warnings]]


# --- checks that happened only when the run started -------------------------------------------


@pytest.mark.parametrize(("shape", "shown"), [("[3]", "(3,)"), ("[NDOF, 2]", "(6, 2)")])
def test_join_inputs_of_a_shape_other_than_the_output_are_refused_where_the_input_is_named(tmp_path: Path, shape, shown) -> None:
    # tau_x: a join input only the join links (its port takes any shape), set by its initial value
    text = edited(JOINED, ("inputs: [tau_pid, tau_g]", "inputs: [tau_pid, tau_x]"),
                  ("  tau_g:", f"  tau_x: {{type: float64, shape: {shape}, initial: 0}}\n  tau_g:"))
    error = expect(tmp_path, text, "tau_x]", "E319",
                   rf"task 'join' \(module 'join'\) needs one shape on ports 'out', 'tau_pid', 'tau_x': port 'tau_x' links "
                   rf"variable 'tau_x', of shape {re.escape(shown)}, where port 'out' links 'tau_u', of shape \(6,\)")
    assert [(note.line, note.message) for note in error.notes] == [
        (at(text, "join:")[0], "port 'out' links variable 'tau_u', of shape (6,)"),
        (at(text, "tau_x:")[0], f"variable 'tau_x' is declared here, with shape {shown}")]


@pytest.mark.parametrize(("edit", "needle", "message"), [
    pytest.param(("critical: true, resources: [arm]}", "critical: true}"), "robot:",
                 r"task 'robot' \(module 'robot_torque'\) opens "
                 r"device 'arm' \(params: device, by default\), which is not among its resources \(none\)", id="by_default"),
    pytest.param(("critical: true, resources: [arm]}", "critical: true, params: {device: arm}}"), "arm}}",
                 r"task 'robot' \(module 'robot_torque'\) opens device 'arm' \(params: device\), "
                 r"which is not among its resources",
                 id="named_in_its_params"),
])
def test_a_device_a_module_opens_outside_its_tasks_resources_is_refused(tmp_path: Path, edit, needle, message) -> None:
    expect(tmp_path, edited(BASE, edit), needle, "E608", message)


@pytest.mark.parametrize(("device", "module", "has", "needs"), [
    pytest.param("{driver: mujoco_arm, mode: position, exclusive: true}", "robot_torque", "position", "torque",
                 id="robot_torque_on_a_position_arm"),
    pytest.param("{driver: mujoco_arm, exclusive: true}", "robot_position", "torque (driver mujoco_arm's default)", "position",
                 id="robot_position_on_an_arm_in_the_default_torque_mode"),
])
def test_a_robot_interface_on_an_arm_in_the_other_mode_is_refused_at_its_module(tmp_path: Path, device, module, has,
                                                                               needs) -> None:
    text = edited(BASE, ("{driver: mujoco_arm, mode: torque, exclusive: true}", device),
                  ("module: robot_torque", f"module: {module}"))
    if module == "robot_position":  # it reads q_r, not tau_u
        text = edited(text, ("tau_u: {type: float64, shape: [NDOF]}", "tau_u: {type: float64, shape: [NDOF], initial: 0}"))
    error = expect(tmp_path, text, module, "E609", rf"task 'robot' \(module '{module}'\) needs device 'arm' with mode: {needs}, "
                                                   rf"but the device has mode: {re.escape(has)}")
    [note] = error.notes
    assert note.message == f"device 'arm' has mode: {has}" and note.line == at(text, "arm: {")[0]


@pytest.mark.parametrize(("options", "needle", "code", "message"), [
    pytest.param("wrist_wrenh: [0, 0, 0, 0, 0, 0]", "wrist_wrenh", "E111", r"unknown option 'wrist_wrenh' of plant mujoco_arm",
                 id="an_unknown_name"),
    pytest.param("q0: [1, 2]", "[1, 2]", "E320", r"plant option q0 must have 6 values \(NDOF: the joints of puma560\), got: 2",
                 id="q0_of_another_length_than_the_robots_joints"),
    pytest.param("wrist_wrench: [0]", "[0]", "E320", r"plant option wrist_wrench must have 6 values, got: 1",
                 id="a_wrench_of_one_value"),
    pytest.param("seed: lucky", "lucky", "E320", r"plant option seed must be an integer, got: 'lucky'", id="a_wrong_type"),
    pytest.param("adc_noise: -1", "-1", "E320", r"plant option adc_noise must be in \[0, 10\], got: -1",
                 id="a_value_out_of_range"),
    pytest.param("q0: [0, 0, .nan, 0, 0, 0]", ".nan", "E320",
                 r"plant option q0\[2\] must be a finite number, got: \.nan \(not a number\)",
                 id="a_value_that_is_not_finite_at_its_element"),
    pytest.param("command_timeout: 1.0e+300", "1.0e+300", "E320",
                 r"plant option command_timeout must be in \[0, 3600\], got: 1e\+300",
                 id="a_time_beyond_its_range"),
])
def test_plant_options_are_checked_against_what_the_plant_declares(tmp_path: Path, options, needle, code, message) -> None:
    text = edited(BASE, ("timestep: 1 ms}", f"timestep: 1 ms, {options}}}"))
    error = expect(tmp_path, text, needle, code, message)
    if code == "E111":
        assert error.hint.startswith("did you mean 'wrist_wrench'?")


@pytest.mark.parametrize(("gains", "count"), [("kp: [400, 400]", 2), ("kd: [1, 2, 3, 4, 5, 6, 7]", 7)])
def test_a_gain_list_of_another_length_than_the_joints_is_refused_at_the_gain(tmp_path: Path, gains: str, count: int) -> None:
    text = edited(BASE, ("kp: 400, kd: 40", f"kp: 400, kd: 40, {gains}" if gains.startswith("kd") else f"{gains}, kd: 40"))
    if gains.startswith("kd"):
        text = edited(text, ("kd: 40, ", ""))
    name = gains.split(":")[0]
    error = expect(tmp_path, text, gains.split(": ")[1], "E308",
                   rf"params of task 'pid' \(module 'pid_joint'\): {name} must have 6 values \(NDOF\), got: {count}")
    assert error.hint == "give a list of 6 values, or one number for all"


@pytest.mark.parametrize(("option", "needle"), [("gain: 2", "gain"), ("mode: torq", "torq")])
def test_a_driver_option_the_driver_refuses_is_reported_at_the_option(tmp_path: Path, option: str, needle: str) -> None:
    text = edited(BASE, ("mode: torque, exclusive: true}", f"{option}, exclusive: true}}" if needle == "torq" else
                         f"mode: torque, exclusive: true, {option}}}"))
    error = only_error(check(tmp_path, text))
    assert (error.code, (error.line, error.column)) == ("E607", at(text, needle)), error.format()


def test_two_plant_mistakes_are_two_errors_in_one_pass(tmp_path: Path) -> None:
    result = check(tmp_path, edited(BASE, ("timestep: 1 ms}", "timestep: 1 ms, q0: [1, 2], wrist_wrenh: [0]}")))
    assert sorted(e.code for e in result.errors) == ["E111", "E320"]


# --- misleading messages ---------------------------------------------------------------------


def test_a_wrong_member_of_a_combined_module_is_one_error_without_a_nobody_writes_it_follow_on(tmp_path: Path) -> None:
    text = edited(BASE,
                  ("  pid:   {module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {kp: 400, kd: 40}, ports: {tau: tau_u}}",
                   "  pid:   {module: combined, rtpu: rtpu0, period: 1 ms, params: {members: [\n"
                   "            {module: pid_joint, ports: {tau: qdd_r}}, {module: inverse_dynamix}]}}"))
    error = only_error(check(tmp_path, text))
    assert error.code == "E308" and "member 2" in error.message and "inverse_dynamix" in error.message
    assert (error.line, error.column) == at(text, "inverse_dynamix")  # the member to fix, not the whole params


@pytest.mark.parametrize(("params", "needle"), [("{kp: 400, kq: 1}", "kq"), ("{kp: stiff}", "stiff"),
                                                ("{kp: 400, kd: -1}", "-1")])
def test_a_refused_parameter_is_reported_at_the_parameter(tmp_path: Path, params: str, needle: str) -> None:
    text = edited(BASE, ("params: {kp: 400, kd: 40}", f"params: {params}"))
    error = only_error(check(tmp_path, text))
    assert (error.code, (error.line, error.column)) == ("E308", at(text, needle)), error.format()


@pytest.mark.parametrize("value", ["high", "{a: 1}"])
def test_a_parameter_that_takes_a_number_or_a_list_says_both_when_it_gets_neither(tmp_path: Path, value: str) -> None:
    error = only_error(check(tmp_path, edited(BASE, ("kp: 400", f"kp: {value}"))))
    assert error.code == "E308"
    assert re.search(r"PidJoint\.kp must be a number or a list of numbers, got: ", error.message), error.message


def test_a_list_parameter_with_a_wrong_item_names_the_item(tmp_path: Path) -> None:
    error = only_error(check(tmp_path, edited(BASE, ("kp: 400", "kp: [400, high]"))))
    assert error.message.endswith("PidJoint.kp[1] must be a number, got: 'high'")


@pytest.mark.parametrize(("edit", "needle", "code", "message", "ports"), [
    pytest.param(("q_r:   {type: float64", "q_r:   {type: float32"), "float32", "E301",
                 r"variable 'q_r' is float32, but all 2 ports that link it are float64", ["traj", "pid"], id="its_type"),
    pytest.param(("tau_u: {type: float64, shape: [NDOF]}", "tau_u: {type: float64, shape: [7]}"), "[7]", "E302",
                 r"variable 'tau_u' has shape \(7,\), but all 2 ports that link it are of shape \(6,\)", ["robot", "pid"],
                 id="its_shape"),
])
def test_a_variable_declared_unlike_all_its_ports_is_one_error_at_the_declaration_with_the_ports_as_notes(
        tmp_path: Path, edit, needle, code, message, ports) -> None:
    text = edited(BASE, edit)
    error = expect(tmp_path, text, needle, code, message)
    assert [note.line for note in error.notes] == [at(text, f"{task}:")[0] for task in ports]


def test_a_port_unlike_the_other_ports_of_its_variable_is_the_error_with_the_declaration_as_a_note(tmp_path: Path) -> None:
    # the robot writes ARM and the PID reads it, both (6, 29); the PID's EE port, (8,), linked to ARM too is the odd one
    text = edited(BASE, ("  q_d:", "  ARM:   {type: float64, shape: [NDOF, 29]}\n  q_d:"),
                  ("ports: {tau: tau_u}", "ports: {tau: tau_u, end_effector: ARM}"))
    error = expect(tmp_path, text, "ARM}", "E302",
                   r"task 'pid' port 'end_effector' \(in-const\) has shape \(8,\), but variable 'ARM' has shape \(6, 29\)")
    [note] = error.notes
    assert (note.line, note.message) == (at(text, "ARM:")[0], "variable 'ARM' is declared with shape (6, 29) here")


def test_a_task_the_configuration_leaves_out_is_reported_at_the_configurations_list(tmp_path: Path) -> None:
    text = edited(BASE, ("[robot, traj, pid]", "[robot, pid]"))
    error = expect(tmp_path, text, "[robot, pid]", "E408",
                   r"configuration 'joint_pid' leaves out task 'traj', which writes 'q_r' and 'qd_r', read by 'pid'")
    assert error.hint == "add it: joint_pid: [robot, pid, traj]"
    assert [n.message for n in error.notes] == ["task 'pid' reads in-var 'q_r' and in-var 'qd_r'",
                                                "task 'traj' writes 'q_r' and 'qd_r'"]


def test_an_input_no_task_writes_anywhere_is_still_reported_at_its_reader(tmp_path: Path) -> None:
    text = edited(BASE, ("ports: {tau: tau_u}", "ports: {tau: tau_u, q_r: q_x}"),
                  ("  tau_u:", "  q_x:   {type: float64, shape: [NDOF]}\n  tau_u:"))
    expect(tmp_path, text, "q_x}", "E403", r"task 'pid' reads in-var 'q_x', but no task in configuration 'joint_pid' writes it")


# --- notes: where the fix goes first, the related places after --------------------------------


@pytest.mark.parametrize(("edits", "needle", "code", "note_at", "note"), [
    pytest.param([("configurations:",
                   "  gravity: {module: gravity_compensation, rtpu: rtpu1, period: 1 ms, ports: {tau_g: tau_u}}\n"
                   "configurations:"), ("[robot, traj, pid]", "[robot, traj, pid, gravity]")],
                 "tau_u}}\nconfigurations", "E401", "tau_u}}\n  gravity",
                 "task 'pid' writes 'tau_u' (port 'tau')", id="the_other_writer"),
    pytest.param([("[robot, traj, pid]", "[robot, traj, pid, pid]")], "pid]", "E402", "pid,", "task 'pid' is first listed here",
                 id="the_first_listing"),
    pytest.param([("params: {max_velocity: 1.0}}", "params: {max_velocity: 1.0}, resources: [arm]}")], "arm]}\n  pid", "E601",
                 "arm]}", "task 'robot' opens it here", id="the_other_user_of_an_exclusive_device"),
])
def test_a_conflict_is_reported_at_its_second_party_with_the_first_as_a_note(tmp_path: Path, edits, needle, code, note_at,
                                                                             note) -> None:
    text = edited(BASE, *edits)
    error = only_error(check(tmp_path, text))
    assert (error.code, (error.line, error.column)) == (code, at(text, needle)), error.format()
    assert [(n.line, n.column, n.message) for n in error.notes] == [(*at(text, note_at), note)]


def test_a_diagnostic_prints_its_notes_after_the_message_and_before_the_hint() -> None:
    error = ConfigError("variable 'x' is float32", "a.yaml", 3, 9, "change it", code="E301",
                        notes=[Note("task 't' port 'x' is float64", "a.yaml", 7, 3)])
    assert error.format() == ("a.yaml:3:9: error[E301]: variable 'x' is float32\n"
                              "  a.yaml:7:3: note: task 't' port 'x' is float64\n"
                              "  hint: change it")


def test_pbo_check_gives_the_notes_in_its_json_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "late.yaml"
    path.write_text(edited(BASE, ("[robot, traj, pid]", "[robot, pid]")))
    assert main(["check", str(path), "--format", "json"]) == 1
    [error] = json.loads(capsys.readouterr().out)["errors"]
    assert error["code"] == "E408"
    assert [n["line"] for n in error["notes"]] == [at(path.read_text(), "pid:")[0], at(path.read_text(), "traj:")[0]]
