"""tools/cpu_trace.py: each overrun of a run matched with what held the CPUs (Linux scheduler trace)."""

from __future__ import annotations

import re

import pytest

from tests.support import REPO
from tools import cpu_trace
from tools.cpu_trace import (
    ProcessNames,
    SchedulerTrace,
    TraceUnavailable,
    explain,
    holders,
    occupancy,
    parse_switches,
    parse_wakeups,
)


def line(cpu: int, time: float, prev: int, state: str, following: int) -> str:
    """A sched_switch line as tracefs writes it (its fields, spacing and flags)."""
    return (f"          python-{prev}    [{cpu:03d}] d..2.  {time:.6f}: sched_switch: prev_comm=python prev_pid={prev} "
            f"prev_prio=120 prev_state={state} ==> next_comm=python next_pid={following} next_prio=120")


RTPU, KDAMOND, PLANT = 101, 77, 55
# CPU 0: the RTPU spins, kdamond preempts it for 1.4 ms, it runs its cycle and sleeps.
# CPU 1: idle but for one plant step.
EXCERPT = [
    line(0, 10.000000, 0, "R", RTPU),
    line(1, 10.000000, 0, "R", 0),
    line(0, 10.000100, RTPU, "R", KDAMOND),
    "          python-101    [000] d.s4.  10.000200: sched_wakeup: comm=rcu_preempt pid=15 prio=120 target_cpu=001",
    line(1, 10.000500, 0, "R", PLANT),
    line(1, 10.000600, PLANT, "S", 0),
    line(0, 10.001600, KDAMOND, "S", RTPU),
    line(0, 10.001650, RTPU, "S", 0),
    line(0, 10.002000, 0, "R", 0),
    line(1, 10.002000, 0, "R", 0),
]


def names() -> ProcessNames:
    known = ProcessNames()  # not entered: no sampling thread, names given here
    known.names.update({RTPU: "RTPU rtpu0", KDAMOND: "[kdamond.0]", PLANT: "plant"})
    return known


def test_a_trace_excerpt_parses_into_its_context_switches_in_time_order():
    switches = parse_switches(list(reversed(EXCERPT)))
    assert len(switches) == 9, "the wakeup line is not a switch"
    assert [s.time for s in switches] == sorted(s.time for s in switches)
    preempted = [s for s in switches if s.prev == RTPU and s.prev_state == "R"]
    assert len(preempted) == 1 and preempted[0].next == KDAMOND and preempted[0].cpu == 0


def test_who_held_each_cpu_is_counted_within_the_window_only():
    held = holders(occupancy(parse_switches(EXCERPT)), 10.0002, 10.00165)
    assert held[0][KDAMOND] == pytest.approx(0.0014)
    assert held[0][RTPU] == pytest.approx(0.00005)
    assert held[1][PLANT] == pytest.approx(0.0001)
    assert held[1][0] == pytest.approx(0.00135), "the idle task, pid 0"


def test_each_overrun_the_report_kept_is_matched_with_the_cpus_holders():
    report = {"started_monotonic": 9.0, "duration": 5.0,
              "tasks": {"pid": {"rtpu": "rtpu0", "overruns": 1, "last_overruns": [[1.0002, 0.0014, 0.00005]]},
                        "traj": {"rtpu": "rtpu0", "overruns": 0, "last_overruns": []}}}
    rows = explain(report, parse_switches(EXCERPT), names())
    assert len(rows) == 1
    cpu0 = rows[0]["cpus"][0]
    assert next(iter(cpu0)) == "[kdamond.0]" and cpu0["[kdamond.0]"] == pytest.approx(0.0014)
    text = cpu_trace.render(rows, report)
    assert "pid (rtpu0) at 1.000 s: started 1.40 ms late, ran 0.05 ms" in text
    assert "CPU 0 (ms): [kdamond.0] 1.40, RTPU rtpu0 0.05" in text
    assert text.endswith("across these overruns (ms): [kdamond.0] 1.40, plant 0.10")


def wakeup(cpu: int, time: float, pid: int) -> str:
    """A sched_wakeup line as tracefs writes it, from the idle task's interrupt on `cpu`."""
    return (f"          <idle>-0       [{cpu:03d}] dNh4.  {time:.6f}: sched_wakeup: comm=python pid={pid} prio=49 "
            f"target_cpu={cpu:03d}")


# CPU 1 as this VM traces it: the switch out of the idle task is missing. The RTPU's timer was to
# wake it at 9.9998 (0.2 ms before its release at 10.0); it fired 1.3 ms late, at 10.0011.
UNTRACED_SWITCH_IN = [
    line(1, 9.999000, RTPU, "S", 0),
    wakeup(1, 10.001100, RTPU),
    line(1, 10.001300, RTPU, "S", 0),
]


def test_a_task_seen_leaving_a_cpu_it_was_not_seen_entering_ran_there_from_its_wakeup():
    spans = occupancy(parse_switches(UNTRACED_SWITCH_IN), parse_wakeups(UNTRACED_SWITCH_IN))
    assert spans[1] == [(9.999, pytest.approx(10.0011), 0), (pytest.approx(10.0011), 10.0013, RTPU)]
    assert occupancy(parse_switches(UNTRACED_SWITCH_IN))[1] == [(9.999, 10.0013, RTPU)], "no wake-up: since the switch before"


def test_an_overrun_says_when_its_rtpu_was_woken_from_its_release():
    report = {"started_monotonic": 9.0, "duration": 5.0,
              "tasks": {"pid": {"rtpu": "rtpu0", "overruns": 1, "last_overruns": [[1.0, 0.0012, 0.0001]]}}}
    rows = explain(report, parse_switches(UNTRACED_SWITCH_IN), names(), parse_wakeups(UNTRACED_SWITCH_IN))
    assert rows[0]["woken"] == [pytest.approx(0.0011)]
    assert rows[0]["cpus"][1] == {"idle": pytest.approx(0.0011), "RTPU rtpu0": pytest.approx(0.0002)}
    text = cpu_trace.render(rows, report)
    assert "started 1.20 ms late, ran 0.10 ms; its RTPU was woken at +1.10 ms from the release" in text


def test_a_run_without_overruns_says_so():
    report = {"started_monotonic": 9.0, "duration": 5.0, "tasks": {"pid": {"overruns": 0, "last_overruns": []}}}
    assert cpu_trace.render(explain(report, [], names()), report) == "no overrun in 5.0 s (0 counted)"


def test_a_report_of_the_simulated_clock_is_refused_with_the_reason():
    with pytest.raises(TraceUnavailable, match="no started_monotonic"):
        explain({"started_monotonic": 0.0, "tasks": {}}, [], names())


def test_without_tracefs_the_trace_says_what_to_do(tmp_path):
    with pytest.raises(TraceUnavailable, match=r"^no tracefs at .*missing: mount it"), SchedulerTrace(tmp_path / "missing"):
        pass


@pytest.mark.multiprocess
def test_a_real_run_is_traced_and_the_trace_settings_are_put_back(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the run's directory (runs/...) lands here, not in the checkout
    settings = {name: cpu_trace.TRACEFS / name for name in ("trace_clock", "set_event", "tracing_on")}
    before = {name: path.read_text() for name, path in settings.items() if path.exists()}
    status = cpu_trace.main([str(REPO / "configs" / "pid_joint.yaml"), "--duration", "1"])
    out, err = capsys.readouterr()
    if status == 2 and err.startswith("cpu_trace: ") and ("tracefs" in err or "root" in err):
        pytest.skip(f"no scheduler trace on this machine: {err.strip()}")
    assert status == 0, err
    assert re.match(r"^(no overrun in 1\.\d s \(\d+ counted\)|\d+ overruns explained)", out), out
    assert {name: path.read_text() for name, path in settings.items() if path.exists()} == before, "the settings are put back"
