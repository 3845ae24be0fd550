"""`pbo set` on a member of a combined task: addressed as `kp`, `1.kp` or `pid_joint.kp`, checked as the
file is (the gain's range, the computed-torque loop's stability), saved into the member's params, and
taken by that member at a cycle boundary of a run on the simulated clock."""

from __future__ import annotations

import shutil

import pytest

from pbo_runtime.config.loader import check_file, format_diagnostics, load_subsystem
from pbo_runtime.edit.live_save import same_subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import BadRequest
from pbo_runtime.supervisor.commands import dispatch
from pbo_runtime.supervisor.run_options import RunOptions
from pbo_runtime.supervisor.supervisor import Supervisor
from tests.fake_job_host import FakeJobHost
from tests.support import REPO


@pytest.fixture
def file(tmp_path):
    path = tmp_path / "computed_torque.yaml"
    shutil.copy(REPO / "configs" / "computed_torque.yaml", path)
    return path


@pytest.fixture
def host(file):
    return FakeJobHost(load_subsystem(str(file)), "combined")


def pid_member(host: FakeJobHost) -> dict:
    return host.subsystem.tasks["ctc"].params["members"][0]["params"]


@pytest.mark.parametrize("address", ["kd", "1.kd", "pid_joint.kd", "1:pid_joint.kd"])
def test_a_members_gain_is_set_by_its_name_its_number_or_its_module(host, address):
    reply = dispatch(host, "set", {"task": "ctc", "param": address, "values": ["80"]})
    assert reply["value"] == 80 and pid_member(host)["kd"] == 80 and len(host.plans) == 1
    assert pid_member(host)["kp"] == 2500 and host.subsystem.tasks["pid"].params["kd"] == 100  # nothing else


UNSTABLE = (r"^setting '1\.kd' of task 'ctc' would break the live configuration:\n<pbo set ctc 1\.kd>:1:1: error\[E326\]: the "
            r"position loop of joint 1 \(joint1\) under member 1 \(pid_joint\) of task 'ctc' \(kp 2500, kd 1200\) through the "
            r"inverse dynamics of member 2 \(inverse_dynamics\) of task 'ctc' is unstable as a unit inertia .*\n"
            r"  hint: stable for kd < 999\.\d+ \(at kp 2500\)")


@pytest.mark.parametrize("address, values, refusal", [
    ("1.kd", ["1200"], UNSTABLE),
    ("1.kp", ["-3"], r"^setting '1\.kp' of task 'ctc' would break the live configuration:\n<pbo set ctc 1\.kp>:1:1: "
                     r"error\[E308\]: .*member 1 \(pid_joint\): PidJoint\.kp must be in \[0, 1e\+06\], got: -3"),
    ("3.kd", ["80"], r"^task 'ctc' has no member '3' \(members: 1 \(pid_joint\), 2 \(inverse_dynamics\)\): name one by its "
                     r"number or its module: pbo set ctc 1\.kd VALUE$"),
    ("kq", ["80"], r"^no member of combined task 'ctc' has a parameter 'kq' \(members: 1 \(pid_joint\), 2 \(inverse_dynamics\); "
                   r"live-tunable: 1\.kp, 1\.kd, 1\.ki\)$"),
    ("1.kdd", ["80"], r"^module 'pid_joint' of member 1 of task 'ctc' has no parameter 'kdd': did you mean 'kd'\? "),
    ("gravity_feedforward", ["true"], r"^parameter '1\.gravity_feedforward' of task 'ctc' is not live-tunable: module "
                                      r"'pid_joint' of member 1 reads it in init only \(live-tunable: kp, kd, ki\)"),
    ("max_torque", ["50"], r"^parameter '2\.max_torque' of task 'ctc' is not live-tunable"),
    ("members", ["[]"], r"^parameter 'members' of task 'ctc' is not live-tunable: module 'combined' reads it in init only"),
    ("1.kd", [], r"^pbo set ctc 1\.kd needs a value$"),
])
def test_a_members_set_that_is_wrong_is_refused_as_a_tasks_is(host, address, values, refusal):
    with pytest.raises(BadRequest, match=refusal):
        dispatch(host, "set", {"task": "ctc", "param": address, "values": values})
    assert host.plans == [] and pid_member(host)["kd"] == 100


def test_two_members_of_one_module_are_told_apart_by_their_number(tmp_path):
    text = (REPO / "configs" / "computed_torque.yaml").read_text().replace(
        "{module: inverse_dynamics}]}}", "{module: inverse_dynamics},\n            {module: pid_joint, ports: {tau: q_x}}]}}")
    text = text.replace("  tau_u: {type: float64, shape: [NDOF]}", "  tau_u: {type: float64, shape: [NDOF]}\n"
                                                                   "  q_x:   {type: float64, shape: [NDOF]}")
    path = tmp_path / "two_pids.yaml"
    path.write_text(text)
    host = FakeJobHost(load_subsystem(str(path)), "combined")
    with pytest.raises(BadRequest, match=r"^members 1 and 3 of task 'ctc' both have a parameter 'kd': name one by its "
                                         r"number: 1\.kd or 3\.kd$"):
        dispatch(host, "set", {"task": "ctc", "param": "kd", "values": ["80"]})
    with pytest.raises(BadRequest, match=r"^members 1 and 3 of task 'ctc' are both module 'pid_joint': name one by its "
                                         r"number: 1\.kd or 3\.kd$"):
        dispatch(host, "set", {"task": "ctc", "param": "pid_joint.kd", "values": ["80"]})
    dispatch(host, "set", {"task": "ctc", "param": "3.kd", "values": ["80"]})
    assert host.subsystem.tasks["ctc"].params["members"][2]["params"]["kd"] == 80


def test_save_writes_a_members_new_gain_into_its_params(host, tmp_path):
    dispatch(host, "set", {"task": "ctc", "param": "1.kp", "values": ["1600"]})
    saved = tmp_path / "saved.yaml"
    dispatch(host, "save", {"file": str(saved)})
    assert "{module: pid_joint, params: {kp: 1600, kd: 100, ki: 0, gravity_feedforward: false}" in saved.read_text()
    result = check_file(saved)
    assert result.ok, format_diagnostics(result)
    assert result.subsystem is not None and same_subsystem(result.subsystem, host.subsystem)


def run_with_sets(file, sets: list[tuple[float, str, list[str]]]) -> tuple[dict, list]:
    """Configuration 'combined' for 0.6 s on the simulated clock (the arm on its way to q_d throughout),
    each set sent at its simulated time; the run's report and each set's reply (or refusal)."""
    script, replies, busy = list(sets), [], [False]

    def on_tick(supervisor: Supervisor) -> None:
        # job control ticks on while it applies a change: one set at a time, as the control queue serves them
        started = supervisor.started_at
        if busy[0] or not script or started is None or supervisor.now() - started < script[0][0] - 1e-9:
            return
        _, address, values = script.pop(0)
        busy[0] = True
        try:
            replies.append(dispatch(supervisor, "set", {"task": "ctc", "param": address, "values": values}))
        except PboError as exc:
            replies.append(exc)
        finally:
            busy[0] = False

    supervisor = Supervisor(load_subsystem(str(file)), duration=0.6, configuration="combined", on_tick=on_tick,
                            say=lambda _: None, options=RunOptions(clock="sim", out_dir=str(file.parent)))
    return supervisor.run().to_json(), replies


@pytest.mark.multiprocess
def test_on_the_simulated_clock_an_unstable_gain_is_refused_and_a_stable_one_is_taken_by_the_member(file):
    unchanged, _ = run_with_sets(file, [(0.2, "kp", ["2500"])])  # the same change, to the value the member has
    result, replies = run_with_sets(file, [(0.1, "1.kd", ["1200"]), (0.2, "kp", ["900"]), (0.2, "kd", ["60"])])
    assert result["failure"] == "" and result["faults"] == [], (result["failure"], result["faults"])
    refused, *taken = replies
    assert isinstance(refused, PboError) and "error[E326]" in str(refused) and "stable for kd < 999" in str(refused)
    assert [reply["value"] for reply in taken] == [900, 60]
    assert [s["change"] for s in result["switches"] if "change" in s] == ["set 'kp' of 'ctc'", "set 'kd' of 'ctc'"]
    robot = result["tasks"]["robot"]
    assert robot["stale_reads"] == robot["cycles_lost_to_switches"] == 0
    # the runs replay bit for bit: the arm moved otherwise only because the member took its new gains
    assert result["variables"]["q_m"]["value"] != unchanged["variables"]["q_m"]["value"]
