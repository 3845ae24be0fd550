"""Combined modules (TR §4.5): members run as one task, member-to-member links stay local."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from modules.combined import Combined
from modules.joint_trajectory import JointTrajectory
from modules.pid_joint import PidJoint
from pbo_runtime import ParamError
from pbo_runtime.config import bus_model
from pbo_runtime.config.loader import check_file
from pbo_runtime.config.model import PortBinding, TaskSpec
from pbo_runtime.task.lifecycle import Task
from tests.support import PBO, REPO, arm_constants, arm_tables, assert_nothing_left, demo_copy, task_spec, variables

PUMA_ARM, PUMA_EE = arm_tables("puma560")  # what its robot interface publishes
DIMS = {"NDOF": 6}
MEMBERS = [
    {"module": "joint_trajectory", "params": {"max_velocity": 1.0, "max_acceleration": 4.0}},
    {"module": "pid_joint", "params": {"kp": 400, "kd": 40, "gravity_feedforward": False}, "ports": {"tau": "tau_u"}},
]

ARM = variables(
    *arm_constants(6), ("q_m", "float64", (6,)),
    ("qd_m", "float64", (6,)), ("q_d", "float64", (6,)), ("q_r", "float64", (6,)), ("qd_r", "float64", (6,)),
    ("tau_u", "float64", (6,)),
)


def combined_spec(params, index=0) -> TaskSpec:
    built = Combined.build_params(params)
    bindings = tuple(PortBinding(p, p.variable, p.resolved_shape(DIMS)) for p in Combined.ports_for(built))
    return TaskSpec("ctl", "combined", "rtpu0", 0.001, params=params, bindings=bindings, index=index)


def test_links_between_members_stay_local_and_shared_inputs_are_read_once():
    params = Combined.build_params({"members": MEMBERS})
    ports = {p.name: p.kind.value for p in Combined.ports_for(params)}
    assert "q_r" not in ports and "qd_r" not in ports  # traj -> pid only: local
    assert ports["q_m"] == "in-var" and list(ports).count("q_m") == 1  # both read q_m: one port
    assert ports["tau_u"] == "out-var" and ports["q_d"] == "in-var" and ports["ARM"] == ports["EE"] == "in-const"


def test_an_exported_link_is_written_to_the_table_and_read_in_place_by_the_members():
    params = Combined.build_params({"members": MEMBERS, "export": ["q_r"]})
    ports = {p.name: p.kind.value for p in Combined.ports_for(params)}
    assert ports["q_r"] == "out-var" and "qd_r" not in ports


def test_a_combined_task_computes_what_its_members_compute_apart(make_table):
    def arm_table():
        table = make_table(ARM)
        table.write("NDOF", 6, when=0)
        table.write("ARM", PUMA_ARM, when=0)
        table.write("EE", PUMA_EE, when=0)
        table.write("q_m", np.full(6, 0.1), when=0)
        table.write("q_d", np.full(6, 0.5), when=0)
        return table

    together = arm_table()
    task = Task(combined_spec({"members": MEMBERS}), Combined, together, DIMS)
    apart = arm_table()
    traj = Task(task_spec(JointTrajectory, "traj", 0, dims=DIMS, params=MEMBERS[0]["params"]), JointTrajectory, apart, DIMS)
    pid = Task(task_spec(PidJoint, "pid", 1, dims=DIMS, ports={"tau": "tau_u"},
                         params=MEMBERS[1]["params"]), PidJoint, apart, DIMS)
    for t in (task, traj, pid):
        assert t.spawn(0.0), t.last_error
        assert t.turn_on(0.0), t.last_error
    for k in range(1, 50):
        task.run_cycle(k * 0.001)
        traj.run_cycle(k * 0.001)
        pid.run_cycle(k * 0.001)
        assert together.read("tau_u")[0] == pytest.approx(apart.read("tau_u")[0], abs=1e-12)
    assert together.read("q_r")[1] == 0  # never written: it stayed local


@pytest.mark.parametrize(("params", "message"), [
    ({"members": [MEMBERS[0]]}, r"members must list at least two modules to combine"),
    ({"members": [MEMBERS[0], {"module": "pid_jiont"}]}, r"member 2: no module named 'pid_jiont'"),
    ({"members": [MEMBERS[0], {"module": "pid_joint", "ports": {"torque": "x"}}]},
     r"member 2 \(pid_joint\) has no port\(s\) 'torque'"),
    ({"members": [MEMBERS[1], MEMBERS[1]]}, r"members 1:pid_joint and 2:pid_joint both write 'tau_u'"),
    ({"members": [MEMBERS[0], {"module": "pid_joint", "params": {"kp": -1}}]},
     r"^bad parameters for Combined: member 2 \(pid_joint\): PidJoint\.kp must be in \[0, 1e\+06\], got: -1$"),
    ({"members": [MEMBERS[0], MEMBERS[1]], "export": ["tau_u"]}, r"export names 'tau_u', which is no member-to-member variable"),
])
def test_bad_members_are_refused_with_the_reason(params, message):
    with pytest.raises(ParamError, match=message):
        Combined.build_params(params)


def test_the_computed_torque_configuration_checks_and_the_bus_shows_what_combining_saves():
    result = check_file(REPO / "configs" / "computed_torque.yaml")
    assert result.errors == [], [e.format() for e in result.errors]
    subsystem = result.subsystem
    apart = bus_model.predict(subsystem, "separate")
    together = bus_model.predict(subsystem, "combined")
    assert together.total < apart.total  # qdd_r never crosses the bus when PID and inverse dynamics are one task
    ctc = subsystem.tasks["ctc"]
    assert "qdd_r" not in {b.variable for b in ctc.bindings}


@pytest.mark.multiprocess
def test_computed_torque_tracks_a_fast_trajectory_at_least_five_times_better_than_pid_alone():
    """TR Figure 14's point, on the arm and the simulated clock (so the figures are exact)."""
    from tools.tracking_gain import tracking_errors

    errors = tracking_errors(seconds=2.5)
    assert errors["pid_alone"]["max"] >= 5 * errors["combined"]["max"], errors
    assert errors["pid_alone"]["rms"] >= 5 * errors["combined"]["rms"], errors


# --- two different combined modules in one configuration (issue 22) ----------------------------

TWO_COMBINED = REPO / "configs" / "combined_modules.yaml"


def test_a_configuration_with_two_different_combined_modules_checks_clean_issue_22():
    result = check_file(TWO_COMBINED)
    assert result.errors == [] and result.warnings == [], [e.format() for e in result.errors + result.warnings]
    tasks = result.subsystem.tasks
    members = result.subsystem.configurations["two_combined"].tasks
    assert [name for name in members if tasks[name].module == "combined"] == ["ik", "ctc"]
    assert {b.variable for b in tasks["ik"].bindings if not b.port.kind.is_input} == {"q_r", "qd_r"}  # qd_r exported
    assert "qdd_r" not in {b.variable for b in tasks["ctc"].bindings}  # kept local


@pytest.mark.multiprocess
def test_two_combined_modules_bring_the_hand_to_its_cartesian_goal_issue_22(tmp_path):
    """ik (resolved rate + integrator) gives the joint reference, ctc (PID + inverse dynamics) the torque."""
    path = demo_copy(tmp_path, "two_combined_run", source=TWO_COMBINED)
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(path), "--duration", "3", "--clock", "sim", "--report", str(report_path),
                           "--no-live"], cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    report = json.loads(report_path.read_text())
    values = {name: np.array(v["value"]) for name, v in report["variables"].items()}
    writers = {name: v["writer"] for name, v in report["variables"].items()}
    assert (writers["q_r"], writers["qd_r"], writers["tau_u"]) == ("ik", "ik", "ctc")
    assert np.max(np.abs(values["x_m"][:3] - values["x_d"][:3])) < 0.002, f"hand at {values['x_m'][:3]}, goal {values['x_d'][:3]}"
    assert np.max(np.abs(values["x_m"][3:] - values["x_d"][3:])) < 0.01  # and holds its orientation
    assert_nothing_left(report)
