"""configs/branches.yaml run for real on the simulated clock: the decisions, their replay, a failure no try catches."""

from __future__ import annotations

import json
import subprocess

import pytest

from tests.support import PBO, REPO, assert_nothing_left

BRANCHES = REPO / "configs" / "branches.yaml"
WALL = ("run_id", "objects", "wall_seconds", "running_wall_seconds", "startup", "started_monotonic", "started_at",
        "realtime", "switches", "tasks")  # what differs between two runs of one file: wall times, names, pids


def run_sim(tmp_path, config, out: str, *arguments: str) -> tuple[subprocess.CompletedProcess, dict]:
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--no-live", "--out", str(tmp_path / out), *arguments],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    return done, json.loads((tmp_path / out / "report.json").read_text())


@pytest.mark.multiprocess
def test_the_arm_falls_back_repeats_decides_and_replays_bit_for_bit(tmp_path):
    first_run, first = run_sim(tmp_path, BRANCHES, "first", "--app", "pick")
    second_run, second = run_sim(tmp_path, BRANCHES, "second", "--app", "pick")
    assert first_run.returncode == 0, first_run.stdout + first_run.stderr
    assert first["stopped_by"] == "application 'pick' done" and first["failure"] == ""
    # the approach timed out: its fallback ran, and the application went on to the end
    assert [(d["kind"], d.get("taken")) for d in first["decisions"]] == [
        ("try", "fallback"), ("repeat", None), ("repeat", None), ("wait", "holds"), ("if", "then")]
    assert first["decisions"][0]["failure"].startswith("job 'approach' (pick > try): timed out after 0.3 s")
    assert first["jobs_done"] == ["reach", "reach", "reach", "reach", "reach", "settle"]
    assert "decision at" in first_run.stdout and "try failed -> fallback" in first_run.stdout
    # the replay: the same decisions on the same values, the same log to the byte
    assert second_run.returncode == 0
    assert {k: v for k, v in first.items() if k not in WALL} == {k: v for k, v in second.items() if k not in WALL}
    assert (tmp_path / "first" / "branches.mcap").read_bytes() == (tmp_path / "second" / "branches.mcap").read_bytes()
    assert_nothing_left(first)


@pytest.mark.multiprocess
def test_a_failure_no_try_catches_ends_the_run_as_a_failed_job_does(tmp_path):
    config = tmp_path / "doomed.yaml"
    config.write_text(BRANCHES.read_text().replace("subsystem: puma_branches", "subsystem: puma_doomed")
                      + "  doomed:\n    - try: [approach: far]\n      fallback: [approach: far]\n    - reach: ready\n")
    done, report = run_sim(tmp_path, config, "out", "--app", "doomed")
    assert done.returncode == 2, done.stdout + done.stderr
    assert report["stopped_by"] == "failure"
    assert report["failure"].startswith("job 'approach' (doomed > fallback): timed out after 0.3 s")
    assert [d["kind"] for d in report["decisions"]] == ["try"]
    assert "Traceback" not in done.stderr
