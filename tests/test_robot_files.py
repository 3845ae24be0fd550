"""Robots from URDF and MJCF files: messy real files load, the controllers' model is the plant's, the checker checks.

The real robots are files no one here wrote, shipped by the example-robot-data package (a test
dependency); the small ones are written by the tests themselves, to make each mess on purpose.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pinocchio
import pytest

from drivers.robots.files import RobotFileError
from drivers.robots.plant_model import load_robot
from pbo_runtime import Arm, arm_model
from pbo_runtime.config.loader import check_file
from tests.support import EXAMPLE_ROBOTS, example_robot

TIMESTEP = 0.001


def random_states(model: mujoco.MjModel, count: int = 10, seed: int = 21):
    """States strictly inside the joint ranges (no limit acts), moving and accelerating."""
    rng = np.random.default_rng(seed)
    low = np.where(model.jnt_limited > 0, model.jnt_range[:, 0], -np.pi)
    high = np.where(model.jnt_limited > 0, model.jnt_range[:, 1], np.pi)
    margin = 0.1 * (high - low)
    for _ in range(count):
        yield rng.uniform(low + margin, high - margin), rng.uniform(-1, 1, model.nv), rng.uniform(-3, 3, model.nv)


@pytest.fixture(scope="module", params=sorted(EXAMPLE_ROBOTS))
def shipped(request):
    """Each arm of example-robot-data in turn, as the plant loads it."""
    return load_robot(example_robot(request.param), Path("."), TIMESTEP, {})


def test_pinocchio_from_the_arm_table_matches_mujoco_inverse_dynamics(shipped):
    mj_model = shipped.model
    mj_model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)  # the tree's dynamics alone
    mj_data = mujoco.MjData(mj_model)
    model = arm_model(shipped.arm, shipped.ee)
    data = model.createData()
    for q, v, a in random_states(mj_model):
        mj_data.qpos[:], mj_data.qvel[:], mj_data.qacc[:] = q, v, a
        mujoco.mj_inverse(mj_model, mj_data)
        expected = mj_data.qfrc_inverse - mj_model.dof_damping * v  # MuJoCo's inverse counts the damping's torque
        np.testing.assert_allclose(pinocchio.rnea(model, data, q, v, a), expected, rtol=0, atol=1e-6)


def test_the_end_effector_frame_is_where_the_plant_puts_its_site(shipped):
    mj_model = shipped.model
    mj_data = mujoco.MjData(mj_model)
    model = arm_model(shipped.arm, shipped.ee)
    data = model.createData()
    ee = model.getFrameId("ee")
    for q, _, _ in random_states(mj_model, count=5):
        mj_data.qpos[:] = q
        mujoco.mj_kinematics(mj_model, mj_data)
        pinocchio.framesForwardKinematics(model, data, q)
        site = mj_model.site("ee").id
        np.testing.assert_allclose(data.oMf[ee].translation, mj_data.site_xpos[site], atol=1e-9)
        np.testing.assert_allclose(data.oMf[ee].rotation, mj_data.site_xmat[site].reshape(3, 3), atol=1e-9)


def test_the_ur5_loads_with_its_names_limits_and_what_was_dropped_said():
    ur5 = load_robot(example_robot("ur5"), Path("."), TIMESTEP, {})
    assert ur5.joint_names == ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                               "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
    assert ur5.ee_name == "tool0"  # the tip of the chain, when the YAML does not name one
    np.testing.assert_array_equal(ur5.torque_limits, [150, 150, 150, 28, 28, 28])  # the URDF's effort
    np.testing.assert_allclose(ur5.velocity_limits, [3.15, 3.15, 3.15, 3.2, 3.2, 3.2])  # its velocity
    np.testing.assert_array_equal(ur5.arm[:, Arm.EFFORT], ur5.torque_limits)
    assert any("dropped meshes MuJoCo cannot read" in note and ".dae" in note for note in ur5.notes)
    assert ur5.dims == {"NDOF": 6}


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def two_link_urdf(extra_link: str = "", extra_robot: str = "", effort: str = 'effort="20"', joint2: str = "revolute") -> str:
    inertial = '<inertial><mass value="{m}"/><inertia ixx="0.02" iyy="0.02" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
    return f"""<?xml version="1.0"?>
<robot name="two_link">
  <link name="base"/>
  <link name="upper">{inertial.format(m=2.0)}{extra_link}</link>
  <link name="fore">{inertial.format(m=1.0)}</link>
  <link name="tool"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" {effort} velocity="2"/></joint>
  <joint name="elbow" type="{joint2}"><parent link="upper"/><child link="fore"/>
    <origin xyz="0 0 0.4"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" {effort} velocity="2"/></joint>
  <joint name="flange" type="fixed"><parent link="fore"/><child link="tool"/><origin xyz="0 0 0.3"/></joint>
  {extra_robot}
</robot>
"""


def test_a_messy_urdf_loads_with_package_meshes_resolved_and_the_rest_dropped(tmp_path):
    package = tmp_path / "my_arm_description"
    write(package, "package.xml", "<package><name>my_arm_description</name></package>")
    write(package, "meshes/upper.obj", "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    write(package, "meshes/upper.dae", "<COLLADA/>")
    write(package, "meshes/broken.stl", "solid ascii, which MuJoCo does not decode\nendsolid\n")
    visual = '<visual><geometry><mesh filename="package://my_arm_description/meshes/upper.dae"/></geometry></visual>'
    collision = '<collision><geometry><mesh filename="package://my_arm_description/meshes/upper.obj"/></geometry></collision>'
    gone = '<collision><geometry><mesh filename="package://my_arm_description/meshes/gone.stl"/></geometry></collision>'
    broken = '<collision><geometry><mesh filename="../meshes/broken.stl"/></geometry></collision>'
    urdf = write(package, "urdf/arm.urdf", two_link_urdf(
        extra_link=visual + collision + gone + broken,
        extra_robot='<gazebo reference="upper"><material>Gazebo/Grey</material></gazebo>'
                    '<transmission name="t"><type>x</type></transmission>'))
    arm = load_robot(str(urdf), tmp_path, TIMESTEP, {"ee": "tool"})
    assert arm.joint_names == ("shoulder", "elbow") and arm.ee_name == "tool"
    notes = " | ".join(arm.notes)
    assert "left out, tags for other tools: 1 <gazebo>, 1 <transmission>" in notes
    assert "1 visual .dae" in notes
    assert "not found" in notes and "gone.stl" in notes
    assert "dropped mesh broken.stl, which MuJoCo cannot decode" in notes
    assert arm.model.ngeom >= 1  # the readable collision mesh stayed


@pytest.mark.parametrize(("change", "key", "message"), [
    ({"model": "missing.urdf"}, "model", "robot file .*missing.urdf does not exist"),
    ({"ee": "wrist"}, "ee", "end effector 'wrist' is neither a link"),
    ({"q0": [0.0]}, "q0", "plant option q0 must have 2 values"),
    ({"torque_limits": [1, -1]}, "torque_limits", "plant option torque_limits must be 2 finite numbers > 0"),
])
def test_a_robot_that_cannot_be_used_says_what_and_which_key(tmp_path, change, key, message):
    write(tmp_path, "arm.urdf", two_link_urdf())
    options = {k: v for k, v in change.items() if k != "model"}
    with pytest.raises(RobotFileError, match=message) as refused:
        load_robot(change.get("model", "arm.urdf"), tmp_path, TIMESTEP, options)
    assert refused.value.key == key


@pytest.mark.parametrize(("urdf", "message"), [
    (two_link_urdf(effort='effort="0"'), "gives no torque limit for joints shoulder, elbow: give each joint one"),
    (two_link_urdf(joint2="floating"), "is a free joint"),
    ("<robot name='x'><link name='a'/></robot>", "has no joints"),
    ("<robot name='x'><link", "is not well-formed XML"),
    ("<sdf version='1.6'/>", "has a <sdf> root; a URDF has <robot>, an MJCF <mujoco>"),
    ("<!DOCTYPE r [<!ENTITY a 'aaaa'>]><robot name='x'/>", "declares entities or a DOCTYPE"),
])
def test_a_broken_robot_file_is_refused_with_the_reason(tmp_path, urdf, message):
    write(tmp_path, "arm.urdf", urdf)
    with pytest.raises(RobotFileError, match=message):
        load_robot("arm.urdf", tmp_path, TIMESTEP, {})


def test_an_mjcf_arm_gives_its_actuators_force_ranges_and_its_home_keyframe(tmp_path):
    write(tmp_path, "arm.xml", """<mujoco model="mj_arm">
  <compiler angle="radian"/>
  <worldbody>
    <body name="upper"><joint name="shoulder" axis="0 1 0" range="-2 2"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.4" size="0.04" mass="2"/>
      <body name="fore" pos="0 0 0.4"><joint name="elbow" axis="0 1 0" range="-2 2" damping="0.5"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.03" mass="1"/>
        <site name="tip" pos="0 0 0.3"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="shoulder" ctrlrange="-1 1" gear="30"/>
    <position joint="elbow" kp="50" forcerange="-12 12"/>
  </actuator>
  <keyframe><key name="home" qpos="0.3 -0.4"/></keyframe>
</mujoco>""")
    arm = load_robot("arm.xml", tmp_path, TIMESTEP, {"ee": "tip"})
    np.testing.assert_array_equal(arm.torque_limits, [30.0, 12.0])
    np.testing.assert_array_equal(arm.q0, [0.3, -0.4])
    assert arm.model.nu == 0 and any("removed 2 actuators" in note for note in arm.notes)
    assert arm.arm[1, Arm.DAMPING] == 0.5 and arm.ee[0] == 1  # the tip moves with the elbow


def test_a_registered_robot_takes_the_same_road_and_keeps_its_dh_dynamics():
    from drivers.robots import robot
    from tests.support import dh_pinocchio_model

    puma = robot("puma560")
    loaded = load_robot("puma560", Path("."), TIMESTEP, {})
    ours, theirs = arm_model(loaded.arm, loaded.ee), dh_pinocchio_model(puma.dh, puma.dyn)
    for q, v, a in random_states(loaded.model, count=5):
        np.testing.assert_allclose(pinocchio.rnea(ours, ours.createData(), q, v, a),
                                   pinocchio.rnea(theirs, theirs.createData(), q, v, a), atol=1e-9)
    np.testing.assert_array_equal(loaded.q0, puma.q0)
    np.testing.assert_array_equal(loaded.torque_limits, puma.torque_limits)


# --- what pbo check says -----------------------------------------------------------------------


def subsystem_with(tmp_path: Path, plant: str, dims: str = "") -> Path:
    return write(tmp_path, "robot.yaml", f"""subsystem: mine
rtpus: [rtpu0]
plant: {plant}
devices:
  arm: {{driver: mujoco_arm, mode: torque, exclusive: true}}
{dims}
variables:
  q_d: {{type: float64, shape: [NDOF], initial: 0}}
tasks:
  robot: {{module: robot_torque, rtpu: rtpu0, period: 1 ms, critical: true, resources: [arm]}}
  pid:   {{module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {{kp: 10, kd: 1}}, ports: {{tau: tau_u, q_r: q_d, qd_r: qd_m}}}}
configurations:
  hold: [robot, pid]
""")


def test_a_urdf_robot_gives_ndof_to_the_check(tmp_path):
    write(tmp_path, "robots/arm.urdf", two_link_urdf())
    result = check_file(subsystem_with(tmp_path, "{model: robots/arm.urdf, ee: tool}"))
    assert result.ok, [str(e) for e in result.errors]
    assert result.robot_dims == {"NDOF": 2} and result.subsystem.dims["NDOF"] == 2


@pytest.mark.parametrize(("plant", "dims", "code", "where", "message"), [
    ("{model: my_robot.urdf}", "", "E216", (3, 16), "robot file .*my_robot.urdf does not exist"),
    ("{model: puma650}", "", "E216", (3, 16), "plant model 'puma650' is neither a registered robot nor a robot file"),
    ("{model: robots/arm.urdf, ee: wrist}", "", "E217", (3, 37), "end effector 'wrist' is neither a link"),
    ("{model: robots/arm.urdf}", "dims: {NDOF: 6}", "E318", (6, 14),
     r"dim 'NDOF' is 6 here, but the plant's robot 'robots/arm.urdf' has 2 joints \(at .*robot.yaml:3:16\)"),
    ("{model: puma560}", "dims: {NDOF: 7}", "E318", (6, 14), "dim 'NDOF' is 7 here, but the plant's robot 'puma560' has 6"),
])
def test_a_robot_the_check_refuses_is_reported_where_the_fix_goes(tmp_path, plant, dims, code, where, message):
    write(tmp_path, "robots/arm.urdf", two_link_urdf())
    result = check_file(subsystem_with(tmp_path, plant, dims))
    error = next(e for e in result.errors if e.code == code)
    assert (error.line, error.column) == where
    assert re.search(message, error.message), error.message


@pytest.mark.parametrize(("plant", "code"), [("{model: robots/arm.urdf, ee: tool, q0: [0.1]}", "E216"),
                                           ("{model: robots/arm.urdf, ee: wrist}", "E217")])
def test_a_robot_option_the_robot_refuses_is_one_error_as_the_robot_without_it_still_gives_ndof(tmp_path, plant, code):
    write(tmp_path, "robots/arm.urdf", two_link_urdf())
    result = check_file(subsystem_with(tmp_path, plant))
    assert [e.code for e in result.errors] == [code], [str(e) for e in result.errors]  # no "NDOF is not defined" after it


@pytest.mark.multiprocess
def test_your_robot_reaches_its_goal_within_a_milliradian_on_the_simulated_clock(tmp_path):
    config = Path(__file__).resolve().parent.parent / "configs" / "your_robot.yaml"
    run = subprocess.run([sys.executable, "-m", "pbo_runtime.cli", "run", str(config), "--clock", "sim", "--app", "demo",
                          "--out", str(tmp_path / "run"), "--report", str(tmp_path / "report.json")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["jobs_done"] == ["reach", "reach"] and report["faults"] == []
    final, goal = (np.array(report["variables"][name]["value"]) for name in ("q_m", "q_d"))
    np.testing.assert_allclose(goal, [-0.4, -1.6, 1.0, 0.6, -0.5, -0.3])  # the last step's goal
    assert np.max(np.abs(final - goal)) < 1e-3
    assert "dropped meshes MuJoCo cannot read" in run.stdout  # the run says what loading the URDF changed
    [gains] = report["gains"]  # and the gains its bandwidth made
    assert gains.startswith("gains of task 'pid': bandwidth 30 rad/s, damping 1 make kp [") and gains in run.stdout


def test_a_package_registers_a_robot_file_by_name_and_it_loads_like_a_path(tmp_path, monkeypatch):
    import drivers.robots.plant_model as plant_model

    urdf = write(tmp_path, "shipped/arm.urdf", two_link_urdf())
    monkeypatch.setattr(plant_model, "registered_robot", lambda name: urdf if name == "my_arm" else None)
    arm = load_robot("my_arm", Path("/elsewhere"), TIMESTEP, {"ee": "tool"})
    assert arm.joint_names == ("shoulder", "elbow") and arm.source == str(urdf)
