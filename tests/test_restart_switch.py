"""An RTPU that dies in the middle of a switch, or of a job's step, is restarted and the switch completes.

configs/switch_joint.yaml with a restart policy and a fault injector in its `pd` configuration that
aborts its process when it is turned on (`fault: abort, in_on: true`), once per run: switching from
`pid` to `pd` kills rtpu0 while it applies the switch. Its restart brings it back in `pd` (its tasks
of `pd` ON, `pid` not), the switch's record names the restart, and the run ends as asked, having
left nothing behind; dynamic and static switches alike, and a switch made by an application's step.
Past the policy (a module whose init aborts, spawned by a static switch), the run stops and says
why. Real clock, no timing asserted: each test waits for the run to end, and the safety nets only catch a hang.
"""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest

from tests.support import (
    PBO,
    REPO,
    assert_ended_well,
    assert_nothing_left,
    config_copy,
    kill_and_await_restart,
    killed_on_failure,
    read_until,
    run_output,
    start_run,
)

pytestmark = pytest.mark.multiprocess

SWITCH_JOINT = REPO / "configs" / "switch_joint.yaml"
RUN_SAFETY_NET = 300  # seconds: a net for a run that hangs, not a timing
CRASH_ON_TURN_ON = (
    ("  pd:    {module: pid_joint", "  crash: {module: fault_injector, rtpu: rtpu0, period: 10 ms, "
                                    "params: {fault: abort, in_on: true}}\n  pd:    {module: pid_joint"),
    ("  pd:  [robot, traj, pd]", "  pd:  [robot, traj, pd, crash]"),
)
STEPS = (  # an application: a step in pid, then one in pd (its switch crashes rtpu0), each for a while
    ("jobs:\n", "jobs:\n  still: {configuration: pid, timeout: 0.2 s}\n  hold: {configuration: pd, timeout: 0.5 s}\n"),
    ("applications:\n", "applications:\n  through:\n    - still: {q_d: [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]}\n"
                        "    - hold: {q_d: [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]}\n"),
)


def policy(most: int) -> tuple[str, str]:
    return ("rtpus: [rtpu0, rtpu1]", f"rtpus: [rtpu0, rtpu1]\nrestart: {{max: {most}, within: 10 min}}")


def run_to_the_end(config: Path, folder: Path, *arguments: str) -> tuple[subprocess.CompletedProcess[str], dict]:
    report_path = folder / "report.json"
    run = subprocess.run([*PBO, "run", str(config), "--no-live", "--report", str(report_path), "--out", str(folder / "out"),
                          *arguments], cwd=folder, capture_output=True, text=True, timeout=RUN_SAFETY_NET)
    assert "Traceback" not in run.stderr, run.stderr
    return run, json.loads(report_path.read_text())


def assert_restarted_once_into_pd(run: subprocess.CompletedProcess[str], report: dict) -> None:
    assert_ended_well(run.returncode, report, run.stderr)
    assert report["failure"] == "", report["failure"]
    restarts = [(r["rtpu"], r["cause"], r["seconds"] is not None) for r in report["restarts"]]
    assert restarts == [("rtpu0", "killed by SIGABRT", True)]
    assert sorted(report["restarts"][0]["tasks_on"]) == ["crash", "pd", "traj"]  # pd's tasks of rtpu0, not pid
    said = (run.stdout + run.stderr).replace("\n", "")  # (the console wraps long lines)
    assert "restarting it in 'pd', the configuration it was switching to" in said, said
    into_pd = [s for s in report["switches"] if s["to"] == "pd"]
    assert [s.get("restarted") for s in into_pd] == [["rtpu0"]]
    states = {name: task["state"] for name, task in report["tasks"].items()}
    on = ("robot", "traj", "pd", "crash")
    assert {name: states[name] for name in on} == dict.fromkeys(on, "ON")
    assert states["pid"] != "ON"
    assert_nothing_left(report)


@pytest.mark.parametrize("how", ["dynamic", "static"])
def test_an_rtpu_that_dies_applying_a_switch_is_restarted_in_the_new_configuration_and_the_switch_completes(tmp_path, how):
    config = config_copy(SWITCH_JOINT, tmp_path, f"restart_switch_{how}", (policy(2), *CRASH_ON_TURN_ON))
    run, report = run_to_the_end(config, tmp_path, "--alternate", "pid,pd", "--switches", "1",
                                 *(["--static"] if how == "static" else []))
    assert report["stopped_by"] == "1 switches done", report["stopped_by"]
    assert_restarted_once_into_pd(run, report)
    assert "switches through an RTPU's restart: 1 (rtpu0)" in run.stdout, run.stdout


def test_an_rtpu_that_dies_in_a_jobs_switch_is_restarted_and_the_application_goes_on(tmp_path):
    config = config_copy(SWITCH_JOINT, tmp_path, "restart_step", (policy(2), *CRASH_ON_TURN_ON, *STEPS))
    run, report = run_to_the_end(config, tmp_path, "--app", "through")
    assert report["stopped_by"] == "application 'through' done", report["stopped_by"]
    assert report["jobs_done"] == ["still", "hold"]
    assert_restarted_once_into_pd(run, report)
    # the robot interface held the arm while rtpu0 was away (nothing wrote its torque), and went back to
    # its cycle once the restarted pd wrote it: nothing left it holding (the dead switch's word was cleared)
    robot_holds = [e for e in report["stable_episodes"] if e["task"] == "robot"]
    assert robot_holds and all(e["to"] is not None for e in robot_holds), robot_holds


def test_past_its_policy_an_rtpu_that_dies_during_a_switch_stops_the_run_and_says_why(tmp_path):
    # a static switch spawns the fault injector of pd, whose init aborts its process every time: the
    # restart dies as the first did, and the second death is past the policy (at most one)
    crash_in_init = tuple((old, new.replace("in_on: true", "in_init: true")) for old, new in CRASH_ON_TURN_ON)
    config = config_copy(SWITCH_JOINT, tmp_path, "restart_switch_past", (policy(1), *crash_in_init))
    run, report = run_to_the_end(config, tmp_path, "--alternate", "pid,pd", "--switches", "1", "--static")
    assert run.returncode == 2, run.stderr
    assert "RTPU 'rtpu0'" in run.stderr and "died (killed by SIGABRT)" in run.stderr, run.stderr
    assert "it died 2 times within 600 s, more than its restart policy allows (restart: {max: 1, within: 600 s}), " \
           "so the run stops" in run.stderr, run.stderr
    assert report["stopped_by"] == "failure" and "restart policy" in report["failure"]
    assert [r["seconds"] is None for r in report["restarts"]] == [True]  # its restart died too, and was not brought back
    assert_nothing_left(report)


def test_an_rtpu_that_dies_turning_on_a_task_spawned_live_comes_back_with_the_live_description(tmp_path):
    # `pbo spawn` a fault injector that aborts in on: its plan kills rtpu0, which comes back knowing the
    # spawned task (the description the plan swapped in, not the file's); killed once more later, it
    # comes back with it again
    config = config_copy(SWITCH_JOINT, tmp_path, "restart_live", (policy(2),))
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "0", "--report", str(report_path), "--out", str(tmp_path / "out"),
                    live=True)
    with killed_on_failure(run):
        spawned = subprocess.run([*PBO, "spawn", "crash", "--module", "fault_injector", "--rtpu", "rtpu0", "--period", "10ms",
                                  "--param", "fault=abort", "in_on=true", "--subsystem", "restart_live"],
                                 capture_output=True, text=True, timeout=RUN_SAFETY_NET)
        assert spawned.returncode == 0 and "task 'crash' on rtpu0" in spawned.stdout, spawned
        read_until(run, "restarted:")  # (said before the spawn's answer: the plan waited for it)
        kill_and_await_restart(run)
        run.send_signal(signal.SIGINT)
        _out, err = run_output(run, RUN_SAFETY_NET)
    assert "Traceback" not in err, err
    report = json.loads(report_path.read_text())
    assert report["failure"] == "" and report["stopped_by"] == "Ctrl-C", report["failure"]
    assert [(r["rtpu"], r["cause"]) for r in report["restarts"]] == [("rtpu0", "killed by SIGABRT"),
                                                                     ("rtpu0", "killed by SIGKILL")]
    assert all(sorted(r["tasks_on"]) == ["crash", "pid", "traj"] for r in report["restarts"]), report["restarts"]
    assert [s.get("restarted") for s in report["switches"] if s.get("change") == "spawn 'crash'"] == [["rtpu0"]]
    assert {name: report["tasks"][name]["state"] for name in ("robot", "traj", "pid", "crash")} == dict.fromkeys(
        ("robot", "traj", "pid", "crash"), "ON")
    assert_nothing_left(report)
