"""The plan's lead from measured read delays, and the activation it gives: arithmetic only, no process."""

from __future__ import annotations

import pytest

from pbo_runtime.supervisor.job_control import plan_activation
from pbo_runtime.supervisor.plan_lead import (
    FIRST_SAMPLES,
    LEAD_MAX,
    LEAD_MIN,
    MARGIN,
    MARGIN_FACTOR,
    PlanLead,
    RtpuAround,
    deadline,
    earliest_activation,
)


def test_until_enough_plans_were_read_the_lead_is_the_fixed_bound():
    lead = PlanLead()
    for _ in range(FIRST_SAMPLES - 1):
        lead.record(0.0001)
        assert lead.value == LEAD_MAX


def test_the_lead_is_a_high_quantile_of_the_read_delays_plus_a_margin():
    lead = PlanLead()
    for delay in (0.0001, 0.0002, 0.0003, 0.0004):
        lead.record(delay)
    assert lead.value == pytest.approx(MARGIN_FACTOR * 0.0004 + MARGIN)  # fewer than 100: their largest


def test_with_hundreds_of_plans_one_slow_read_in_a_hundred_is_left_out_of_the_quantile():
    lead = PlanLead(window=200)
    for _ in range(198):
        lead.record(0.0002)
    lead.record(0.0009)
    lead.record(0.0015)
    assert lead.quantile() == pytest.approx(0.0009)  # the 2nd largest of 200


@pytest.mark.parametrize(("delay", "expected"), [(0.0, LEAD_MIN), (0.01, LEAD_MAX)])
def test_the_lead_stays_within_its_bounds(delay, expected):
    lead = PlanLead()
    for _ in range(FIRST_SAMPLES):
        lead.record(delay)
    assert lead.value == expected


def test_a_late_read_raises_the_lead_until_it_leaves_the_window():
    lead = PlanLead(window=8)
    for _ in range(8):
        lead.record(0.0001)
    quick = lead.value
    lead.record(0.0012, late=True)
    assert lead.late == 1 and lead.value == pytest.approx(MARGIN_FACTOR * 0.0012 + MARGIN)
    assert lead.value > quick
    for _ in range(8):
        lead.record(0.0001)
    assert lead.value == pytest.approx(quick)


@pytest.mark.parametrize("delay", [float("nan"), float("inf")])
def test_a_delay_that_was_not_measured_is_ignored(delay):
    lead = PlanLead()
    lead.record(delay)
    assert lead.quantile() != lead.quantile() and lead.value == LEAD_MAX  # nan: nothing recorded


@pytest.mark.parametrize(("requested", "lead", "expected"), [
    (10.0104, 0.0002, 10.011),  # the next boundary, when the lead fits before it
    (10.0109, 0.0002, 10.012),  # the one after, when it does not
    (10.0108, 0.0002, 10.011),  # exactly the lead before a boundary: that boundary
    (10.0104, 0.002, 10.013),   # the old fixed lead: two periods more
])
def test_the_activation_is_the_first_boundary_of_the_grid_at_least_the_lead_after_the_request(requested, lead, expected):
    assert plan_activation(requested, lead, epoch=0.0, grid=0.001) == pytest.approx(expected)


ON_THE_GRID = RtpuAround(0.0, on_periods=(0.001, 0.002), entering_periods=(0.001,), aperiodic=False)
POST, WAKE = 0.0001, 0.0008


@pytest.mark.parametrize(("rtpu", "expected"), [
    (ON_THE_GRID, (10.011, True)),  # a task ON there releases at the activation: its own timer brings it
    (RtpuAround(0.0005, (0.001,), (), False), (10.0115, True)),  # staggered: its first release after it
    (RtpuAround(0.0, (0.01,), (0.001,), False), (10.011, False)),  # the entering task is due before its own next release
    (RtpuAround(0.0, (0.001,), (), True), (10.011, False)),  # an aperiodic task may run at any time
    (RtpuAround(0.0, (), (), False), (float("inf"), True)),  # nothing runs there
])
def test_an_rtpus_deadline_is_its_first_release_at_or_after_the_activation(rtpu, expected):
    due, by_itself = deadline(rtpu, 10.011)
    assert (due, by_itself) == (pytest.approx(expected[0]), expected[1])


def test_rtpus_their_own_releases_bring_need_the_plan_only_posted_by_their_boundary():
    activation, lead = earliest_activation(10.0104, 0.0, 0.001, [ON_THE_GRID, RtpuAround(0.0005, (0.001,), (), False)],
                                           POST, WAKE)
    assert activation == pytest.approx(10.011) and lead == pytest.approx(POST)


def test_an_rtpu_only_the_wake_up_brings_needs_the_plan_read_by_its_deadline():
    woken = RtpuAround(0.0, (0.01,), (0.001,), False)
    activation, lead = earliest_activation(10.0104, 0.0, 0.001, [ON_THE_GRID, woken], POST, WAKE)
    assert activation == pytest.approx(10.012) and lead == pytest.approx(WAKE)  # 10.011 is 0.6 ms away: too soon


def test_a_staggered_rtpu_the_wake_up_brings_may_read_the_plan_until_its_own_boundary():
    woken = RtpuAround(0.0005, (0.01,), (0.001,), False)  # its entering task is first due half a period after
    activation, lead = earliest_activation(10.0104, 0.0, 0.001, [ON_THE_GRID, woken], POST, WAKE)
    assert activation == pytest.approx(10.011) and lead == pytest.approx(WAKE - 0.0005)


def test_the_grid_wait_is_less_than_a_period_after_the_lead_it_gives():
    for requested in (10.0100, 10.0103, 10.0109, 10.01099):
        woken = RtpuAround(0.0005, (0.01,), (0.001,), False)
        activation, lead = earliest_activation(requested, 0.0, 0.001, [ON_THE_GRID, woken], POST, WAKE)
        assert 0.0 <= activation - requested - lead < 0.001 + 1e-12
