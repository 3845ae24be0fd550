"""Reconfiguration on the running arm, in real processes: switches, jobs, an application.

The 200 switches here run on the real clock and assert no timing: every switch made, in order,
and counted. What the arm does through them, and the exact no-lost-cycle proof, is the same run on
the simulated clock (test_simulated_clock.py). Jobs and applications run on the simulated clock,
so their outcome never depends on scheduling luck.
"""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

from tests.support import PBO, REPO, assert_ended_well, assert_nothing_left

pytestmark = pytest.mark.multiprocess

SWITCHING = REPO / "configs" / "switch_joint.yaml"


def run(tmp_path, *arguments: str) -> tuple[subprocess.CompletedProcess, dict]:
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(SWITCHING), "--no-live", "--report", str(report_path), *arguments],
                          cwd=tmp_path, capture_output=True, text=True, timeout=240)
    return done, json.loads(report_path.read_text())


def test_two_hundred_switches_between_two_controllers_on_the_running_arm(tmp_path):
    done, report = run(tmp_path, "--alternate", "pid,pd", "--switches", "200", "--interval", "0.02")
    assert_ended_well(done.returncode, report, done.stderr)
    switches = report["switches"]
    assert len(switches) == 200
    assert all(math.isfinite(s["latency"]) and s["latency"] > 0 for s in switches)
    assert [s["to"] for s in switches[:4]] == ["pd", "pid", "pd", "pid"]
    assert all(sorted(s["off"]) != sorted(s["on"]) for s in switches)
    # per switch, what the critical task read until the next one (counts, not timing, are checked here)
    assert all(set(s["cycles_lost"]) == {"robot"} and set(s["stale_reads"]) == {"robot"} for s in switches)
    robot = report["tasks"]["robot"]
    assert sum(s["cycles_lost"]["robot"] for s in switches) == robot["cycles_lost_to_switches"]
    assert {"cycles_lost_to_switches", "stale_reads", "stable_cycles"} <= set(robot)
    assert report["failure"] == "" and report["states_at_stop"]["robot"] == "ON"
    assert "switches: 200; latency ms" in done.stdout
    assert_nothing_left(report)


def test_an_application_of_three_jobs_runs_to_its_end(tmp_path):
    done, report = run(tmp_path, "--app", "tour", "--clock", "sim")
    assert done.returncode == 0, done.stderr
    assert report["jobs_done"] == ["reach", "settle", "reach"]
    assert report["stopped_by"] == "application 'tour' done"
    assert [s["to"] for s in report["switches"]] == ["pd", "pid"]
    q_m = np.array(report["variables"]["q_m"]["value"])
    assert np.max(np.abs(q_m - np.array([-0.2, -0.6, 0.4, 0.1, 0.3, -0.1]))) < 0.01
    assert "job 'settle' (step 2 of 3 of application 'tour'): done" in done.stdout


def test_static_reconfiguration_kills_and_spawns_between_jobs(tmp_path):
    done, report = run(tmp_path, "--app", "tour", "--static", "--clock", "sim")
    assert done.returncode == 0, done.stderr
    assert report["jobs_done"] == ["reach", "settle", "reach"]
    assert report["states_at_stop"]["pd"] == "KILLED"  # left in the second switch, killed, not just off


def test_a_job_that_times_out_stops_the_application_with_the_condition_and_values(tmp_path):
    text = SWITCHING.read_text().replace('post: "max(abs(q_m - q_d)) < 0.01", timeout: 10 s',
                                         'post: "max(abs(q_m - q_d)) < 1e-9", timeout: 1 s')
    path = tmp_path / "impatient.yaml"
    path.write_text(text)
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(path), "--no-live", "--app", "tour", "--clock", "sim", "--report", str(report_path)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert done.returncode == 2
    assert ("job 'reach' (step 1 of 3 of application 'tour'): timed out after 1 s; "
            "post-condition 'max(abs(q_m - q_d)) < 1e-9' still false (q_d = [") in done.stderr
    assert "Traceback" not in done.stderr
    report = json.loads(report_path.read_text())
    assert report["stopped_by"] == "failure"


def test_an_incomplete_application_is_refused_before_anything_starts(tmp_path):
    text = SWITCHING.read_text().replace("    - settle: {q_d: [0.0, -0.3, 0.3, 0.0, 0.2, 0.0]}", "    - settle")
    path = tmp_path / "incomplete.yaml"
    path.write_text(text)
    checked = subprocess.run([*PBO, "check", str(path)], capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0 and "warning[W701]: application 'tour' is incomplete" in checked.stdout
    done = subprocess.run([*PBO, "run", str(path), "--app", "tour"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "application 'tour' is incomplete (a step lacks the object its job needs) and cannot be run" in done.stderr
    assert "starting subsystem" not in done.stdout


def test_an_incomplete_application_given_a_named_object_runs_each_of_its_jobs_with_it(tmp_path):
    # Onika §4.4.2: `approach` lacks its objects; `visit` gives it `ready`, which fills both gaps
    text = SWITCHING.read_text().replace("subsystem: puma_switch", "subsystem: puma_switch_visit")
    path = tmp_path / "visit.yaml"
    path.write_text(text + "  approach: [reach, settle]\n  visit: [{approach: ready}]\n")
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(path), "--no-live", "--app", "visit", "--clock", "sim", "--report", str(report_path)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=240)
    report = json.loads(report_path.read_text())
    assert_ended_well(done.returncode, report, done.stderr)
    assert report["jobs_done"] == ["reach", "settle"] and report["stopped_by"] == "application 'visit' done"
    q_m = np.array(report["variables"]["q_m"]["value"])
    assert np.max(np.abs(q_m - np.array([0.3, -0.5, 0.5, 0.2, 0.4, 0.2]))) < 0.01
    assert_nothing_left(report)
