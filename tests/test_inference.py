"""Pins joined by name: variables that only connect ports take their dtype and shape from the ports.

Figure 8 written with only its tasks and the variable that needs an initial value checks clean and
describes the same subsystem as configs/pid_joint.yaml; what cannot be inferred is an error at the
port (or at the entry), with a hint to declare it.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pbo_runtime.cli import main
from pbo_runtime.config.loader import CheckResult, check_file
from tests.support import REPO

FULL = REPO / "configs" / "pid_joint.yaml"
MINIMAL = REPO / "configs" / "pid_joint_minimal.yaml"

# A small subsystem of shipped modules: a trajectory generator and its reader, nothing declared.
SMALL = """\
subsystem: small
rtpus: [rtpu0]
dims: {NDOF: 6}
variables:
  q_d: {type: float64, shape: [NDOF], initial: 0}
  q_m: {type: float64, shape: [NDOF], initial: 0}
  qd_m: {type: float64, shape: [NDOF], initial: 0}
tasks:
  traj: {module: joint_trajectory, rtpu: rtpu0, period: 2 ms, params: {max_velocity: 1.0}}
  pos:  {module: time_integrator, rtpu: rtpu0, period: 1 ms}
configurations:
  moving: [traj]
"""


def check(tmp_path: Path, text: str) -> CheckResult:
    path = tmp_path / "file.yaml"
    path.write_text(text)
    return check_file(path)


def errors(result: CheckResult) -> list[tuple[str, int, str]]:
    return [(e.code, e.line, e.message) for e in result.errors]


def test_figure_8_with_only_its_tasks_and_initial_values_checks_clean_as_the_same_subsystem() -> None:
    minimal, full = check_file(MINIMAL), check_file(FULL)
    assert minimal.errors == [] and minimal.warnings == []
    a, b = minimal.subsystem, full.subsystem
    assert a is not None and b is not None
    assert {n: (v.dtype, v.shape) for n, v in a.variables.items()} == {n: (v.dtype, v.shape) for n, v in b.variables.items()}
    assert dict(a.dims) == dict(b.dims) == {"NDOF": 6}
    assert a.init_order == b.init_order
    for name, task in a.tasks.items():
        assert [(x.port.name, x.variable, x.shape) for x in task.bindings] == \
               [(x.port.name, x.variable, x.shape) for x in b.tasks[name].bindings]
    assert (minimal.initial_values["q_d"] == full.initial_values["q_d"]).all()
    assert set(minimal.inferred) == set(a.variables)  # q_d too: its entry gives no type
    assert minimal.robot_dims == {"NDOF": 6}
    assert full.inferred == () and full.robot_dims == {"NDOF": 6}  # neither file copies NDOF into dims:


def test_pbo_check_lists_the_inferred_variables_and_dims_in_text_and_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(MINIMAL)]) == 0
    out = capsys.readouterr().out
    assert "dims from the plant's robot 'puma560': NDOF = 6" in out
    assert "inferred from their ports: 9 variable(s)" in out
    assert any(line.split() == ["ARM", "float64", "[6,", "29]"] for line in out.splitlines())
    assert any(line.split() == ["EE", "float64", "[8]"] for line in out.splitlines())
    assert main(["check", "--format", "json", str(MINIMAL)]) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["inferred"]["ARM"] == {"type": "float64", "shape": [6, 29]}
    assert document["inferred"]["EE"] == {"type": "float64", "shape": [8]}
    assert document["inferred"]["NDOF"] == {"type": "int32", "shape": []}
    assert document["robot_dims"] == {"NDOF": 6}


def test_a_file_that_declares_every_variable_says_nothing_of_inference(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(FULL)]) == 0
    assert "inferred" not in capsys.readouterr().out
    assert main(["check", "--format", "json", str(FULL)]) == 0
    document = json.loads(capsys.readouterr().out)
    assert "inferred" not in document
    assert document["robot_dims"] == {"NDOF": 6}  # NDOF is the robot's, not a copy in dims: (TR §4.3)


def test_a_variable_only_ports_link_takes_their_dtype_and_shape(tmp_path: Path) -> None:
    result = check(tmp_path, SMALL)
    assert result.errors == [], errors(result)
    assert result.subsystem is not None
    assert {n: (v.dtype, v.shape) for n, v in result.subsystem.variables.items() if n in result.inferred} == {
        "q_r": ("float64", (6,)), "qd_r": ("float64", (6,))}


def test_a_declared_variable_wins_and_its_ports_are_checked_against_it(tmp_path: Path) -> None:
    text = SMALL.replace("variables:\n", "variables:\n  q_r: {type: float32, shape: [NDOF]}\n")
    result = check(tmp_path, text)
    assert [(code, message) for code, _, message in errors(result)] == [  # once, at the declaration: both ports agree
        ("E301", "variable 'q_r' is float32, but all 2 ports that link it are float64")]
    assert "q_r" not in result.inferred


def test_an_entry_without_a_type_takes_it_from_its_ports_and_its_initial_value_is_checked_against_it(tmp_path: Path) -> None:
    good = check(tmp_path, SMALL.replace("q_d: {type: float64, shape: [NDOF], initial: 0}",
                                         "q_d: {initial: [1, 2, 3, 4, 5, 6], doc: goal}"))
    assert good.errors == [] and good.subsystem is not None
    assert (good.subsystem.variables["q_d"].dtype, good.subsystem.variables["q_d"].doc) == ("float64", "goal")
    assert list(good.initial_values["q_d"]) == [1, 2, 3, 4, 5, 6]
    bad = check(tmp_path, SMALL.replace("q_d: {type: float64, shape: [NDOF], initial: 0}", "q_d: {initial: [1, 2, 3]}"))
    assert [(code, line) for code, line, _ in errors(bad)] == [("E312", 5)]


def test_an_entry_without_a_type_that_no_port_links_is_an_error_at_the_entry(tmp_path: Path) -> None:
    result = check(tmp_path, SMALL.replace("variables:\n", "variables:\n  spare: {doc: nothing links it}\n"))
    assert errors(result) == [("E112", 5, "variable 'spare' has no 'type:', and no task's port links it to give it one")]


def test_ports_that_disagree_on_an_undeclared_variable_are_each_an_error(tmp_path: Path) -> None:
    # the integrator's q_r is (NDOF,); the trajectory generator's x_r (6,), with NDOF 7, linked to q_r too
    text = SMALL.replace("dims: {NDOF: 6}", "dims: {NDOF: 7}").replace("initial: 0}", "initial: 0}", 2)
    text = text.replace("  pos:  {module: time_integrator, rtpu: rtpu0, period: 1 ms}",
                        "  pos:  {module: time_integrator, rtpu: rtpu0, period: 1 ms}\n"
                        "  cart: {module: cartesian_trajectory, rtpu: rtpu0, period: 1 ms, "
                        "ports: {x_r: q_r, x_d: q_d, x_m: q_m}}")
    result = check(tmp_path, text)
    shapes = [(code, message) for code, _, message in errors(result) if "'q_r'" in message]
    assert [code for code, _ in shapes] == ["E317"] * 3, errors(result)
    assert ("task 'cart' port 'x_r' (out-var) gives undeclared variable 'q_r' shape (6,), "
            "but task 'traj' port 'q_r' gives it shape (7,)") in [message for _, message in shapes]
    assert all(e.hint.startswith("ports that share a variable agree on its shape: declare 'q_r'")
               for e in result.errors if e.code == "E317")


def test_a_port_of_any_dtype_cannot_define_a_variable_and_the_hint_says_to_declare_it(tmp_path: Path) -> None:
    text = SMALL.replace("  pos: ", "  j:    {module: join, rtpu: rtpu0, period: 1 ms, params: {inputs: [q_r, q_d]}}\n  pos: ")
    result = check(tmp_path, text)
    assert [(code, message) for code, _, message in errors(result)] == [
        ("E206", "task 'j' (module 'join') links port 'out' by default to variable 'joined', which 'variables' does not declare "
                 "and its ports cannot define")]
    assert result.errors[0].hint.startswith("no port that links 'joined' declares a dtype (port 'out' of task 'j' is any dtype, "
                                            "any shape); declare 'joined' under variables:")


def test_a_name_only_one_tasks_ports_mapping_uses_is_not_made_a_variable(tmp_path: Path) -> None:
    result = check(tmp_path, SMALL.replace("period: 1 ms}", "period: 1 ms, ports: {q_r: q_rr}}"))
    assert [(code, message) for code, _, message in errors(result)] == [
        ("E205", "task 'pos' links port 'q_r' to variable 'q_rr', which 'variables' does not declare")]
    assert result.errors[0].hint.startswith("did you mean 'q_r'?")


def test_two_tasks_may_name_a_new_variable_in_their_ports_mappings(tmp_path: Path) -> None:
    text = (SMALL.replace("period: 1 ms}", "period: 1 ms, ports: {q_r: q_a}}")
            .replace("max_velocity: 1.0}", "max_velocity: 1.0}, ports: {q_r: q_a}"))
    result = check(tmp_path, text)
    assert "q_a" in result.inferred, errors(result)


def test_without_dims_a_port_dim_comes_from_the_plants_robot_and_never_overrides_dims(tmp_path: Path) -> None:
    no_dims = SMALL.replace("dims: {NDOF: 6}", "plant: {model: redundant7}").replace("shape: [NDOF]", "shape: [7]")
    result = check(tmp_path, no_dims)
    assert result.errors == [], errors(result)
    assert result.robot_dims == {"NDOF": 7} and result.subsystem is not None and result.subsystem.dims == {"NDOF": 7}
    given = check(tmp_path, SMALL.replace("dims: {NDOF: 6}", "dims: {NDOF: 7}\nplant: {model: redundant7}"))
    assert given.errors == [] and given.robot_dims == {} and given.subsystem is not None  # dims said it: nothing taken
    assert given.subsystem.variables["q_r"].shape == (7,)


def test_dims_that_disagree_with_the_plants_robot_are_e318_at_the_dim_never_overridden(tmp_path: Path) -> None:
    given = check(tmp_path, SMALL.replace("dims: {NDOF: 6}", "dims: {NDOF: 6}\nplant: {model: redundant7}"))
    assert [(code, message.split(" (at ")[0]) for code, _, message in errors(given)] == [
        ("E318", "dim 'NDOF' is 6 here, but the plant's robot 'redundant7' has 7 joints")]
    assert given.errors[0].line == 3 and given.robot_dims == {}
    assert given.errors[0].hint == "remove NDOF from dims: (the robot gives it) or set it to 7"


def test_without_dims_and_without_a_plant_an_undefined_port_dim_is_e304_with_a_hint_to_add_one(tmp_path: Path) -> None:
    result = check(tmp_path, SMALL.replace("dims: {NDOF: 6}\n", "").replace("shape: [NDOF]", "shape: [6]"))
    codes = {e.code for e in result.errors}
    assert codes == {"E304"}, errors(result)
    assert all("add a plant: whose robot gives it" in e.hint for e in result.errors)


@pytest.mark.parametrize("name", ["pid_joint", "computed_torque", "cartesian_teleop", "visual_servoing", "switch_joint",
                                  "fault_drill", "operator_goal", "force_sensing", "leader", "follower", "join",
                                  "combined_modules", "cartesian_teleop_hmi", "visual_servoing_spp"])
def test_a_shipped_config_takes_ndof_from_its_robot_with_no_dims_copied_in(name: str) -> None:
    """TR §4.3: if the robot is changed, only the robot interface changes; no file repeats its NDOF."""
    path = REPO / "configs" / f"{name}.yaml"
    assert "\ndims:" not in path.read_text()
    result = check_file(path)
    assert result.errors == [] and result.warnings == []
    assert result.robot_dims == {"NDOF": 6} and result.subsystem is not None and result.subsystem.dims == {"NDOF": 6}
