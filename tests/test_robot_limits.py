"""The robot's limits: where they come from, the robot interface clipping every command to them,
and divergence (a saturated command, a joint past its velocity limit or its range) as a fault
that brakes the arm and ends the run's summary with a `fault:` line.

The interface runs as a real Task on a real table over an in-process MuJoCo plant stepped by
hand, one plant step per cycle, so what reaches the plant is read from its registers.
"""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.mujoco_arm.driver import MujocoArmDriver
from drivers.mujoco_arm.plant import MujocoArmPlant
from modules._robot_limits import DRAIN_SLOWER, SATURATION_BOUND, VELOCITY_TOLERANCE, ArmLimits
from modules.robot_position import RobotPosition
from modules.robot_torque import RobotTorque
from pbo_runtime import Arm, ParamError, Status
from pbo_runtime.config.loader import check_file
from pbo_runtime.config.model import DeviceSpec, TaskSpec
from pbo_runtime.table.table import StateTable, TaskState
from pbo_runtime.task.lifecycle import Task
from tests.support import NO_WATCHDOG, PBO, arm_constants, arm_tables, demo_copy, task_spec, unique_name, variables

TIMESTEP = 0.001
PUMA_EFFORT = np.array([97.6, 186.4, 89.4, 24.2, 20.1, 21.3])


# --- the limit arrays and their checks, on an ARM table -----------------------------------------------


def limits_of(model: str, period: float = TIMESTEP, position_tolerance: float = 0.02) -> ArmLimits:
    arm, _ = arm_tables(model)
    return ArmLimits(arm, period, SATURATION_BOUND, position_tolerance)


def test_a_torque_past_the_effort_limit_is_clipped_to_it_and_counted_while_it_stays_there():
    limits = limits_of("puma560")
    asked = np.array([1e6, -1e6, 10.0, -10.0, 20.1, 0.0])
    out = np.zeros(6)
    for cycle in range(1, 4):
        assert limits.saturate_torque(asked, out)
        np.testing.assert_array_equal(out, [97.6, -186.4, 10.0, -10.0, 20.1, 0.0])
        np.testing.assert_array_equal(limits.at_limit, [cycle, cycle, 0, 0, cycle, 0])  # at the limit, either sign, counts
    np.testing.assert_array_equal(limits.saturation_count, [6, 6, 0, 0, 6, 0])
    for drained in range(1, 7):  # back within: each count drains, DRAIN_SLOWER times slower than it rose
        assert not limits.saturate_torque(np.zeros(6), out)
        np.testing.assert_array_equal(limits.saturation_count, [6 - drained, 6 - drained, 0, 0, 6 - drained, 0])
    np.testing.assert_array_equal(limits.at_limit, 0)  # every count at 0: the next saturation is counted afresh
    assert not limits.saturate_torque(np.zeros(6), out)
    np.testing.assert_array_equal(limits.saturation_count, 0)  # never below 0


def test_a_torque_saturated_past_the_bound_is_divergence_and_not_before():
    limits = limits_of("puma560")
    asked, out = np.full(6, 1e6), np.zeros(6)
    allowed = limits.saturated_cycles_allowed
    assert allowed == round(SATURATION_BOUND / TIMESTEP)
    for _ in range(allowed):
        limits.saturate_torque(asked, out)
        assert not limits.saturated_too_long()
    limits.saturate_torque(asked, out)
    assert limits.saturated_too_long()
    message = limits.saturation_message(asked, "tau_u", TIMESTEP, allowed * TIMESTEP)
    assert message.startswith("joint 1: the torque command 'tau_u' stayed at its effort limit of 97.6 N m for 51 ms")


def limit_cycle(at_limit: int, within: int, cycles: int) -> Iterator[np.ndarray]:
    """Joint 6's torque at its limit `at_limit` cycles of every `at_limit + within`, its sign turning
    each time it comes back (the others at rest)."""
    tau = np.zeros(6)
    for k in range(cycles):
        phase, swing = k % (at_limit + within), k // (at_limit + within)
        tau[5] = (-1) ** swing * (40.0 if phase < at_limit else 10.0)
        yield tau


@pytest.mark.parametrize("at_limit, within", [(2, 1), (1, 1)])
def test_a_torque_that_keeps_coming_back_to_its_limit_in_either_direction_is_divergence(at_limit, within):
    limits = limits_of("puma560")
    out = np.zeros(6)
    for k, tau in enumerate(limit_cycle(at_limit, within, 2000)):
        if limits.saturate_torque(tau, out, k * TIMESTEP) and limits.saturated_too_long():
            break
    else:
        pytest.fail("the limit cycle was never caught")
    swing, net = at_limit + within, DRAIN_SLOWER * at_limit - within  # what each swing adds to the count
    assert k + 1 <= swing * math.ceil((limits.saturated_cycles_allowed + 1) * DRAIN_SLOWER / net)  # once past the bound's worth
    message = limits.saturation_message(tau, "tau_u", TIMESTEP, k * TIMESTEP)
    held, span = limits.at_limit[5], k + 1
    assert message.startswith(f"joint 6: the torque command 'tau_u' kept coming back to its effort limit of ±21.3 N m: at it "
                              f"{held} ms of the last {span} ms, past the saturation bound of 50 ms"), message
    assert held == pytest.approx(span * at_limit / swing, abs=at_limit)


def test_a_torque_at_its_limit_one_cycle_in_three_is_never_divergence():
    limits = limits_of("puma560")
    out = np.zeros(6)
    for tau in limit_cycle(1, DRAIN_SLOWER, 5000):  # what a cycle at the limit adds, the cycles within take off
        limits.saturate_torque(tau, out)
        assert not limits.saturated_too_long()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_command_that_is_not_finite_is_never_clipped_and_reaches_the_driver_to_be_refused(bad):
    limits = limits_of("puma560")
    out = np.zeros(6)
    tau = np.full(6, 1e6)
    tau[2] = bad
    assert not limits.saturate_torque(tau, out)
    np.testing.assert_array_equal(out, tau)
    np.testing.assert_array_equal(limits.saturation_count, 0)
    limits.limit_position(tau, np.zeros(6), np.full(6, 0.001), out)
    np.testing.assert_array_equal(out, tau)


@pytest.mark.parametrize(("joint", "q_offset", "qd", "fault"), [
    (3, 0.0, 1.0, None),  # within: joint 4's limit is 1.309 rad/s
    (3, 0.0, np.radians(75) * (1 + VELOCITY_TOLERANCE) * 0.999, None),  # past the limit, within the tolerance
    (3, 0.0, -1.5, "joint 4: measured velocity -1.5 rad/s is past its limit of 1.309 rad/s (tolerance 10%)"),
    (1, 0.019, 0.0, None),  # joint 2 past its range by less than the tolerance
    (1, 0.021, 0.0, "joint 2: measured position 2.115 rad is past its range [-2.094, 2.094] rad"),
    (6, -0.03, 0.0, "joint 7: measured position -3.084 rad is past its range [-3.054, 3.054] rad"),
])
def test_a_joint_past_its_velocity_limit_or_range_is_divergence(joint, q_offset, qd, fault):
    limits = limits_of("redundant7")
    arm, _ = arm_tables("redundant7")
    q, qdot = np.zeros(7), np.zeros(7)
    q[joint] = (arm[joint, Arm.Q_MAX] + q_offset) if q_offset > 0 else (arm[joint, Arm.Q_MIN] + q_offset if q_offset < 0 else 0.0)
    qdot[joint] = qd
    assert limits.outside(q, qdot) is (fault is not None)
    if fault is not None:
        assert limits.divergence_message(q, qdot).startswith(fault)


def test_a_joint_without_a_velocity_limit_or_range_never_diverges():
    arm = arm_tables("puma560")[0].copy()  # no velocity limits
    arm[0, Arm.LIMITED] = 0.0
    limits = ArmLimits(arm, TIMESTEP, SATURATION_BOUND, 0.02)
    q, qd = np.zeros(6), np.zeros(6)
    q[0], qd[:] = 1e3, 1e3
    q[1:] = 0.1
    assert not limits.outside(q, qd)


def test_a_position_command_stays_in_range_and_moves_at_most_the_velocity_limit_a_period():
    limits = limits_of("redundant7")
    step = limits.velocity * TIMESTEP
    previous, out = np.zeros(7), np.zeros(7)
    limits.limit_position(np.full(7, 10.0), previous, step, out)
    np.testing.assert_allclose(out, step)
    previous = limits.q_max - 1e-4
    limits.limit_position(np.full(7, 10.0), previous, step, out)
    np.testing.assert_array_equal(out, limits.q_max)


def test_the_checks_allocate_nothing():
    from tests.support import allocation_peak

    limits = limits_of("redundant7")
    tau, out, q, qd = np.full(7, 1e6), np.zeros(7), np.zeros(7), np.zeros(7)
    step = limits.velocity * TIMESTEP

    def cycle() -> None:
        limits.outside(q, qd)
        limits.saturate_torque(tau, out, 0.5)
        limits.saturated_too_long()
        limits.saturate_torque(q, out, 0.5)  # within: the counts drain
        limits.limit_position(q, out, step, out)

    assert allocation_peak(cycle) == 0


# --- the robot interface over the plant ---------------------------------------------------------------


@pytest.fixture
def plant(request) -> Iterator[MujocoArmPlant]:
    model, options = getattr(request, "param", ("puma560", {}))
    made = MujocoArmPlant(unique_name("plant"), model, TIMESTEP, {**NO_WATCHDOG, **options})
    try:
        yield made
    finally:
        made.close()


def robot_task(make_table, plant: MujocoArmPlant, module: type = RobotTorque, params: dict | None = None,
               ) -> tuple[Task, StateTable, list[MujocoArmDriver]]:
    n = plant.ndof
    command = ("tau_u",) if module is RobotTorque else ("q_r",)
    table = make_table(variables(*arm_constants(n), ("q_m", "float64", (n,)), ("qd_m", "float64", (n,)),
                                 (command[0], "float64", (n,))))
    opened: list[MujocoArmDriver] = []
    mode = "torque" if module is RobotTorque else "position"

    def opener(spec: DeviceSpec, _task: TaskSpec) -> MujocoArmDriver:
        opened.append(MujocoArmDriver(plant.name, spec.options))
        return opened[-1]

    dims = {"NDOF": n}
    spec = dataclasses.replace(task_spec(module, dims=dims, period=TIMESTEP, params=params), resources=("arm",))
    task = Task(spec, module, table, dims, devices={"arm": DeviceSpec("arm", "mujoco_arm", True, {"mode": mode})}, opener=opener)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    return task, table, opened


def drive(task: Task, table: StateTable, plant: MujocoArmPlant, variable: str, value: np.ndarray, cycles: int,
          seen: list[np.ndarray]) -> Status:
    """Cycles of the task, each followed by one plant step, with `value` written to `variable`; `seen`
    gets what the plant's command register held at each step. The first status that is not CONTINUE."""
    registers = plant._registers.tau if variable == "tau_u" else plant._registers.q_cmd
    for k in range(1, cycles + 1):
        table.write(variable, value, when=k * TIMESTEP)
        status = task.run_cycle(k * TIMESTEP)
        if status is not Status.CONTINUE:
            return status
        seen.append(registers.copy())
        plant.step()
    return Status.CONTINUE


def test_a_controller_asking_1e6_n_m_never_reaches_the_plant_and_the_arm_is_braked_after_the_bound(make_table, plant):
    task, table, opened = robot_task(make_table, plant)
    seen: list[np.ndarray] = []
    status = drive(task, table, plant, "tau_u", np.full(6, 1e6), 1000, seen)
    assert status is Status.ERROR and task.state is TaskState.ERROR
    assert len(seen) == round(SATURATION_BOUND / TIMESTEP)  # every cycle up to the bound commanded, clipped
    np.testing.assert_array_equal(np.abs(np.array(seen)).max(axis=0), PUMA_EFFORT)  # never past the effort limit
    assert "joint 1: the torque command 'tau_u' stayed at its effort limit of 97.6 N m for 51 ms" in task.last_error
    assert opened[0].brakes_engaged
    assert opened[0].figures()["command"] == "tau_u" and "effort limit" in opened[0].figures()["fault"]


def test_the_brakes_hold_the_arm_after_a_divergence(make_table, plant):
    task, table, _ = robot_task(make_table, plant)
    drive(task, table, plant, "tau_u", np.full(6, 1e6), 1000, [])
    moving = plant.data.qvel.copy()
    assert np.abs(moving).max() > 1.0  # 50 ms at full torque: the arm was moving fast
    plant.step()
    held = plant.data.qpos.copy()
    for _ in range(500):
        plant.step()
    assert plant.brakes_engaged
    np.testing.assert_array_equal(plant.data.qpos, held)
    np.testing.assert_array_equal(plant.data.qvel, 0.0)


@pytest.mark.parametrize("plant", [("redundant7", {"velocity_limits": [0.05] * 7})], indirect=True)
def test_a_joint_past_its_velocity_limit_brakes_the_arm(make_table, plant):
    task, table, opened = robot_task(make_table, plant)
    status = drive(task, table, plant, "tau_u", np.zeros(7), 1000, [])  # no torque: it falls under gravity
    assert status is Status.ERROR
    assert "measured velocity" in task.last_error and "past its limit of 0.05 rad/s" in task.last_error
    assert opened[0].brakes_engaged


def test_a_joint_past_its_range_brakes_the_arm(make_table, plant):
    task, table, _opened = robot_task(make_table, plant, params={"position_tolerance": 0.0})
    push = np.zeros(6)
    push[4] = 15.0  # joint 5 towards its upper limit, within its effort limit
    status = drive(task, table, plant, "tau_u", push, 3000, [])
    assert status is Status.ERROR
    assert "joint 5: measured position" in task.last_error and "past its range [-1.745, 1.745] rad" in task.last_error


def test_after_a_range_fault_the_arm_may_be_driven_back_but_not_further_out(make_table, plant):
    task, table, _ = robot_task(make_table, plant, params={"position_tolerance": 0.0})
    push = np.zeros(6)
    push[4] = 15.0
    assert drive(task, table, plant, "tau_u", push, 3000, []) is Status.ERROR  # joint 5 past its upper limit
    for _ in range(100):  # the brakes hold it there until the operator comes
        plant.step()
    assert plant.data.qpos[4] > 1.745
    assert task.clear() and task.turn_on(0.0), task.last_error  # the operator's clear, then on: braked past the range
    back = np.zeros(6)
    back[4] = -5.0
    assert drive(task, table, plant, "tau_u", back, 200, []) is Status.CONTINUE  # driven back: no fault
    assert plant.data.qpos[4] < 1.745
    task.turn_off()
    assert task.turn_on(0.0), task.last_error
    assert drive(task, table, plant, "tau_u", push, 3000, []) is Status.ERROR  # out again past the range: a fault again


@pytest.mark.parametrize("plant", [("redundant7", {})], indirect=True)
def test_a_position_command_reaches_the_plant_within_range_and_at_most_the_velocity_limit_a_period(make_table, plant):
    task, table, _ = robot_task(make_table, plant, module=RobotPosition)
    seen: list[np.ndarray] = []
    assert drive(task, table, plant, "q_r", np.full(7, 10.0), 200, seen) is Status.CONTINUE
    commands = np.array([plant.robot.q0, *seen])
    arm, _ = arm_tables("redundant7")
    assert np.all(np.abs(np.diff(commands, axis=0)) <= arm[:, Arm.VELOCITY] * TIMESTEP + 1e-12)
    assert np.all(commands <= arm[:, Arm.Q_MAX])


@pytest.mark.parametrize(("module", "command", "value"), [(RobotTorque, "tau_u", 10.0), (RobotTorque, "tau_u", 1e6),
                                                        (RobotPosition, "q_r", 0.1)])
def test_a_robot_interface_cycle_with_its_limits_allocates_no_array(make_table, plant, module, command, value):
    from tests.support import allocation_peak, one_array

    task, table, _ = robot_task(make_table, plant, module=module)
    table.write(command, np.full(plant.ndof, value), when=TIMESTEP)
    assert task.run_cycle(TIMESTEP) is Status.CONTINUE, task.last_error
    assert allocation_peak(task.module.cycle, times=20) < one_array()  # 41 cycles saturated: within the bound


# --- where the limits come from: pbo check -------------------------------------------------------------


def subsystem(folder: Path, plant: str) -> Path:
    path = folder / "limits.yaml"
    path.write_text(f"""subsystem: limits
rtpus: [rtpu0]
plant: {plant}
devices:
  arm: {{driver: mujoco_arm, mode: torque, exclusive: true}}
variables:
  q_d: {{type: float64, shape: [NDOF], initial: 0}}
tasks:
  robot: {{module: robot_torque, rtpu: rtpu0, period: 1 ms, critical: true, resources: [arm]}}
  pid:   {{module: pid_joint, rtpu: rtpu0, period: 1 ms, params: {{kp: 10, kd: 1}}, ports: {{tau: tau_u, q_r: q_d, qd_r: qd_m}}}}
configurations:
  hold: [robot, pid]
""")
    return path


def test_check_shows_the_limits_of_a_built_in_robot(tmp_path):
    result = check_file(subsystem(tmp_path, "{model: redundant7}"))
    assert result.ok, [str(e) for e in result.errors]
    assert [row["effort"] for row in result.robot_limits] == [320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0]
    assert result.robot_limits[3]["velocity"] == pytest.approx(np.radians(75))
    assert result.robot_limits[1]["lower"] == pytest.approx(np.radians(-120))


def test_a_plant_option_may_tighten_a_limit(tmp_path):
    result = check_file(subsystem(tmp_path, "{model: puma560, torque_limits: [50, 50, 50, 20, 20, 20], "
                                            "velocity_limits: [1, 1, 1, 2, 2, 2]}"))
    assert result.ok, [str(e) for e in result.errors]
    assert [row["effort"] for row in result.robot_limits] == [50, 50, 50, 20, 20, 20]
    assert [row["velocity"] for row in result.robot_limits] == [1, 1, 1, 2, 2, 2]  # puma560 gives none: the option gives them


def test_a_plant_option_may_narrow_a_joint_range_and_the_arm_table_carries_it(tmp_path):
    ranges = [[-1, 1], [-0.5, 3], [-3, 0.5], [-1, 2], [-1, 1], [-4, 4]]
    result = check_file(subsystem(tmp_path, f"{{model: puma560, joint_limits: {ranges}}}"))
    assert result.ok, [str(e) for e in result.errors]
    assert [[row["lower"], row["upper"]] for row in result.robot_limits] == ranges
    with MujocoArmPlant(unique_name("plant"), "puma560", TIMESTEP, {**NO_WATCHDOG, "joint_limits": ranges}) as plant:
        arm = plant.robot.arm
        np.testing.assert_array_equal(arm[:, [Arm.Q_MIN, Arm.Q_MAX]], ranges)
        np.testing.assert_array_equal(plant.model.jnt_range, ranges)  # the simulated joint stops too


@pytest.mark.parametrize(("option", "message", "hint"), [
    ("torque_limits: [97.6, 300, 89.4, 24.2, 20.1, 21.3]", r"torque_limits would widen .* joint2 \(300 > 186.4 N m\)",
     "give at most the robot's own: [97.6, 186.4, 89.4, 24.2, 20.1, 21.3]"),
    ("torque_limits: [98, 186.4, 89.4, 24.2, 20.1, 21.3]", r"torque_limits would widen .* joint1 \(98 > 97.6 N m\)",
     "give at most the robot's own: [97.6, 186.4, 89.4, 24.2, 20.1, 21.3]"),
    ("joint_limits: [[-1, 1], [-1, 1], [-1, 1], [-1, 1], [-1, 1], [-5, 1]]",
     r"joint_limits would widen the range .* joint6 \(\[-5, 1\] past \[-4.643, 4.643\]\)",
     "give each joint a range within the robot's own (pbo check lists them)"),
])
def test_a_plant_option_that_would_widen_a_limit_is_an_error_at_its_line(tmp_path, option, message, hint):
    import re

    result = check_file(subsystem(tmp_path, f"{{model: puma560, {option}}}"))
    error = next(e for e in result.errors if e.code == "E216")
    assert (error.line, error.column) == (3, len("plant: {model: puma560, ") + option.index(":") + 3)  # at its value
    assert re.search(message, error.message), error.message
    assert error.hint == hint


@pytest.mark.parametrize(("writer", "said"), [("ctl", "task 'ctl'"), ("job control", "job control"), ("", "no task")])
def test_a_divergence_line_names_the_writer_of_the_variable_the_command_port_reads(writer, said):
    from pbo_runtime.supervisor.run_report import divergence_lines

    spec = task_spec(RobotTorque, name="arm_if", ports={"tau_u": "tau_cmd"}, dims={"NDOF": 6})
    figures = {"faults": [{"fault": "joint 2: it diverged; the arm is braked", "command": "tau_u", "at": 12.5}]}
    writers = {"tau_cmd": writer} if writer else {}
    assert divergence_lines("arm_if", spec, figures, writers, 10.0) == [
        f"joint 2: it diverged; the arm is braked at 2.500 s into the run (robot interface 'arm_if'; its 'tau_cmd' was "
        f"written by {said})"]


# --- a whole run ------------------------------------------------------------------------------------------


@pytest.mark.multiprocess
def test_a_run_whose_controller_asks_1e6_n_m_ends_with_a_fault_naming_the_joint_and_the_task(tmp_path):
    config = demo_copy(tmp_path, "limits1e6", pid={"module": "fault_injector", "params": {"command": 1.0e6},
                                                   "ports": {"command": "tau_u"}})
    report = tmp_path / "report.json"
    run = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--duration", "0.5", "--out", str(tmp_path / "run"),
                          "--report", str(report)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 2, run.stdout + run.stderr
    faults = json.loads(report.read_text())["faults"]
    assert len(faults) == 1, faults  # told once: not again as a task left in ERROR
    assert faults[0].startswith("joint 1: the torque command 'tau_u' stayed at its effort limit of 97.6 N m"), faults
    assert faults[0].endswith("(robot interface 'robot'; its 'tau_u' was written by task 'pid')"), faults
    assert "fault: joint 1: the torque command 'tau_u'" in run.stderr, run.stderr
    assert "Traceback" not in run.stdout + run.stderr


def test_the_injector_command_refuses_a_number_that_is_not_finite():
    from modules.fault_injector import FaultInjectorParams

    with pytest.raises(ValueError, match="command must be a finite number"):
        FaultInjectorParams(command=float("inf"))


@pytest.mark.parametrize("module", [RobotTorque, RobotPosition])
def test_a_robot_interface_refuses_a_negative_position_tolerance_naming_its_range(module):
    with pytest.raises(ParamError, match=r"position_tolerance must be in \[0, 1\], got: -1"):
        module.build_params({"position_tolerance": -1.0})

