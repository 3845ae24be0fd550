"""Non-preemptive response-time analysis (`pbo check --profile`) and the search for an assignment (`pbo allocate`).

Known answers are worked by hand in whole ticks (tick=1); a brute-force simulation of the
executive's policy (a fake, in this file only) checks that no release pattern it tries
responds later than the analysis says. The CLI is driven in-process on hand-made profiles; one
real run on the simulated clock feeds its report to `pbo check --profile`.
"""

from __future__ import annotations

import itertools
import json
import math
import random
import subprocess
from pathlib import Path

import pytest

from pbo_runtime.analysis.allocation import pinned_tasks, propose
from pbo_runtime.analysis.schedulability import Cost, Load, analyse_configuration, response_times
from pbo_runtime.cli.main import main
from pbo_runtime.config.loader import load_subsystem
from tests.support import PBO, REPO, demo_copy

# --- the analysis, known answers ---------------------------------------------------------------


def test_a_short_critical_task_behind_a_long_one_misses_though_preemptive_edf_would_keep_it() -> None:
    # U = 1/2 + 3/10 = 0.8 <= 1: preemptive EDF meets every deadline. Non-preemptive: B starts one
    # tick before A's release, A waits 2 ticks and runs 1: R_A = 3 > T_A = 2.
    loads = [Load("A", 1, 2, critical=True), Load("B", 3, 10, critical=True)]
    assert sum(x.cost / x.period for x in loads) <= 1
    times = response_times(loads, tick=1)
    assert (times["A"].time, times["A"].blocked_by, times["A"].blocking) == (3, "B", 2)
    assert times["B"].time == 4  # behind one A released with it


def test_a_critical_task_is_blocked_by_a_long_non_critical_cycle_but_never_interfered_with() -> None:
    # preemptive (critical first) R_robot would be 0.2 ms; a 1.5 ms cycle that started just before blocks it
    times = response_times([Load("robot", 0.2e-3, 1e-3, critical=True), Load("traj", 1.5e-3, 10e-3)])
    assert times["robot"].time == pytest.approx(1.7e-3, abs=1e-8) and times["robot"].blocked_by == "traj"
    assert times["traj"].time == pytest.approx(1.7e-3, abs=1e-8)  # behind one robot cycle, then its own


def test_three_tasks_under_non_preemptive_edf_have_the_worked_response_times() -> None:
    # c blocks a and b by 2 ticks; b waits for a too; c waits for one a and one b (deadlines earlier)
    times = response_times([Load("a", 1, 4, True), Load("b", 2, 6, True), Load("c", 3, 12, True)], tick=1)
    assert {n: r.time for n, r in times.items()} == {"a": 3, "b": 5, "c": 6}
    assert times["b"].blocked_by == "c" and times["c"].blocked_by == ""


def test_an_overloaded_rtpu_has_unbounded_response_times() -> None:
    times = response_times([Load("a", 3, 4, True), Load("b", 2, 6, True)], tick=1)
    assert times["a"].time == math.inf and times["b"].time == math.inf


def _simulate(loads: list[Load], offsets: tuple[int, ...], horizon: int) -> dict[str, int]:
    """A fake of the executive's policy in whole ticks: critical first, then the earliest deadline; no preemption."""
    jobs = sorted((o + k * int(x.period), i) for i, (x, o) in enumerate(zip(loads, offsets, strict=True))
                  for k in range((horizon - o) // int(x.period) + 1))
    pending: list[tuple[int, int]] = []  # (release, task)
    worst = {x.name: 0 for x in loads}
    now, n = 0, 0
    while n < len(jobs) or pending:
        while n < len(jobs) and jobs[n][0] <= now:
            pending.append(jobs[n])
            n += 1
        if not pending:
            now = jobs[n][0]
            continue
        job = min(pending, key=lambda j: (not loads[j[1]].critical, j[0] + loads[j[1]].period, j[1]))
        pending.remove(job)
        now += int(loads[job[1]].cost)
        worst[loads[job[1]].name] = max(worst[loads[job[1]].name], now - job[0])
    return worst


def _random_sets(count: int) -> list[list[Load]]:
    rng = random.Random(22)
    sets = []
    while len(sets) < count:
        loads = [Load(f"t{i}", rng.randint(1, 3), rng.randint(2, 7), rng.random() < 0.5) for i in range(rng.randint(2, 3))]
        if sum(x.cost / x.period for x in loads) <= 1:
            sets.append(loads)
    return sets


@pytest.mark.parametrize("loads", _random_sets(20), ids=lambda loads: ",".join(
    f"{x.cost:g}/{x.period:g}{'*' if x.critical else ''}" for x in loads))
def test_no_release_pattern_simulated_responds_later_than_the_analysis(loads: list[Load]) -> None:
    analysed = response_times(loads, tick=1)
    hyper = math.lcm(*(int(x.period) for x in loads))
    seen = {x.name: 0 for x in loads}
    for offsets in itertools.product(*(range(int(x.period)) for x in loads)):
        for name, r in _simulate(loads, offsets, 2 * hyper + 8).items():
            seen[name] = max(seen[name], r)
    assert all(seen[name] <= analysed[name].time for name in seen), (seen, analysed)


def test_the_analysis_is_tight_where_an_offset_gives_the_worst_case() -> None:
    loads = [Load("A", 1, 2, True), Load("B", 3, 10, True)]
    simulated = max(_simulate(loads, (1, 0), 40)["A"], _simulate(loads, (0, 0), 40)["A"])
    assert simulated == response_times(loads, tick=1)["A"].time == 3


# --- a subsystem's configurations and the search ----------------------------------------------


def _costs(**ms: float) -> dict[str, Cost]:
    return {name: Cost(value * 1e-3, "exec_max") for name, value in ms.items()}


DEMO_COSTS = {"robot": 0.2, "traj": 0.3, "pid": 0.4, "logger": 0.9}


def _profile(folder: Path, subsystem: str, clock: str = "real", **figures: dict) -> Path:
    tasks = {name: {"cycles": 100, "exec_max": ms * 1e-3, "exec_p99": ms * 1e-4} for name, ms in DEMO_COSTS.items()}
    tasks.update(figures)
    path = folder / "run.json"
    path.write_text(json.dumps({"subsystem": subsystem, "clock": clock, "tasks": tasks}))
    return path


def test_the_demo_as_shipped_proves_its_robot_deadline(tmp_path: Path) -> None:
    sub = load_subsystem(demo_copy(tmp_path, "sched_demo"))
    verdicts = analyse_configuration(sub, "joint_pid", _costs(**DEMO_COSTS))
    [robot] = verdicts["rtpu1"]
    assert robot.status == "proven" and robot.response is not None and robot.response.time == pytest.approx(2e-4)


def test_allocate_moves_the_blocking_task_off_the_critical_rtpu(tmp_path: Path) -> None:
    sub = load_subsystem(demo_copy(tmp_path, "sched_bad", logger={"rtpu": "rtpu1"}))
    costs = _costs(**DEMO_COSTS)
    [robot, _] = analyse_configuration(sub, "joint_pid", costs)["rtpu1"]
    assert robot.status == "refuted" and robot.response is not None and robot.response.blocked_by == "logger"
    search = propose(sub, costs, ["joint_pid"], pinned_tasks(sub))
    assert search.proposal is not None and search.proposal.moves["logger"] == ("rtpu1", "rtpu0")
    assert "robot" not in search.proposal.moves  # it uses the exclusive arm: it keeps its RTPU
    after = analyse_configuration(sub, "joint_pid", costs, search.proposal.placement)
    assert all(v.status in ("proven", "meets") for vs in after.values() for v in vs)


def test_allocate_finds_nothing_when_the_blocking_task_is_pinned(tmp_path: Path) -> None:
    sub = load_subsystem(demo_copy(tmp_path, "sched_pinned", logger={"rtpu": "rtpu1"}))
    search = propose(sub, _costs(**DEMO_COSTS), ["joint_pid"], pinned_tasks(sub, pins=["logger"]))
    assert search.proposal is None and not search.gave_up


def test_an_aperiodic_task_counts_at_its_min_interarrival_and_blocks_like_any_cycle() -> None:
    sub = load_subsystem(REPO / "configs" / "operator_goal.yaml")
    costs = _costs(robot=0.2, goal=0.9, traj=0.3, pid=0.4)
    verdicts = {v.task: v for v in analyse_configuration(sub, "operated", costs, {"goal": "rtpu1"})["rtpu1"]}
    assert verdicts["goal"].period == pytest.approx(0.1)  # min_interarrival: 100 ms
    robot = verdicts["robot"]
    assert robot.status == "refuted" and robot.response is not None and robot.response.blocked_by == "goal"


# --- the CLI ------------------------------------------------------------------------------------


def test_check_with_a_profile_prints_a_verdict_per_task(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_ok")
    assert main(["check", str(file), "--profile", str(_profile(tmp_path, "sched_ok"))]) == 0
    out = capsys.readouterr().out
    assert "C = exec_max of " in out and "(the longest cycle measured: safe)" in out
    assert "configuration 'joint_pid':" in out
    assert [line.split()[0] for line in out.splitlines() if line.strip().endswith(("proven     -", "proven    -"))] == ["robot*"]
    assert "critical deadlines: 1 task(s) proven, 0 refuted, 0 not analysed" in out


def test_check_says_when_it_used_the_99th_percentile(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_p99")
    assert main(["check", str(file), "--profile", str(_profile(tmp_path, "sched_p99")), "--exec-time", "p99"]) == 0
    assert "C = exec_p99 of " in capsys.readouterr().out


def test_a_refuted_critical_deadline_is_an_error_at_the_task_with_a_remedy(tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_refuted", logger={"rtpu": "rtpu1"})
    assert main(["check", str(file), "--profile", str(_profile(tmp_path, "sched_refuted"))]) == 1
    err = capsys.readouterr().err
    line = next(n for n, text in enumerate(file.read_text().splitlines(), 1) if text.strip() == "robot:")
    assert f"{file}:{line}:3: error: critical task 'robot' can miss its deadline on RTPU 'rtpu1' in configuration " \
           "'joint_pid': response time 1.100 ms > deadline 1.000 ms (C = 0.200 ms, blocked 0.900 ms by 'logger')" in err
    assert "hint: move task 'logger' to RTPU 'rtpu0', or lengthen the period of 'robot' to 1.100 ms" in err


def test_check_with_a_profile_as_json_carries_the_verdicts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_json", logger={"rtpu": "rtpu1"})
    assert main(["check", str(file), "--profile", str(_profile(tmp_path, "sched_json")), "--format", "json"]) == 1
    timing = json.loads(capsys.readouterr().out)["schedulability"]
    assert timing["exec_time"] == "exec_max"
    [robot] = [v for v in timing["configurations"]["joint_pid"]["rtpu1"] if v["task"] == "robot"]
    assert robot["verdict"] == "refuted" and robot["blocked_by"] == "logger"
    assert timing["errors"][0]["message"].startswith("critical task 'robot' can miss its deadline")


@pytest.mark.parametrize("case, expected", [
    ("missing", r"no such profile \(a run's report.json, or the run's directory\)"),
    ("other_subsystem", r"the profile is a run of subsystem 'puma', not of 'sched_err'"),
    ("unknown_task", r"the profile has task 'ghost' that .* does not have"),
    ("not_json", r"the profile is not JSON"),
    ("not_a_report", r"the profile is not a run report"),
])
def test_a_profile_that_does_not_fit_the_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                         case: str, expected: str) -> None:
    import re

    file = demo_copy(tmp_path, "sched_err")
    profile = tmp_path / "run.json"
    if case == "other_subsystem":
        _profile(tmp_path, "puma")
    elif case == "unknown_task":
        _profile(tmp_path, "sched_err", ghost={"cycles": 1, "exec_max": 1e-4})
    elif case == "not_json":
        profile.write_text("{not json")
    elif case == "not_a_report":
        profile.write_text("[1, 2]")
    for verb in (["check", str(file)], ["allocate", str(file)]):
        assert main([*verb, "--profile", str(profile)]) == 1
        err = capsys.readouterr().err
        assert re.search(rf"^{re.escape(str(profile))}: error: {expected}", err, re.M), err
        assert "hint: " in err and "Traceback" not in err


def test_each_configuration_is_judged_with_its_own_tasks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import yaml

    file = demo_copy(tmp_path, "sched_two", logger={"rtpu": "rtpu1"})
    text = yaml.safe_load(file.read_text())
    text["configurations"]["quiet"] = ["robot", "traj", "pid"]  # no logger beside the robot
    file.write_text(yaml.safe_dump(text, sort_keys=False))
    assert main(["check", str(file), "--profile", str(_profile(tmp_path, "sched_two"))]) == 1
    out, err = capsys.readouterr()
    quiet = out[out.index("configuration 'quiet':\n"):]  # its table (the check's own summary names it too)
    assert [line.split()[5:8] for line in quiet.splitlines() if line.strip().startswith("robot*")] == [["0.200", "ms", "proven"]]
    assert "configuration 'joint_pid': response time 1.100 ms" in err
    assert "configuration 'quiet': response" not in err


def test_a_task_that_did_not_run_leaves_its_rtpu_unanalysed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_unrun", logger={"rtpu": "rtpu1"})
    profile = _profile(tmp_path, "sched_unrun", logger={"cycles": 0, "exec_max": 0.0, "exec_p99": 0.0})
    assert main(["check", str(file), "--profile", str(profile)]) == 0
    out = capsys.readouterr()
    assert "critical task 'robot' on RTPU 'rtpu1' in configuration 'joint_pid' is not analysed: no execution time " \
           "for 'logger'" in out.out
    assert "1 not analysed" in out.out


def test_allocate_prints_the_yaml_lines_to_change(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_alloc", logger={"rtpu": "rtpu1"})
    assert main(["allocate", str(file), "--profile", str(_profile(tmp_path, "sched_alloc"))]) == 0
    out = capsys.readouterr().out
    assert "move 2 task(s) to prove every critical deadline (and every other deadline):" in out
    assert "task 'logger': rtpu rtpu1 -> rtpu0" in out
    assert "    - rtpu: rtpu1" in out and "    + rtpu: rtpu0" in out


def test_allocate_says_when_no_assignment_exists(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_none", logger={"rtpu": "rtpu1"})
    assert main(["allocate", str(file), "--profile", str(_profile(tmp_path, "sched_none")), "--pin", "logger"]) == 1
    err = capsys.readouterr().err
    assert "error: no assignment of the tasks to the RTPUs proves every critical deadline of configuration(s) " \
           "'joint_pid' on 2 RTPU(s) (kept: 'robot' uses exclusive device 'arm'; 'logger' pinned (--pin))" in err


def test_allocate_leaves_a_passing_assignment_alone(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file = demo_copy(tmp_path, "sched_fine")
    profile = _profile(tmp_path, "sched_fine", logger={"cycles": 10, "exec_max": 1e-4, "exec_p99": 1e-5})
    assert main(["allocate", str(file), "--profile", str(profile)]) == 0
    assert "the given assignment already proves every critical deadline; nothing to change" in capsys.readouterr().out


@pytest.mark.multiprocess
def test_a_real_run_report_feeds_check_with_a_profile(tmp_path: Path) -> None:
    file = demo_copy(tmp_path, "sched_run")
    out = tmp_path / "run"
    done = subprocess.run([*PBO, "run", str(file), "--duration", "0.1", "--clock", "sim", "--no-live", "--out", str(out)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    checked = subprocess.run([*PBO, "check", str(file), "--profile", str(out)], cwd=tmp_path, capture_output=True,
                             text=True, timeout=60)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert "note: the profile is a run on the simulated clock" in checked.stdout
    lines = checked.stdout.split("\nschedulability ", 1)[1].splitlines()  # the verdicts, after the file's own lines
    verdicts = {line.split()[0]: line for line in lines if line.startswith("    ") and line.split()[0] != "task"}
    assert set(verdicts) == {"robot*", "traj", "pid", "logger"}, checked.stdout
    assert " proven " in verdicts["robot*"]
    assert "critical deadlines: 1 task(s) proven" in checked.stdout


def test_a_profile_is_refused_for_an_application_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    profile = _profile(tmp_path, "puma")
    assert main(["check", str(REPO / "configs" / "leader_follower.yaml"), "--profile", str(profile)]) == 1
    assert "error: --profile takes a subsystem file, and " in capsys.readouterr().err
