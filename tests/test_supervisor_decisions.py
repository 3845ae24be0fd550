"""The supervisor's decisions on restarts and on the table lock, as functions of the run's state: no process."""

import pytest

from pbo_runtime.config.model import RestartPolicy, RtpuSpec
from pbo_runtime.supervisor.lock_watch import LockVerdict, holder_alive, lock_verdict
from pbo_runtime.supervisor.restarts import RestartPlan, count_death, may_restart, restart_plan

POLICY = RestartPolicy(max=3, within=10.0)
RTPUS = [RtpuSpec("rtpu0", 0, restart=POLICY), RtpuSpec("rtpu1", 1)]


# --- whether a death is restarted ------------------------------------------------------------


@pytest.mark.parametrize(("role", "table_made", "stopping", "restarted"), [
    ("rtpu0", True, "", True),
    ("rtpu1", True, "", False),  # no policy: the run stops
    ("plant", True, "", False),  # the plant is never restarted
    ("rtpu0", False, "", False),  # before the table exists: a start that failed
    ("rtpu0", True, "Ctrl-C", False),  # the run is stopping anyway
    ("rtpu9", True, "", False),  # not an RTPU of this subsystem
])
def test_only_an_rtpu_with_a_policy_is_restarted_and_only_while_the_run_goes_on(role, table_made, stopping, restarted):
    assert may_restart(role, RTPUS, table_made, stopping) is restarted


# --- the policy's count ----------------------------------------------------------------------


def test_the_deaths_past_max_within_the_window_stop_the_run():
    deaths: list[float] = []
    verdicts = []
    for at in (1.0, 2.0, 3.0, 4.0):
        deaths, past = count_death(deaths, at, POLICY)
        verdicts.append(past)
    assert verdicts == [False, False, False, True]
    assert deaths == [1.0, 2.0, 3.0, 4.0]


def test_a_death_that_left_the_window_is_no_longer_counted():
    deaths, past = count_death([1.0, 2.0, 3.0], 11.5, POLICY)  # 1.0 is 10.5 s before: out of the 10 s window
    assert (deaths, past) == ([2.0, 3.0, 11.5], False)


def test_a_policy_of_no_restart_stops_the_run_at_the_first_death():
    assert count_death([], 0.5, RestartPolicy(max=0, within=10.0)) == ([0.5], True)


def test_counting_leaves_the_deaths_it_was_given_alone():
    before = [1.0]
    count_death(before, 2.0, POLICY)
    assert before == [1.0]


# --- what a restart brings back --------------------------------------------------------------


STATES = {"traj": "ON", "pid": "ON", "spare": "OFF", "gone": "KILLED", "never": "NOT_CREATED"}
HOSTED = ["traj", "pid", "spare", "gone", "never"]


def test_a_restart_brings_back_what_was_alive_and_turns_on_what_was_on():
    assert restart_plan(HOSTED, STATES, "run") == RestartPlan(["traj", "pid", "spare"], ("traj", "pid"), "run")


def test_a_task_the_supervisor_never_heard_of_is_not_spawned():
    assert restart_plan(["traj", "late"], {"traj": "ERROR"}, "run") == RestartPlan(["traj"], (), "run")


def test_a_dynamic_switch_keeps_what_was_spawned_and_turns_on_the_new_configurations_members():
    plan = restart_plan(HOSTED, STATES, "hold", switching_to=["spare", "never"], static=False)
    assert plan == RestartPlan(["traj", "pid", "spare"], ("spare",), "hold")


def test_a_static_switch_spawns_only_the_new_configurations_members():
    plan = restart_plan(HOSTED, STATES, "hold", switching_to=["spare", "never"], static=True)
    assert plan == RestartPlan(["spare", "never"], ("spare", "never"), "hold")


# --- a holding of the table lock past its bound ----------------------------------------------


OWN = 100


@pytest.mark.parametrize(("pid", "state", "ours", "verdict"), [
    (0, "", False, LockVerdict("left", "dead", "it cannot be told who holds it; the run is stopped")),
    (OWN, "", False, LockVerdict("left", "dead", "it cannot be told who holds it; the run is stopped")),
    (200, "", True, LockVerdict("released", "dead")),  # gone: its lock is released
    (200, "Z", True, LockVerdict("released", "dead")),  # a zombie holds nothing
    (200, "T", True, LockVerdict("killed", "stopped")),  # a child stopped by SIGSTOP
    (200, "R", True, LockVerdict("killed", "running")),
    (300, "S", False, LockVerdict("left", "running",
                                  "it is not a process of this run, so it was not signalled; the run is stopped")),
    (300, "", False, LockVerdict("released", "dead")),  # any dead holder's lock is released
])
def test_a_wedged_lock_is_released_from_the_dead_and_taken_from_the_runs_own_never_from_another(pid, state, ours, verdict):
    assert lock_verdict(pid, OWN, state, ours) == verdict


@pytest.mark.parametrize(("state", "alive"), [("", False), ("Z", False), ("X", False), ("R", True), ("S", True),
                                              ("D", True), ("T", True), ("t", True)])
def test_only_a_live_holder_gets_a_last_look(state, alive):
    assert holder_alive(state) is alive
