"""Applications that decide, run by job control on a fake host and a manual clock: each path of each kind."""

from __future__ import annotations

from pathlib import Path

import pytest

from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.supervisor.decisions import decision_lines
from pbo_runtime.supervisor.job_control import JobFailure
from tests.fake_job_host import SUBSYSTEM, FakeJobHost

# jobs of tests/fake_job_host.py: reach and settle (a post-condition, 10 s timeout), guarded (a
# pre-condition that never holds), hold (no condition at all), dwell (runs 50 ms)
APPLICATIONS = """
  branch_then:
    - if: "max(abs(q_m)) < 1"
      then: [dwell]
      else: [hold]
  branch_else:
    - if: "max(abs(q_m)) > 1"
      then: [dwell]
      else: [hold, dwell]
  branch_none:
    - if: "max(abs(q_m)) > 1"
      then: [dwell]
  caught:
    - try: [guarded, hold]
      fallback: [dwell]
    - hold
  not_needed:
    - try: [dwell]
      fallback: [hold]
  timed_out:
    - try: [reach: ready]
      fallback: [dwell]
  uncaught:
    - try: [guarded]
      fallback: [reach: ready]
  thrice:
    - repeat: [dwell, hold]
      times: 3
  until_moved:
    - repeat: [dwell]
      until: "q_m[0] > 0.2"
      max: 5
  never_moved:
    - repeat: [dwell]
      until: "q_m[0] > 0.2"
      max: 2
  still:
    - wait: "q_m[0] > 0.2"
      timeout: 1 s
  wait_caught:
    - try:
        - wait: "q_m[0] > 0.2"
          timeout: 100 ms
      fallback: [hold]
  twins:
    - if: "max(abs(q_m)) < 1"
      then: [dwell]
    - hold
    - if: "max(abs(q_m)) < 1"
      then: [dwell]
  nested:
    - try:
        - repeat: [dwell]
          times: 2
        - guarded
      fallback:
        - if: "q_m[0] < 0.2"
          then: [hold]
"""


@pytest.fixture(scope="module")
def subsystem(tmp_path_factory):
    folder: Path = tmp_path_factory.mktemp("decisions")
    path = folder / "switch_joint.yaml"
    path.write_text(SUBSYSTEM + APPLICATIONS)  # applications: is the file's last section
    return load_subsystem(str(path))


@pytest.fixture
def host(subsystem) -> FakeJobHost:
    return FakeJobHost(subsystem, "pd")


def arm_moves_after(seconds: float):
    """An on_pump that moves the arm to q_d once `seconds` of run time have passed."""
    def move(host: FakeJobHost) -> None:
        if host.now() >= seconds:
            host.values["q_m"] = host.values["q_d"].copy()
    return move


def kinds(host: FakeJobHost) -> list[tuple[str, str]]:
    return [(entry.kind, entry.taken) for entry in host.job_control.decisions]


@pytest.mark.parametrize("application, jobs, taken", [
    ("branch_then", ["dwell"], "then"),
    ("branch_else", ["hold", "dwell"], "else"),
    ("branch_none", [], "else"),
])
def test_an_if_runs_the_row_its_condition_chooses_on_the_values_read_then(host, application, jobs, taken):
    host.job_control.run_application(application)
    assert host.job_control.jobs_done == jobs
    [entry] = host.job_control.decisions
    assert (entry.kind, entry.taken, entry.path) == ("if", taken, application)
    assert entry.values == {"q_m": [0.0] * 6}


def test_a_try_that_fails_runs_its_fallback_and_the_application_goes_on(host):
    host.job_control.run_application("caught")
    assert host.job_control.jobs_done == ["dwell", "hold"]
    [entry] = host.job_control.decisions
    assert entry.kind == "try" and entry.taken == "fallback" and entry.path == "caught"
    assert entry.failure.startswith("job 'guarded' (caught > try): pre-condition 'max(abs(q_m)) > 10' does not hold")
    assert entry.values == {"q_m": [0.0] * 6}


def test_a_try_that_does_not_fail_skips_its_fallback(host):
    host.job_control.run_application("not_needed")
    assert host.job_control.jobs_done == ["dwell"] and host.job_control.decisions == []


def test_a_try_whose_job_times_out_runs_its_fallback_in_the_configuration_it_is_in(host):
    host.job_control.run_application("timed_out")
    assert host.job_control.jobs_done == ["dwell"]
    [entry] = host.job_control.decisions
    assert "timed out after 10 s" in entry.failure and set(entry.values or {}) == {"q_d", "q_m"}
    assert [(r.before, r.after) for r in host.job_control.switches] == [("pd", "pid"), ("pid", "pd")]


def test_a_failure_no_try_catches_ends_the_application_as_a_sequence_does(host):
    with pytest.raises(JobFailure, match=r"^job 'reach' \(uncaught > fallback\): timed out after 10 s"):
        host.job_control.run_application("uncaught")
    assert kinds(host) == [("try", "fallback")] and host.job_control.path == []


def test_a_repeat_of_times_runs_its_row_that_many_times(host):
    host.job_control.run_application("thrice")
    assert host.job_control.jobs_done == ["dwell", "hold"] * 3
    assert [(e.turn, e.of) for e in host.job_control.decisions] == [(1, 3), (2, 3), (3, 3)]


def test_a_repeat_until_stops_when_its_condition_holds_after_a_turn(host):
    host.on_pump = arm_moves_after(0.12)  # during the third dwell
    host.job_control.run_application("until_moved")
    assert kinds(host) == [("repeat", "again"), ("repeat", "again"), ("repeat", "done")]
    assert host.job_control.jobs_done == ["dwell"] * 3


def test_a_repeat_until_still_false_after_max_fails(host):
    with pytest.raises(JobFailure, match=r"^never_moved: repeat ran 2 times; 'q_m\[0\] > 0.2' still false"):
        host.job_control.run_application("never_moved")
    assert kinds(host) == [("repeat", "again"), ("repeat", "failed")]


def test_a_wait_goes_on_when_its_condition_holds(host):
    host.on_pump = arm_moves_after(0.3)
    host.job_control.run_application("still")
    [entry] = host.job_control.decisions
    assert entry.kind == "wait" and entry.values is not None and entry.values["q_m"][0] == 0.3
    assert 0.3 <= entry.waited < 0.35


def test_a_wait_that_times_out_fails_like_a_job(host):
    with pytest.raises(JobFailure, match=r"^still > wait: 'q_m\[0\] > 0.2' still false after 1 s"):
        host.job_control.run_application("still")


def test_a_wait_that_times_out_inside_a_try_runs_the_fallback(host):
    host.job_control.run_application("wait_caught")
    assert kinds(host) == [("try", "fallback")] and host.job_control.jobs_done == ["hold"]


def test_steps_that_decide_nest_and_the_path_names_each_level(host):
    seen: list[str] = []
    host.on_pump = lambda h: seen.append(" > ".join(h.job_control.path))
    host.job_control.run_application("nested")
    assert "nested > try > repeat 2/2 > dwell" in seen
    assert kinds(host) == [("repeat", ""), ("repeat", ""), ("try", "fallback"), ("if", "then")]
    assert host.job_control.jobs_done == ["dwell", "dwell", "hold"] and host.job_control.path == []


def test_the_summary_lists_each_decision_with_its_values(host):
    host.job_control.run_application("caught")
    [line] = decision_lines(host.job_control.decisions)
    assert line.startswith("decision at 0.000 s (caught): try failed -> fallback: job 'guarded'")


def test_the_same_application_on_the_same_values_decides_the_same_way(subsystem):
    runs = []
    for _ in range(2):
        host = FakeJobHost(subsystem, "pd")
        host.on_pump = arm_moves_after(0.12)
        host.job_control.run_application("until_moved")
        runs.append(list(host.job_control.decisions))
    assert runs[0] == runs[1] and len(runs[0]) == 3


def test_pbo_status_shows_where_an_application_that_decides_is(host):
    from pbo_runtime.cli.operator import status_table
    from pbo_runtime.supervisor.commands import status

    seen: list[str] = []
    host.on_pump = lambda h: seen.append(status(h, {})["path"])
    host.job_control.run_application("caught")
    assert "caught > fallback > dwell" in seen and status(host, {})["path"] == ""
    assert status(host, {})["place"] == []
    title = status_table({"subsystem": "arm", "run_id": "1", "configuration": "pd", "application": "caught",
                          "job": "dwell", "path": "caught > fallback > dwell", "tasks": []}).title
    assert "path caught > fallback > dwell" in str(title) and "application caught" not in str(title)


@pytest.mark.parametrize("application, places", [
    ("twins", [[0, 0, 0], [2, 0, 0]]),  # two identical rows: the path alone says 'twins > then > dwell' for both
    ("caught", [[0, 1, 0]]),  # step 0, its row 1 (the fallback), step 0 of that row
])
def test_the_status_says_which_step_runs_by_its_place_in_the_rows(host, application, places):
    from pbo_runtime.supervisor.commands import status

    seen: list[list[int]] = []
    host.on_pump = lambda h: seen.append(status(h, {})["place"]) if h.job_control.job == "dwell" else None
    host.job_control.run_application(application)
    assert [place for i, place in enumerate(seen) if place not in seen[:i]] == places
    assert status(host, {})["place"] == []
