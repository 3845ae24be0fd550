"""A joint's position loop checked before it runs, and the verdict held to the simulated arm.

The analysis (`objects.joint_loop`) against the closed form of the simplest case; `pbo check` on a
UR5 whose wrist the demo's gains make unstable; then runs on the simulated clock: a gain just
inside the bound settles, one just outside swings between its torque limits and is caught by the
robot interface's saturation fault, and gains given as a bandwidth reach their goals on a UR5 and
on a 7-joint arm from a package. A PID inside a combined task is checked as one of its own.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from drivers.robots.plant_model import load_robot
from pbo_runtime import arm_gains, inertia_range
from pbo_runtime.config.loader import check_file
from pbo_runtime.objects.joint_loop import LoopGains, analyse, bandwidth_gains, design_gains, inertias
from pbo_runtime.objects.waits import cycles_meanwhile
from tests.support import PBO, REPO, example_robot

UR5 = example_robot("ur5")
XARM7 = example_robot("xarm7")


@pytest.mark.parametrize("inertia, kp", [(0.01714, 400.0), (0.2, 50.0), (1.5, 3000.0)])
def test_with_no_delay_the_kd_bound_is_the_closed_form_of_a_sampled_double_integrator(inertia, kp):
    period = 0.001  # ZOH, PD on the state: stable for kp T / 2 < kd < 2 I / T
    verdict = analyse(inertia, inertia, LoopGains(kp, 1e6), period, delay=0)
    assert not verdict.stable and verdict.kd_range is not None
    low, high = verdict.kd_range
    assert low == pytest.approx(kp * period / 2, rel=1e-3)
    assert high == pytest.approx(2 * inertia / period, rel=1e-3)


def test_a_period_of_delay_halves_what_a_loop_tolerates():
    inertia, kp = 0.2, 400.0
    at_once = analyse(inertia, inertia, LoopGains(kp, 1e6), 0.001, delay=0).kd_range
    late = analyse(inertia, inertia, LoopGains(kp, 1e6), 0.001, delay=1).kd_range
    assert at_once is not None and late is not None
    assert 0.4 * at_once[1] < late[1] < 0.6 * at_once[1]


@pytest.mark.parametrize("viscous", [0.0, 0.5])
def test_bandwidth_gains_give_the_asked_bandwidth_and_damping_counting_the_joints_friction(viscous):
    gains = bandwidth_gains(0.3, 30.0, 0.7, integral_time=0.5, viscous=viscous)
    assert gains.kp == pytest.approx(0.3 * 30.0 ** 2)
    assert gains.kd + viscous == pytest.approx(2 * 0.7 * 0.3 * 30.0)
    assert gains.ki == pytest.approx(gains.kp / 0.5)


def test_making_gains_from_a_bandwidth_in_a_live_spawns_init_lets_the_due_cycles_run_at_every_inertia_tried():
    # pbo replace of a bandwidth PID on a running arm: its init searches each joint's gains; the other
    # tasks of its RTPU cycle between the steps of that search (one eigenvalue problem), not after all of it
    loaded = load_robot("puma560", REPO, 0.001, {})
    inertia = inertia_range(loaded.arm, loaded.ee)
    design_gains.cache_clear()
    cycle_points: list[float] = []
    with cycles_meanwhile(cycle_points.append):  # the executive's, in a live spawn: here, each is counted
        kp, _, _, _ = arm_gains(inertia, 30.0, 1.0, 0.0, 0.001)
    assert len(cycle_points) >= kp.size * len(inertias(float(inertia.coupled_low[0]), float(inertia.high[0])))
    assert set(cycle_points) == {0}


def test_a_controller_replaced_by_one_of_the_same_bandwidth_finds_its_gains_made():
    loaded = load_robot("puma560", REPO, 0.001, {})
    inertia = inertia_range(loaded.arm, loaded.ee)
    first = arm_gains(inertia, 30.0, 1.0, 0.0, 0.001)
    cycle_points: list[float] = []
    with cycles_meanwhile(cycle_points.append):
        again = arm_gains(inertia, 30.0, 1.0, 0.0, 0.001)
    assert cycle_points == []  # nothing computed: no step to run cycles between
    for made, kept in zip(first, again, strict=True):
        np.testing.assert_array_equal(made, kept)


def test_a_joint_its_friction_overdamps_gets_no_kd_and_its_slow_pole_at_the_bandwidth():
    inertia, bandwidth, viscous = 0.0002, 30.0, 2.0
    gains = bandwidth_gains(inertia, bandwidth, 1.0, viscous=viscous)
    assert gains.kd == 0.0
    slow = (viscous - (viscous ** 2 - 4 * inertia * gains.kp) ** 0.5) / (2 * inertia)  # the smaller root of I s² + b s + kp
    assert slow == pytest.approx(bandwidth, rel=1e-9)


def subsystem(name: str, model: str, goal: list[float], gains: str, start: list[float] | None = None) -> str:
    """A subsystem of the arm under PID with gravity feed-forward, and an application that moves it to
    `goal` (within 1 mrad and still, in 6 s)."""
    start = start or [0.0] * len(goal)
    return f"""
subsystem: {name}
rtpus: [rtpu0, rtpu1]
plant: {{model: "{model}", timestep: 1 ms}}
devices:
  arm: {{driver: mujoco_arm, mode: torque, exclusive: true}}
variables:
  q_d: {{object: joint_position, initial: {start}}}
tasks:
  robot: {{module: robot_torque, rtpu: rtpu1, period: 1 ms, critical: true, resources: [arm]}}
  traj:  {{module: joint_trajectory, rtpu: rtpu0, period: 2 ms, params: {{max_velocity: 0.8, max_acceleration: 2.0}}}}
  pid:   {{module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {gains}}}
configurations:
  joint_pid: [robot, traj, pid]
jobs:
  reach: {{configuration: joint_pid, object: q_d, post: "max(abs(q_m - q_d)) < 1e-3 and max(abs(qd_m)) < 1e-3", timeout: 6 s}}
applications:
  demo:
    - reach: {{q_d: {goal}}}
"""


UR5_START = [0.0, -1.2, 1.2, 0.0, 0.0, 0.0]
UR5_GOAL = [0.5, -1.0, 1.4, -0.4, 0.5, 0.3]
UR5_WRIST = "kp: [2000, 3000, 800, 200, 200, 400], kd: [130, 200, 50, 15, 15, {kd}], gravity_feedforward: true"


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / f"{name}.yaml"
    path.write_text(text)
    return path


def test_pbo_check_names_the_ur5_wrist_the_demo_gains_make_unstable_and_a_kd_that_is_stable(tmp_path):
    path = write(tmp_path, "ur5_demo", subsystem("ur5_demo_gains", UR5, UR5_GOAL,
                                                 "{kp: 400, kd: 40, ki: 10, gravity_feedforward: true}", UR5_START))
    result = check_file(path)
    [error] = result.errors
    assert error.code == "E326"
    assert path.read_text().splitlines()[error.line - 1][error.column - 1:].startswith("40, ki: 10")  # at the kd
    assert "joint 6 (wrist_3_joint)" in error.message and "kp 400, kd 40, ki 10" in error.message
    assert "inertia 0.01592 kg m² (from 0.01592 with the other joints free to 0.01714 kg m² over the workspace)" in error.message
    assert error.hint.startswith("stable for kd < 15.7")


TRAJECTORY_MEMBER = "{module: joint_trajectory, params: {max_velocity: 0.8, max_acceleration: 2.0}}"


def combined_subsystem(gains: str, first: str = TRAJECTORY_MEMBER, pid_ports: str = "{}") -> str:
    """The UR5 subsystem with `first` (a trajectory from the goal q_d) and a PID as the members of one combined task, `ctl`."""
    return f"""
subsystem: ur5_combined
rtpus: [rtpu0, rtpu1]
plant: {{model: "{UR5}", timestep: 1 ms}}
devices:
  arm: {{driver: mujoco_arm, mode: torque, exclusive: true}}
variables:
  q_d: {{type: float64, shape: [NDOF], initial: {UR5_GOAL}}}
tasks:
  robot: {{module: robot_torque, rtpu: rtpu1, period: 1 ms, critical: true, resources: [arm]}}
  ctl:   {{module: combined, rtpu: rtpu0, period: 1 ms, params: {{members: [
            {first},
            {{module: pid_joint, params: {{{gains}}}, ports: {pid_ports}}}]}}}}
configurations:
  joint_pid: [robot, ctl]
"""


@pytest.mark.parametrize("gains, code, at, said", [
    ("kp: 400, kd: 40, ki: 10, gravity_feedforward: true", "E326", "40, ki: 10",
     "the position loop of joint 6 (wrist_3_joint) under member 2 (pid_joint) of task 'ctl' (kp 400, kd 40, ki 10) is unstable"),
    (UR5_WRIST.format(kd=1.0), "W301", "1.0]",
     "the position loop of joint 6 (wrist_3_joint) under member 2 (pid_joint) of task 'ctl' (kp 400, kd 1) rings"),
    ("bandwidth: 30, kp: 400, gravity_feedforward: true", "E325", "400,",
     "member 2 (pid_joint) of task 'ctl' gives both a bandwidth and raw gains (kp)"),
])
def test_a_pid_inside_a_combined_task_is_checked_at_its_gain_like_a_task_of_its_own(tmp_path, gains, code, at, said):
    path = write(tmp_path, "ur5_combined", combined_subsystem(gains))
    result = check_file(path)
    [found] = result.errors + result.warnings
    assert found.code == code and found.message.startswith(said), found.format()
    assert path.read_text().splitlines()[found.line - 1][found.column - 1:].startswith(at)  # at the member's gain
    if code == "E326":
        assert found.hint.startswith("stable for kd < 15.7")


def test_a_pid_inside_a_combined_task_given_a_bandwidth_checks_clean_and_says_its_gains(tmp_path):
    result = check_file(write(tmp_path, "ur5_combined",
                              combined_subsystem("bandwidth: 30, damping: 1.0, gravity_feedforward: true")))
    assert not result.errors and not result.warnings, [e.format() for e in result.errors + result.warnings]
    assert any(note.startswith("gains of task 'ctl', member 2 (pid_joint): bandwidth 30 rad/s, damping 1 make kp [")
               for note in result.robot_notes), result.robot_notes


def test_a_pid_inside_a_combined_task_that_reads_its_goal_directly_is_warned_of_the_torque_the_step_asks(tmp_path):
    path = write(tmp_path, "ur5_combined", combined_subsystem(
        UR5_WRIST.format(kd=10), first="{module: differentiator, ports: {z: q_d, zd: qd_r}}", pid_ports="{q_r: q_d}"))
    result = check_file(path)
    assert not result.errors, [e.format() for e in result.errors]
    warned = [w for w in result.warnings if w.code == "W302"]
    assert len(warned) == 6, [w.format() for w in result.warnings]  # every joint: the plant starts at zero
    assert warned[1].message == ("the goal of joint 2 (shoulder_lift_joint) is 1 from the start: member 2 (pid_joint) of task "
                                 "'ctl' asks kp 3000 x 1 = 3000 at once, past the effort limit 150")


def wrist_bound() -> float:
    robot = load_robot(UR5, Path(REPO), 0.001, {})
    inertia = inertia_range(robot.arm, robot.ee)
    verdict = analyse(float(inertia.coupled_low[5]), float(inertia.high[5]), LoopGains(400.0, 1e6), 0.001, delay=1)
    assert verdict.kd_range is not None
    return verdict.kd_range[1]


def run_demo(path: Path, cwd: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([*PBO, "run", str(path), "--app", "demo", "--clock", "sim", "--no-live", "--out", str(cwd / "run"),
                           *extra], capture_output=True, text=True, cwd=cwd, timeout=300)


@pytest.mark.multiprocess
def test_the_verdict_agrees_with_the_simulated_arm_on_either_side_of_the_bound(tmp_path):
    bound = wrist_bound()
    inside = write(tmp_path, "inside", subsystem("ur5_kd_inside", UR5, UR5_GOAL, "{" + UR5_WRIST.format(kd=0.85 * bound) + "}",
                                                 UR5_START))
    outside = write(tmp_path, "outside", subsystem("ur5_kd_outside", UR5, UR5_GOAL, "{" + UR5_WRIST.format(kd=1.15 * bound) + "}",
                                                   UR5_START))
    assert not check_file(inside).errors
    assert [e.code for e in check_file(outside).errors] == ["E326"]
    settled = run_demo(inside, tmp_path)
    assert settled.returncode == 0 and "fault:" not in settled.stderr, settled.stdout + settled.stderr
    assert "job 'reach' (step 1 of 1 of application 'demo'): done" in settled.stdout
    refused = subprocess.run([*PBO, "run", str(outside), "--clock", "sim"], capture_output=True, text=True,
                             cwd=tmp_path, timeout=120)
    assert refused.returncode == 1 and "E326" in refused.stderr
    diverged = run_demo(outside, tmp_path, "--allow-unstable-loops")  # the wrist swings from one torque limit to the other
    assert diverged.returncode == 2, diverged.stdout + diverged.stderr
    [fault] = [line for line in diverged.stderr.splitlines() if line.startswith("fault:")]
    assert fault.startswith("fault: joint 6: the torque command 'tau_u' kept coming back to its effort limit of ±28 N m"), fault
    assert fault.endswith("(robot interface 'robot'; its 'tau_u' was written by task 'pid')"), fault


@pytest.mark.multiprocess
@pytest.mark.parametrize("name, model, goal, start", [
    ("ur5_bandwidth", UR5, UR5_GOAL, UR5_START),
    ("xarm7_bandwidth", XARM7, [0.5, 0.3, -0.4, 0.8, 0.5, 0.4, 0.3], [0.0, 0.0, 0.0, 0.5, 0.0, 0.5, 0.0]),
    # seven joints and two fingers; its first and third joints turn about one axis when upright
    ("panda_bandwidth", example_robot("panda"), [0.5, 0.3, -0.4, -1.2, 0.5, 1.4, 0.3, 0.02, 0.02],
     [0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0, 0.02, 0.02]),
])
def test_a_bandwidth_of_30_rad_s_checks_clean_and_reaches_its_goal_within_a_milliradian_in_6_s(tmp_path, name, model, goal,
                                                                                                start):
    path = write(tmp_path, name, subsystem(name, model, goal, "{bandwidth: 30, damping: 1.0, gravity_feedforward: true}", start))
    result = check_file(path)
    assert not result.errors and not result.warnings, [e.format() for e in result.errors + result.warnings]
    assert any(note.startswith("gains of task 'pid': bandwidth 30 rad/s, damping 1 make kp [") for note in result.robot_notes)
    done = run_demo(path, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "job 'reach' (step 1 of 1 of application 'demo'): done" in done.stdout


def test_pbo_status_says_the_gains_a_bandwidth_made_and_only_those(tmp_path):
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.supervisor.commands import dispatch
    from tests.fake_job_host import FakeJobHost

    text = (Path(REPO) / "configs" / "switch_joint.yaml").read_text().replace(
        "params: {kp: 600, kd: 50, ki: 0, gravity_feedforward: true}", "params: {bandwidth: 20, gravity_feedforward: true}")
    path = write(tmp_path, "switch_joint", text)
    reply = dispatch(FakeJobHost(load_subsystem(str(path))), "status", {})
    [gains] = reply["gains"]
    assert gains.startswith("gains of task 'pd': bandwidth 20 rad/s, damping 1 make kp [")
