"""Computed torque checked before it runs: a PID whose acceleration feeds inverse dynamics.

The model cancels each joint's inertia, so the PID's gains act on a unit inertia; the delay between
the two is what the file makes it (none when the inverse dynamics runs after the PID in the same
cycle, a period otherwise). The analysis against the closed form; `pbo check` on the shipped
files that use computed torque (no error, no warning of a loop) and on variants of them; then the
verdict held to the simulated arm: the same gains settle with the PID ahead and diverge with the
inverse dynamics a period late, and a kd either side of the bound does as the check said.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from pbo_runtime.config.loader import check_file
from pbo_runtime.objects.joint_loop import LoopGains, analyse
from tests.support import PBO, REPO

SHIPPED = sorted(p.name for p in (REPO / "configs").glob("*.yaml") if "inverse_dynamics" in p.read_text())
LOOP_CODES = ("E326", "W301", "W302")
GAINS = "kp: 2500, kd: 100, ki: 0"  # the shipped PID's, in both of computed_torque.yaml's configurations


def test_the_shipped_files_with_inverse_dynamics_are_the_ones_this_file_checks():
    assert SHIPPED == ["cartesian_teleop.yaml", "combined_modules.yaml", "computed_torque.yaml"]


@pytest.mark.parametrize("name", SHIPPED)
def test_a_shipped_file_with_computed_torque_checks_with_no_error_and_no_loop_warning(name):
    result = check_file(REPO / "configs" / name)
    found = [e.format() for e in result.errors + result.warnings if e.code in LOOP_CODES or e.severity == "error"]
    assert found == []


@pytest.mark.parametrize("inertia", [0.01, 0.2, 5.0])
def test_under_computed_torque_any_inertia_is_a_unit_one_and_the_kd_bound_is_the_closed_form(inertia):
    period, kp = 0.001, 2500.0  # ZOH, PD on a unit inertia, no delay: stable for kp T / 2 < kd < 2 / T
    verdict = analyse(inertia, inertia, LoopGains(kp, 1e6), period, delay=0, computed_torque=True)
    assert verdict.kd_range is not None
    assert verdict.kd_range[0] == pytest.approx(kp * period / 2, rel=1e-3)
    assert verdict.kd_range[1] == pytest.approx(2 / period, rel=1e-3)


def variant(folder: Path, gains: str = GAINS, *, id_first: bool = False, id_rtpu: str = "rtpu0",
            members_swapped: bool = False) -> Path:
    """configs/computed_torque.yaml with the PID's `gains` in both configurations; `id_first`: task `id`
    declared (so spawned, so run) before `pid`; `members_swapped`: inverse dynamics first in `ctc`."""
    text = (REPO / "configs" / "computed_torque.yaml").read_text().replace(GAINS, gains)
    text = text.replace("id:    {module: inverse_dynamics, rtpu: rtpu0", f"id:    {{module: inverse_dynamics, rtpu: {id_rtpu}")
    lines = text.splitlines()
    if id_first:
        at_id = next(i for i, line in enumerate(lines) if line.startswith("  id:"))
        at_pid = next(i for i, line in enumerate(lines) if line.startswith("  pid:"))
        lines.insert(at_pid, lines.pop(at_id))
    text = "\n".join(lines) + "\n"
    if members_swapped:
        pid_member = next(line for line in lines if line.lstrip().startswith("{module: pid_joint"))
        text = text.replace(pid_member + "\n", "").replace("            {module: inverse_dynamics}]}}",
                                                           "            {module: inverse_dynamics},\n"
                                                           + pid_member.rstrip(",") + "]}}")
    path = folder / "computed_torque.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("who", [
    "task 'pid' (kp 2500, kd 1500) through the inverse dynamics of task 'id'",
    "member 1 (pid_joint) of task 'ctc' (kp 2500, kd 1500) through the inverse dynamics of member 2 (inverse_dynamics) "
    "of task 'ctc'",
])
def test_a_kd_too_high_for_a_unit_inertia_is_an_error_at_the_gain_with_the_bound_in_accelerations(tmp_path, who):
    path = variant(tmp_path, "kp: 2500, kd: 1500")
    result = check_file(path)
    [error] = [e for e in result.errors if who in e.message and "joint 6 (joint6)" in e.message]
    assert error.code == "E326"
    assert error.message == (f"the position loop of joint 6 (joint6) under {who} is unstable as a unit inertia (computed "
                             "torque cancels its 0.1941 to 0.1941 kg m², not its viscous friction), sampled every 1 ms "
                             "with one period of delay: a pole at |z| = 1.22 > 1")
    assert error.hint.startswith("stable for kd < 999.3 (at kp 2500)") and "the gains are accelerations" in error.hint
    assert path.read_text().splitlines()[error.line - 1][error.column - 1:].startswith("1500")  # at the kd


def test_a_kd_too_low_for_a_unit_inertia_rings(tmp_path):
    result = check_file(variant(tmp_path, "kp: 2500, kd: 3"))
    assert not result.errors
    assert {w.code for w in result.warnings} == {"W301"} and len(result.warnings) == 12  # 6 joints, 2 controllers
    assert "rings: damping ratio 0.00 < 0.3 as a unit inertia" in result.warnings[0].message


@pytest.mark.parametrize("change, task, why", [
    ({"id_first": True}, "task 'pid'", "task 'id' reads 'qdd_r' of the cycle before: it comes before 'pid' in the init order, "
                                       "so runs first"),
    ({"id_rtpu": "rtpu1"}, "task 'pid'", "task 'id' reads 'qdd_r' of the cycle before: it runs on another RTPU"),
    ({"members_swapped": True}, "member 2 (pid_joint) of task 'ctc'",
     "member 1 (inverse_dynamics) of task 'ctc' reads 'qdd_r' of the cycle before: it is listed before the controller, "
     "so runs first"),
])
def test_inverse_dynamics_that_reads_the_pids_acceleration_a_period_late_costs_a_period_of_delay(tmp_path, change, task, why):
    # kd 700 at kp 2500: stable with one period of delay (below 999), not with two (above 616)
    assert analyse(1, 1, LoopGains(2500, 700), 0.001, 1).stable and not analyse(1, 1, LoopGains(2500, 700), 0.001, 2).stable
    result = check_file(variant(tmp_path, "kp: 2500, kd: 700", **change))
    late = [e for e in result.errors if e.message.startswith(f"the position loop of joint 1 (joint1) under {task}")]
    assert [e.code for e in late] == ["E326"], [e.format() for e in result.errors]
    assert f"sampled every 1 ms with 2 periods of delay ({why}): a pole at" in late[0].message
    assert all(task not in e.message for e in result.errors if e is not late[0] and "joint 1 " in e.message)


def test_the_same_kd_with_the_pid_ahead_of_the_inverse_dynamics_is_stable(tmp_path):
    result = check_file(variant(tmp_path, "kp: 2500, kd: 700"))
    assert not result.errors, [e.format() for e in result.errors]


@pytest.mark.parametrize("who, through", [
    ("task 'pid'", "task 'id'"), ("member 1 (pid_joint) of task 'ctc'", "member 2 (inverse_dynamics) of task 'ctc'")])
def test_a_bandwidth_under_computed_torque_is_warned_of_the_bandwidth_each_joint_gets(tmp_path, who, through):
    path = variant(tmp_path, "bandwidth: 30, damping: 1.0")
    result = check_file(path)
    assert not result.errors, [e.format() for e in result.errors]
    [warned] = [w for w in result.warnings if w.code == "W303" and w.message.startswith(who)]
    assert warned.message == (f"{who} is given bandwidth 30 rad/s but drives the arm through the inverse dynamics of {through}: "
                              "a bandwidth makes torques for each joint's inertia, which the inverse dynamics multiplies by "
                              "the inertia again: the joints get [67.29, 68.46, 29.07, 13.17, 12.42, 13.22] rad/s")
    assert warned.hint == ("under computed torque the gains are accelerations: give kp: 900, kd: 60 (kp = w², kd = 2 ζ w) "
                           "instead of bandwidth:")
    assert path.read_text().splitlines()[warned.line - 1][warned.column - 1:].startswith("30")  # at the bandwidth


def run_separate(path: Path, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([*PBO, "run", str(path), "--config", "separate", "--clock", "sim", "--duration", "2", "--no-live",
                           "--allow-unstable-loops", "--out", str(cwd / "run")], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


@pytest.mark.multiprocess
@pytest.mark.parametrize("change, settles", [({}, True), ({"id_first": True}, False)])
def test_the_simulated_arm_agrees_on_the_period_of_delay_the_order_of_two_tasks_adds(tmp_path, change, settles):
    path = variant(tmp_path, "kp: 2500, kd: 700", **change)
    assert bool(check_file(path).errors) is not settles
    done = run_separate(path, tmp_path)
    if settles:
        assert done.returncode == 0 and "fault:" not in done.stderr, done.stdout + done.stderr
    else:  # a joint swings from one torque limit to the other: the robot interface's saturation fault
        assert done.returncode == 2, done.stdout + done.stderr
        [fault] = [line for line in done.stderr.splitlines() if line.startswith("fault:")]
        assert "kept coming back to its effort limit" in fault and fault.endswith("its 'tau_u' was written by task 'id')"), fault
