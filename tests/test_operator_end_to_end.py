"""Operator commands against a running subsystem, from another process, as from another terminal.

The fault drill: a task raises in its cycle, waits in ERROR (the robot holds the arm with its
brakes meanwhile), and the operator sees it in `pbo status`, clears it and turns it back on.
The demo's logger turned off or killed: its log is whole, and the arm never held for it.
"""

from __future__ import annotations

import json
import subprocess

import pytest

from pbo_runtime import open_log
from tests.support import PBO, REPO, assert_ended_well, assert_nothing_left, demo_copy, read_until

pytestmark = pytest.mark.multiprocess

DRILL = REPO / "configs" / "fault_drill.yaml"


def pbo(*arguments: str) -> subprocess.CompletedProcess:
    """A command from another terminal; it names its subsystem, as other runs may be alive on the machine."""
    return subprocess.run([*PBO, *arguments], capture_output=True, text=True, timeout=60)


def test_a_task_that_raises_shows_as_error_and_recovers_after_clear(tmp_path):
    report_path = tmp_path / "report.json"
    run = subprocess.Popen([*PBO, "run", str(DRILL), "--duration", "0", "--no-live", "--report", str(report_path)],
                           cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # the robot has run a stable cycle once it says so: what is asserted below waits for events, never for time
        said = read_until(run, "task 'glitch' on rtpu0 is in ERROR",
                          "critical task 'robot' runs its locally stable behaviour: the configuration is illegal")
        assert "injected fault after 200 cycles" in said, run.stderr.read() if run.poll() is not None else said
        status = pbo("status", "--subsystem", "drill")
        assert status.returncode == 0, status.stderr
        assert "glitch" in status.stdout and "ERROR" in status.stdout
        refused = pbo("on", "glitch", "--subsystem", "drill")
        assert refused.returncode == 2 and "only an OFF task can be turned on" in refused.stderr
        cleared = pbo("clear", "glitch", "--subsystem", "drill")
        assert cleared.returncode == 0, cleared.stderr
        assert "task 'glitch' is OFF" in cleared.stdout
        resumed = pbo("on", "glitch", "--subsystem", "drill")
        assert "task 'glitch' is ON" in resumed.stdout, resumed.stderr
        assert "critical task 'robot' is back to its cycle" in read_until(run, "is back to its cycle")
        values = pbo("svar", "q_m", "tau_u", "--subsystem", "drill")
        assert values.returncode == 0 and "q_m" in values.stdout and "robot" in values.stdout
        stopped = pbo("stop", "--subsystem", "drill")
        assert stopped.returncode == 0, stopped.stderr
        _out, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    report = json.loads(report_path.read_text())
    assert_ended_well(run.returncode, report, err)
    assert report["stopped_by"] == "pbo stop"
    assert report["states_at_stop"]["glitch"] == "ON"
    assert report["tasks"]["robot"]["stable_cycles"] > 0  # the arm was held while glitch was in ERROR
    assert any(e["task"] == "robot" for e in report["stable_episodes"])
    assert_nothing_left(report)


def test_switch_and_job_commands_reconfigure_a_running_subsystem(tmp_path):
    report_path = tmp_path / "report.json"
    run = subprocess.Popen([*PBO, "run", str(REPO / "configs" / "switch_joint.yaml"), "--duration", "0", "--no-live",
                            "--report", str(report_path)], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True)
    try:
        read_until(run, "is on")
        switched = pbo("switch", "pd", "--subsystem", "puma_switch")
        assert switched.returncode == 0 and "switched 'pid' -> 'pd'" in switched.stdout, switched.stderr
        unknown = pbo("switch", "nope", "--subsystem", "puma_switch")
        assert unknown.returncode == 1 and "no configuration 'nope' (configurations: pid, pd)" in unknown.stderr  # bad input
        job = pbo("job", "reach", "0.1", "-0.4", "0.4", "0", "0.3", "0.1", "--subsystem", "puma_switch")
        assert job.returncode == 0 and "job 'reach' runs in 'pid'" in job.stdout, job.stderr
        short = pbo("job", "reach", "0.1", "--subsystem", "puma_switch")
        assert short.returncode == 1 and "takes 6 values" in short.stderr
        status = pbo("status", "--subsystem", "puma_switch")
        assert "pid" in status.stdout and "reach" in status.stdout
        assert pbo("stop", "--subsystem", "puma_switch").returncode == 0
        run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    report = json.loads(report_path.read_text())
    assert [s["to"] for s in report["switches"]] == ["pd", "pid"]
    assert_nothing_left(report)


@pytest.mark.parametrize("clock", ["real", "sim"])
@pytest.mark.parametrize("verb", ["off", "kill"])
def test_turning_off_or_killing_the_logger_of_the_running_demo_leaves_its_log_whole_and_the_arm_undisturbed(tmp_path, verb,
                                                                                                           clock):
    subsystem = f"log_{verb}_{clock}"
    report_path = tmp_path / "report.json"
    run = subprocess.Popen([*PBO, "run", str(demo_copy(tmp_path, subsystem)), "--clock", clock, "--duration", "0", "--out",
                            str(tmp_path / "out"), "--report", str(report_path)],
                           cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        read_until(run, "is on")
        done = pbo(verb, "logger", "--subsystem", subsystem)
        assert done.returncode == 0, done.stderr
        assert pbo("stop", "--subsystem", subsystem).returncode == 0
        out, err = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    report = json.loads(report_path.read_text())
    assert report["states_at_stop"]["logger"] == {"off": "OFF", "kill": "KILLED"}[verb]
    log = open_log(tmp_path / "out" / "pid_joint.mcap")  # summary and footer written, every row the logger took
    assert log.complete and len(log.rows) == report["tasks"]["logger"]["cycles"] > 0
    assert "Traceback" not in out + err
    if clock == "sim":  # the simulated clock replays: no hold, no fault, whatever the machine did
        assert run.returncode == 0 and "fault:" not in out + err, out + err
        assert report["tasks"]["robot"]["stable_cycles"] == 0 and report["stable_episodes"] == []
    else:  # on the real clock, the machine may hold the arm for an input late by timing; the verb never does
        assert_ended_well(run.returncode, report, err)
        assert not any("logger" in fault for fault in report["faults"]), report["faults"]
        assert [e for e in report["stable_episodes"] if e["cause"] == "illegal"] == []  # no switch overran its cycle
    assert_nothing_left(report)
