"""The join connector of TR Figure 6: checked in a configuration, and its weighted average."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from modules.join import Join
from pbo_runtime import OutVar, ParamError, PortBasedObject
from pbo_runtime.config.loader import check_file
from pbo_runtime.config.model import PortBinding, TaskSpec
from pbo_runtime.task.lifecycle import Task
from tests.support import PBO, REPO, assert_nothing_left, demo_copy, variables


class FakeTorqueSource(PortBasedObject):
    """Fake module: writes a torque (linked to its own intermediate variable by the YAML)."""

    tau = OutVar("tau_u", shape=(3,))


class OtherFakeTorqueSource(FakeTorqueSource):
    """Fake module: a second, different torque source."""


LIBRARY = {"join": Join, "fake_source": FakeTorqueSource, "other_fake_source": OtherFakeTorqueSource}

JOINED = """\
subsystem: joins
rtpus: [rtpu0]
variables:
  tau_a: {type: float64, shape: [3]}
  tau_b: {type: float64, shape: [3]}
  tau_u: {type: float64, shape: [3]}
tasks:
  a:    {module: fake_source, rtpu: rtpu0, period: 1 ms, ports: {tau: tau_a}}
  b:    {module: other_fake_source, rtpu: rtpu0, period: 1 ms, ports: {tau: tau_b}}
  join: {module: join, rtpu: rtpu0, period: 1 ms, params: {inputs: [tau_a, tau_b], weights: [3, 1]}, ports: {out: tau_u}}
configurations:
  both: [a, b, join]
"""


def check(tmp_path, text):
    path = tmp_path / "joins.yaml"
    path.write_text(text)
    return check_file(path, module_lookup=LIBRARY.__getitem__, module_names=lambda: sorted(LIBRARY))


def test_two_writers_joined_by_a_join_connector_is_a_legal_configuration(tmp_path):
    result = check(tmp_path, JOINED)
    assert result.errors == [], [e.format() for e in result.errors]
    join = result.subsystem.tasks["join"]
    assert [(b.port.name, b.variable) for b in join.bindings] == [("out", "tau_u"), ("tau_a", "tau_a"), ("tau_b", "tau_b")]


def test_two_writers_of_one_variable_without_a_join_are_refused_with_the_hint(tmp_path):
    text = JOINED.replace("ports: {tau: tau_a}", "ports: {tau: tau_u}").replace("ports: {tau: tau_b}", "ports: {tau: tau_u}")
    text = text.replace("  both: [a, b, join]", "  both: [a, b]")
    result = check(tmp_path, text)
    assert any("two writers" in e.message and "join" in e.hint for e in result.errors), [e.format() for e in result.errors]


def test_join_averages_its_inputs_by_their_weights(make_table):
    table = make_table(variables(("tau_a", "float64", (3,)), ("tau_b", "float64", (3,)), ("tau_u", "float64", (3,))))
    params = Join.build_params({"inputs": ["tau_a", "tau_b"], "weights": [3, 1]})
    bindings = tuple(PortBinding(p, "tau_u" if p.name == "out" else p.variable, (3,)) for p in Join.ports_for(params))
    spec = TaskSpec("join", "join", "rtpu0", 0.001, params={"inputs": ["tau_a", "tau_b"], "weights": [3, 1]}, bindings=bindings)
    task = Task(spec, Join, table)
    table.write("tau_a", [4.0, 8.0, -4.0], when=0.0)
    table.write("tau_b", [0.0, 4.0, 4.0], when=0.0)
    assert task.spawn(0.0) and task.turn_on(0.0)
    task.run_cycle(0.001)
    assert table.read("tau_u")[0] == pytest.approx(np.array([3.0, 7.0, -2.0]))


def test_join_with_combine_sum_adds_its_weighted_inputs(make_table):
    table = make_table(variables(("tau_a", "float64", (3,)), ("tau_b", "float64", (3,)), ("tau_u", "float64", (3,))))
    values = {"inputs": ["tau_a", "tau_b"], "weights": [1, 2], "combine": "sum"}
    params = Join.build_params(values)
    bindings = tuple(PortBinding(p, "tau_u" if p.name == "out" else p.variable, (3,)) for p in Join.ports_for(params))
    task = Task(TaskSpec("join", "join", "rtpu0", 0.001, params=values, bindings=bindings), Join, table)
    table.write("tau_a", [4.0, 8.0, -4.0], when=0.0)
    table.write("tau_b", [0.0, 4.0, 4.0], when=0.0)
    assert task.spawn(0.0) and task.turn_on(0.0)
    task.run_cycle(0.001)
    assert table.read("tau_u")[0] == pytest.approx(np.array([4.0, 16.0, 4.0]))


@pytest.mark.parametrize(("params", "message"), [
    ({"inputs": ["x", "y"], "combine": "max"}, r"combine must be 'average' or 'sum', got: 'max'"),
    ({"inputs": ["tau_a"]}, r"inputs must name at least two variables to join, got: \['tau_a'\]"),
    ({"inputs": ["x", "x"]}, r"inputs must not repeat"),
    ({"inputs": ["x", "y"], "weights": [1]}, r"weights and inputs must have equal length: \|weights\| = 1, \|inputs\| = 2"),
    ({"inputs": ["x", "y"], "weights": [0, 0]}, r"weights must be >= 0 and not all zero"),
])
def test_join_params_are_checked(params, message):
    with pytest.raises(ParamError, match=message):
        Join.build_params(params)


# --- TR Figure 6 on the arm: configs/join.yaml ----------------------------------------------------

FIGURE_6 = REPO / "configs" / "join.yaml"


def test_figure_6_with_one_join_per_conflicting_output_checks_clean_issue_22():
    result = check_file(FIGURE_6)
    assert result.errors == [] and result.warnings == [], [e.format() for e in result.errors + result.warnings]
    joins = {name: task for name, task in result.subsystem.tasks.items() if task.module == "join"}
    figure = result.subsystem.configurations["figure_6"].tasks
    assert [name for name in figure if name in joins] == ["join_q", "join_qd"]
    assert [name for name in figure if result.subsystem.tasks[name].module == "joint_trajectory"] == ["traj_a", "traj_b"]


def test_the_figure_6_file_without_its_join_connectors_has_two_writers_of_each_shared_output(tmp_path):
    text = FIGURE_6.read_text()
    for task in ("traj_a", "traj_b"):
        text = text.replace(f"ports: {{q_r: q_r_{task[-1]}, qd_r: qd_r_{task[-1]}}}", "ports: {q_r: q_r, qd_r: qd_r}")
    text = text.replace("  figure_6:   [robot, traj_a, traj_b, join_q, join_qd, pid]",
                        "  figure_6:   [robot, traj_a, traj_b, pid]")
    path = tmp_path / "no_join.yaml"
    path.write_text(text)
    errors = check_file(path).errors
    assert [e.code for e in errors] == ["E407"], [e.format() for e in errors]  # B repeats A on the same outputs
    assert "runs module 'joint_trajectory' twice: as task 'traj_a'" in errors[0].message
    assert "both writing q_r and qd_r" in errors[0].message
    assert "join connector (TR Figure 6)" in errors[0].hint


@pytest.mark.multiprocess
@pytest.mark.parametrize("seconds", [0.4, 3.0], ids=["moving", "arrived"])
def test_figure_6_joins_the_two_references_into_the_one_the_pid_follows_and_the_arm_reaches_its_goal_issue_22(tmp_path, seconds):
    """A and B write p' and p''; one join per conflicting output gives the PID its q_r and qd_r."""
    report = run_report(tmp_path, demo_copy(tmp_path, f"fig6_{int(seconds * 10)}", source=FIGURE_6), seconds)
    values = {name: np.array(v["value"]) for name, v in report["variables"].items()}
    writers = {name: v["writer"] for name, v in report["variables"].items()}
    assert (writers["q_r_a"], writers["q_r_b"], writers["q_r"], writers["qd_r"], writers["tau_u"]) == (
        "traj_a", "traj_b", "join_q", "join_qd", "pid")
    # the joins read A and B once a 2 ms cycle: they lag them by at most a cycle's motion (1.5 rad/s x 2 ms)
    np.testing.assert_allclose(values["q_r"], (values["q_r_a"] + values["q_r_b"]) / 2, atol=0.006)
    if seconds < 1:  # on the way, the brisk and the gentle reference differ: the joined one is between them
        assert np.max(np.abs(values["q_r_a"] - values["q_r_b"])) > 0.1
    else:
        assert np.max(np.abs(values["q_m"] - values["q_d"])) < 0.005, f"arm at {values['q_m']}, goal {values['q_d']}"
    assert_nothing_left(report)


@pytest.mark.multiprocess
def test_the_torque_sum_join_gives_the_robot_feedback_plus_gravity_and_the_arm_reaches_its_goal(tmp_path):
    """p' (PID) and p'' (gravity) are joined into the one tau_u the robot reads."""
    report = run_report(tmp_path, demo_copy(tmp_path, "fig6_torque_sum", source=FIGURE_6), 2.5, "torque_sum")
    values = {name: np.array(v["value"]) for name, v in report["variables"].items()}
    writers = {name: v["writer"] for name, v in report["variables"].items()}
    assert (writers["tau_pid"], writers["tau_g"], writers["tau_u"]) == ("pid_fb", "gravity", "join_tau")
    # the robot reads the sum (the two inputs are sampled a cycle apart: the arm is still, they barely change)
    np.testing.assert_allclose(values["tau_u"], values["tau_pid"] + values["tau_g"], atol=0.05)
    error = np.max(np.abs(values["q_m"] - values["q_d"]))
    sag = np.max(np.abs(values["tau_g"])) / 400.0  # what the PID alone (kp 400, no integral) would settle to
    assert error < 0.005 and sag > 10 * error, f"error {error:.4f} rad, PID alone would sag {sag:.4f} rad"
    assert_nothing_left(report)


def run_report(folder, path, seconds: float, configuration: str | None = None) -> dict:
    report_path = folder / "report.json"
    chosen = ["--config", configuration] if configuration else []
    done = subprocess.run([*PBO, "run", str(path), *chosen, "--duration", str(seconds), "--clock", "sim",
                           "--report", str(report_path), "--no-live"], cwd=folder, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    return json.loads(report_path.read_text())
