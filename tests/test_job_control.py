"""Job control's decisions on a fake host and a manual clock: switches, jobs, applications; no process."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.supervisor.job_control import POLL, SWITCH_TIMEOUT, JobFailure, application_steps, evaluate
from pbo_runtime.supervisor.plan_lead import FIRST_SAMPLES, LEAD_MAX, MARGIN, MARGIN_FACTOR
from tests.fake_job_host import SUBSYSTEM, FakeJobHost, fake_subsystem

GOAL = [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]


@pytest.fixture(scope="module")
def subsystem(tmp_path_factory):
    return fake_subsystem(tmp_path_factory.mktemp("job_control"))


@pytest.fixture
def host(subsystem) -> FakeJobHost:
    return FakeJobHost(subsystem, "pid")


def arm_reaches_its_goal_after(seconds: float):
    """An on_pump that moves q_m to q_d (and stops the arm) once `seconds` of run time have passed."""
    def move(host: FakeJobHost) -> None:
        if host.now() >= seconds:
            host.values["q_m"] = host.values["q_d"].copy()
            host.values["qd_m"][:] = 0.0
    return move


# --- switching --------------------------------------------------------------------------------


def test_a_switch_posts_a_plan_on_the_release_grid_and_ends_when_every_rtpu_applied_it(host):
    host.clock.advance(0.0104)
    record = host.job_control.switch("pd")
    assert host.plans == [(1, "pd", pytest.approx(0.011))]  # the next boundary of the grid the post lead fits before
    assert (record.before, record.after, record.off, record.on) == ("pid", "pd", ["pid"], ["pd"])
    assert set(record.applied) == {"rtpu0", "rtpu1"} and record.latency == pytest.approx(0.011 - 0.0104)
    assert host.configuration == "pd" and host.job_control.pending is None
    assert host.job_control.switches == [record]


def test_before_the_first_plan_the_writing_is_timed_so_its_post_lead_is_measured_not_the_bound(host):
    host.job_control.switch("pd")
    # the plan's words written as they were, FIRST_SAMPLES times: no post delay on the manual clock
    assert host.rewrites == FIRST_SAMPLES and host.job_control.post_lead.value == pytest.approx(MARGIN)
    assert host.job_control.switches[0].lead == pytest.approx(MARGIN)  # every RTPU's own release brings it
    assert host.job_control.lead.value == LEAD_MAX  # the read delays of RTPUs a wake-up brings: none known yet
    host.job_control.switch("pid")
    assert host.rewrites == FIRST_SAMPLES  # once


def test_once_plans_were_posted_the_lead_follows_the_post_delays_when_each_rtpus_own_release_brings_it(host):
    host.read_delay = 0.0001
    for configuration in ("pd", "pid") * (FIRST_SAMPLES // 2):
        host.job_control.switch(configuration)
    assert host.job_control.lead.value == pytest.approx(MARGIN_FACTOR * 0.0001 + MARGIN)
    host.clock.time = 1.0104
    record = host.job_control.switch("pd")
    # the fake posts at its request (no post delay): every RTPU has a task ON releasing at the activation
    assert record.lead == pytest.approx(host.job_control.post_lead.value) == pytest.approx(MARGIN)
    assert host.plans[-1][2] == pytest.approx(1.011)  # the next boundary of the 1 ms grid, not two periods later
    assert record.read_delay == pytest.approx(0.0001) and record.grid_wait == pytest.approx(0.0006 - record.lead)


def test_each_rtpu_around_a_switch_is_made_once_for_the_states_and_descriptions_it_was_made_of(host):
    # made before the plan's activation is counted: kept, it is no part of the next switch's latency
    control = host.job_control
    first = control._around("pid", ["pd"])
    assert control._around("pid", ["pd"]) is first
    host.task_states["traj"] = "OFF"  # a task ON no more: what its RTPU releases changed
    assert control._around("pid", ["pd"]) is not first
    host.task_states["traj"] = "ON"
    control.switching_subsystem = dataclasses.replace(control.subsystem)  # a live change's description
    assert control._around("pid", ["pd"]) is not first


def test_a_request_that_waited_for_the_cpu_counts_its_plans_lead_from_the_posting_not_from_the_request(host):
    host.read_delay = 0.0001
    for configuration in ("pd", "pid") * (FIRST_SAMPLES // 2):
        host.job_control.switch(configuration)
    host.clock.time = 1.0104
    host.posting_delay = 0.0003  # the supervisor was preempted before the posting began
    record = host.job_control.switch("pd")
    assert record.requested_at == pytest.approx(1.0104) and record.counted_from == pytest.approx(1.0107)
    assert host.plans[-1][2] == pytest.approx(1.011)  # still the next boundary: the lead counts from 1.0107
    assert record.read_delay == pytest.approx(0.0001)  # from the clock reading the lead was added to
    assert record.latency == pytest.approx(0.0006)  # the operator's wait counts from the request


@pytest.mark.parametrize(("held", "activation"), [(0.0002, 1.011), (0.0006, 1.012)])
def test_a_posting_held_off_counts_its_activation_again_from_its_last_clock_reading(host, held, activation):
    host.read_delay = 0.0001
    for configuration in ("pd", "pid") * (FIRST_SAMPLES // 2):
        host.job_control.switch(configuration)
    host.clock.time = 1.0104
    host.held_in_posting = held  # between the activation's computing and the plan's writing
    record = host.job_control.switch("pd")
    # the boundary at 1.011 is kept while the post lead (0.1 ms) still fits before it, else the next one
    assert host.plans[-1][2] == pytest.approx(activation)
    assert record.counted_from == pytest.approx(1.0104 + held) and record.posted_at <= activation - MARGIN
    assert host.job_control.post_lead.late == 0


def test_a_plan_read_after_its_activation_is_counted_late_and_raises_the_lead(host):
    host.read_delay = 0.0001
    for configuration in ("pd", "pid") * (FIRST_SAMPLES // 2):
        host.job_control.switch(configuration)
    before = host.job_control.lead.value
    host.read_delay = 0.0015  # past the activation, whatever the phase: an RTPU held up
    host.job_control.switch("pd")
    assert host.job_control.lead.late == 1 and host.job_control.lead.value > before


def test_on_the_simulated_clock_the_plan_activates_at_the_next_tick_of_the_grid(host):
    host.tick = 0.001
    host.clock.advance(0.005)
    host.read_delay = 0.0
    host.job_control.switch("pd")
    assert host.plans[0][2] == pytest.approx(0.006)
    assert len(host.job_control.lead.ordered) == 0  # read at the tick by construction: nothing to learn


def test_a_switch_no_rtpu_applies_times_out_and_says_where_it_stood(host):
    host.rtpus_apply_plans = False
    with pytest.raises(PboError, match=rf"^switch to 'pd' did not complete within {SWITCH_TIMEOUT:g} s \(applied on: no RTPU\)$"):
        host.job_control.switch("pd")
    assert host.now() > SWITCH_TIMEOUT and host.configuration == "pid"


def test_a_switch_to_an_unknown_configuration_names_the_ones_there_are(host):
    with pytest.raises(PboError, match=r"^no configuration 'fast' \(configurations: pid, pd\)$"):
        host.job_control.switch("fast")
    assert host.plans == []


def test_a_static_switch_kills_the_leaving_tasks_and_spawns_and_turns_on_the_entering_ones(subsystem):
    host = FakeJobHost(subsystem, "pid", static=True)
    host.task_states["pd"] = "NOT_CREATED"  # static: only the running configuration's tasks exist
    record = host.job_control.switch("pd")
    assert host.signals == [("critical tasks", "hold"), ("pid", "kill"), ("pd", "spawn"), ("pd", "on"),
                            ("robot", "watch pd"), ("critical tasks", "release")]
    assert host.plans == [] and host.configuration == "pd" and (record.off, record.on) == (["pid"], ["pd"])


@pytest.mark.parametrize("op", ["kill", "spawn", "on"])
def test_a_static_switch_whose_rtpu_dies_restarts_it_and_does_only_what_is_left(subsystem, op):
    host = FakeJobHost(subsystem, "pid", static=True)
    host.task_states["pd"] = "NOT_CREATED"
    host.dies_at = {("pid" if op == "kill" else "pd", op)}  # rtpu0 (pid, pd, traj) dies at that signal
    record = host.job_control.switch("pd")
    done = {"kill": [("pid", "kill")], "spawn": [("pid", "kill"), ("pd", "spawn")],
            "on": [("pid", "kill"), ("pd", "spawn"), ("pd", "on")]}[op]
    # the restart brought pd back ON: nothing after it spawns or turns it on again; the hold is released
    assert host.signals == [("critical tasks", "hold"), *done, ("rtpu0", "restart"), ("robot", "watch pd"),
                            ("critical tasks", "release")]
    assert record.restarted == ["rtpu0"] and record.to_json()["restarted"] == ["rtpu0"]
    assert host.configuration == "pd" and host.job_control.switching is None
    assert [host.task_states[t] for t in ("robot", "traj", "pd", "pid")] == ["ON", "ON", "ON", "NOT_CREATED"]


def test_alternate_switches_the_given_number_of_times_one_interval_apart(host):
    host.job_control.alternate(["pid", "pd"], 4, 0.05)
    assert [r.after for r in host.job_control.switches] == ["pd", "pid", "pd", "pid"]
    requested = [r.requested_at for r in host.job_control.switches]
    assert requested[0] == pytest.approx(0.05, abs=0.003) and all(
        0.045 < b - a < 0.055 for a, b in itertools.pairwise(requested))


# --- jobs -------------------------------------------------------------------------------------


def test_a_job_writes_its_object_switches_and_waits_for_its_post_condition(host):
    host.on_pump = arm_reaches_its_goal_after(0.5)
    host.job_control.run_job("settle", {"q_d": GOAL})
    assert list(host.values["q_d"]) == GOAL and host.configuration == "pd"
    assert host.job_control.job == "settle" and 0.5 <= host.now() < 0.6
    assert host.said[-1].startswith("job 'settle': done in 0.5")


def test_a_job_whose_pre_condition_fails_is_refused_with_the_values_it_read(host):
    with pytest.raises(JobFailure, match=r"^job 'guarded': pre-condition 'max\(abs\(q_m\)\) > 10' does not hold "
                                         r"\(q_m = \[0\., 0\., 0\., 0\., 0\., 0\.\]\)$"):
        host.job_control.run_job("guarded", {})
    assert host.plans == [] and host.configuration == "pid"


def test_a_job_that_times_out_says_its_post_condition_is_still_false(host):
    with pytest.raises(JobFailure, match=r"^job 'reach': timed out after 10 s; post-condition "
                                         r"'max\(abs\(q_m - q_d\)\) < 0\.01' still false "
                                         r"\(q_d = \[ 0\.3, -0\.5, .*; q_m = \[0\., "):
        host.job_control.run_job("reach", {"q_d": GOAL})
    assert host.now() == pytest.approx(10.0, abs=0.02)


def test_a_job_with_a_timeout_and_no_post_condition_runs_for_that_long(host):
    host.job_control.run_job("dwell", {})
    # switched at the plan's activation (2 ms), then 50 ms in polls of POLL: the first poll past them
    assert host.configuration == "pd" and host.now() == pytest.approx(0.002 + 0.05 + POLL)


def test_a_job_with_neither_post_condition_nor_timeout_returns_once_switched(host):
    host.job_control.run_job("hold", {})
    assert host.configuration == "pd" and host.now() < 0.01


def test_an_operators_job_is_started_not_awaited_and_its_object_must_have_the_variables_size(host):
    with pytest.raises(PboError, match=r"^job 'reach': object 'q_d' takes 6 values \(shape \[6\]\), got 2$"):
        host.job_control.start_job("reach", {"q_d": [0.1, 0.2]})
    host.job_control.start_job("settle", {"q_d": GOAL})
    assert host.job_control.job == "settle" and host.configuration == "pd" and list(host.values["q_d"]) == GOAL


def test_an_application_runs_its_jobs_in_order_each_in_its_configuration(host):
    host.on_pump = arm_reaches_its_goal_after(0.0)
    host.job_control.run_application("tour")
    assert [(r.before, r.after) for r in host.job_control.switches] == [("pid", "pd"), ("pd", "pid")]
    assert list(host.values["q_d"]) == [-0.2, -0.6, 0.4, 0.1, 0.3, -0.1] and host.job_control.job is None
    assert [line.split(":")[0] for line in host.said if "done in" in line] == [
        f"job '{job}' (step {n} of 3 of application 'tour')" for n, job in enumerate(["reach", "settle", "reach"], 1)]


def test_an_application_stops_at_the_job_that_times_out_in_the_configuration_it_is_in(host):
    with pytest.raises(JobFailure, match=r"^job 'reach' \(step 1 of 3 of application 'tour'\): timed out after 10 s"):
        host.job_control.run_application("tour")
    assert host.configuration == "pid" and host.job_control.job == "reach"


def test_a_condition_that_cannot_be_evaluated_on_the_values_read_is_a_job_failure_not_a_wrong_answer(subsystem):
    # issue 18: an integer power that wraps around in int64 must not decide a job
    host = FakeJobHost(subsystem, "pid")
    host.values["NDOF"] = np.array(6, dtype=np.int32)
    with pytest.raises(JobFailure, match=r"^condition 'NDOF\*\*40 > 0' cannot be evaluated on the values read \(NDOF = 6\): "
                                         r"'NDOF\*\*40' computes an integer beyond"):
        evaluate(host, "NDOF**40 > 0")


# --- named objects and incomplete applications filled with one (Onika §4.4.2) -------------------------

READY = [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]  # the object `ready` of configs/switch_joint.yaml
ELSEWHERE = [0.1, -0.2, 0.3, 0.0, 0.1, 0.0]


@pytest.fixture(scope="module")
def with_approach(tmp_path_factory):
    """The fake subsystem with an incomplete application of one object type, and one that fills it twice."""
    folder = tmp_path_factory.mktemp("approach")
    path = folder / "approach.yaml"
    path.write_text(SUBSYSTEM + f"  approach: [reach, settle]\n  visit:\n    - approach: ready\n"
                                f"    - approach: {{joint_position: {ELSEWHERE}}}\n    - hold\n")
    return load_subsystem(str(path))


def written_objects(host: FakeJobHost) -> list[tuple[str, list[float]]]:
    """Every write of job control from now on, as (variable, value), in order."""
    writes: list[tuple[str, list[float]]] = []
    write = host.write_variable

    def record(name: str, value) -> None:
        writes.append((name, np.asarray(value).tolist()))
        write(name, value)
    host.write_variable = record  # type: ignore[method-assign]
    return writes


def test_a_step_with_a_named_object_writes_the_objects_value(host):
    writes = written_objects(host)
    host.on_pump = arm_reaches_its_goal_after(0.0)
    host.job_control.run_application("tour")
    assert writes[0] == ("q_d", READY) and len(writes) == 3


def test_an_incomplete_application_given_an_object_fills_each_of_its_gaps_with_it(with_approach):
    host = FakeJobHost(with_approach, "pid")
    writes = written_objects(host)
    host.on_pump = arm_reaches_its_goal_after(0.0)
    host.job_control.run_application("visit")
    assert writes == [("q_d", READY), ("q_d", READY), ("q_d", ELSEWHERE), ("q_d", ELSEWHERE)]
    visit = ["reach", "settle", "reach", "settle", "hold"]
    assert [line.split(":")[0] for line in host.said if "running in" in line] == [
        f"job '{job}' (step {n} of 5 of application 'visit')" for n, job in enumerate(visit, 1)]
    assert [(r.before, r.after) for r in host.job_control.switches] == [("pid", "pd"), ("pd", "pid"), ("pid", "pd")]


def test_an_incomplete_application_is_not_run_on_its_own(with_approach):
    host = FakeJobHost(with_approach, "pid")
    with pytest.raises(JobFailure, match=r"^application 'approach' is incomplete"):
        host.job_control.run_application("approach")
    assert host.plans == [] and host.job_control.switches == []


def test_application_steps_resolve_named_objects_and_fills_down_through_nested_applications(with_approach):
    steps = application_steps(with_approach, "visit")
    assert [(job, {k: np.asarray(v).tolist() for k, v in arguments.items()}) for job, arguments in steps] == [
        ("reach", {"q_d": READY}), ("settle", {"q_d": READY}), ("reach", {"q_d": ELSEWHERE}), ("settle", {"q_d": ELSEWHERE}),
        ("hold", {})]
