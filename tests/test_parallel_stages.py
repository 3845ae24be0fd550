"""`run:` as stages with `parallel:` in an application file: the checker's rules, and configs/two_arms.yaml run."""

from __future__ import annotations

import json
import re
import subprocess

import pytest

from pbo_runtime.config.application import check_application
from tests.support import PBO, REPO

TWO_ARMS = REPO / "configs" / "two_arms.yaml"


def with_run(tmp_path, run: str):
    text = TWO_ARMS.read_text()
    path = tmp_path / "arms.yaml"
    path.write_text(text[:text.index("\nrun:\n")] + "\nrun:\n" + run)
    return check_application(path), path


def test_the_shipped_two_arms_check_with_three_stages():
    result = check_application(TWO_ARMS)
    assert result.errors == [] and result.application is not None
    stages = result.application.stages
    assert [sorted(stage) for stage in stages] == [["left", "right"], ["left"], ["left", "right"]]
    assert stages[1]["left"] == {"app": "wave"} and stages[0]["right"] == {"steps": [{"reach": "ready"}]}


@pytest.mark.parametrize("run, message, marker", [
    ("  - parallel: {left: [reach: ready], middle: [reach: ready]}\n",
     r"run: stage 1 runs subsystem 'middle', which this application does not have", "middle"),
    ("  - both: {left: [reach: ready]}\n", r"run: stage 1 must be parallel: \{SUBSYSTEM: STEPS, \.\.\.\}", "both"),
    ("  - parallel: {left: {app: dance}}\n", r"run: stage 1: subsystem 'left' has no application 'dance'", "dance"),
    ("  - parallel: {left: [reach: nowhere]}\n",
     r"run: stage 1: the steps of subsystem 'left' do not interlock: .*nowhere", "left"),
    ("  - parallel: {right: [reach]}\n", r"run: stage 1: a step of subsystem 'right' lacks its object", "right"),
    ("  - parallel: {right: reach}\n", r"run: stage 1: subsystem 'right' takes a list of steps or \{app: NAME\}", "right"),
])
def test_a_stage_written_wrong_is_one_located_error(tmp_path, run, message, marker):
    result, path = with_run(tmp_path, run)
    assert [e.code for e in result.errors] == ["E813"], result.errors
    [error] = result.errors
    assert re.match(message, error.message), error.message
    lines = path.read_text().splitlines()
    assert error.line == len(lines) and marker in lines[-1]


@pytest.mark.multiprocess
def test_two_arms_run_their_stages_join_and_replay_bit_for_bit(tmp_path):
    reports = []
    for out in ("first", "second"):
        done = subprocess.run([*PBO, "run", str(TWO_ARMS), "--clock", "sim", "--out", str(tmp_path / out)],
                              cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stdout + done.stderr
        reports.append({key: json.loads((tmp_path / out / key / "report.json").read_text()) for key in ("left", "right")})
    first, second = reports
    assert first["left"]["stopped_by"] == first["right"]["stopped_by"] == "stages done"
    assert first["left"]["jobs_done"] == ["reach"] * 6 and first["right"]["jobs_done"] == ["reach"] * 2
    decisions = [(d["kind"], d.get("taken")) for d in first["left"]["decisions"]]
    assert decisions == [("repeat", None), ("repeat", None), ("if", "then")]
    done = {key: [m["time"] for m in first[key]["marks"] if re.fullmatch(r"stage \d+ done", m["label"])]
            for key in ("left", "right")}
    joined = {key: [m["time"] for m in first[key]["marks"] if re.fullmatch(r"stage \d+ joined", m["label"])]
              for key in ("left", "right")}
    assert len(done["left"]) == len(joined["right"]) == 3
    for stage in range(3):  # no arm goes on before both are done with the stage
        assert min(joined["left"][stage], joined["right"][stage]) >= max(done["left"][stage], done["right"][stage])
    for key in ("left", "right"):
        assert first[key]["decisions"] == second[key]["decisions"] and first[key]["marks"] == second[key]["marks"]
        assert (tmp_path / "first" / key / f"{key}.mcap").read_bytes() == (tmp_path / "second" / key / f"{key}.mcap").read_bytes()


def test_pbo_check_lists_the_stages(capsys):
    from pbo_runtime.cli.main import main

    assert main(["check", str(TWO_ARMS)]) == 0
    out = capsys.readouterr().out
    assert ("  stage 1, in parallel: left 1 step(s); right 1 step(s)\n"
            "    left\n      1. reach: configuration 'move' on: robot, traj, pid, logger\n") in out
    assert ("  stage 2, in parallel: left application 'wave'\n    left, path 1: repeat\n"
            + "".join(f"      {n}. reach: stays in 'move' (new object only)\n" for n in range(1, 5))) in out
    assert ("    left, path 1: if: then\n      1. reach: stays in 'move' (new object only)\n"
            "    left, path 2: if: else: no job\n    right\n      1. reach: stays in 'move' (new object only)\n") in out


def test_pbo_check_gives_each_path_of_a_stage_its_switch_table_from_where_the_stage_before_left_it(tmp_path, capsys):
    from pbo_runtime.cli.main import main

    _, path = with_run(tmp_path, "  - parallel: {left: [reach: ready, rest]}\n"
                                 "  - parallel:\n      left:\n        - if: \"q_m[0] > 0.1\"\n          then: [reach: home]\n"
                                 "          else: [rest]\n  - parallel: {left: [reach: ready]}\n")
    text = path.read_text().replace("      move: [robot, traj, pid, logger]\n    jobs:\n",
                                    "      move: [robot, traj, pid, logger]\n      still: [robot, traj, pid]\n    jobs:\n"
                                    "      rest: {configuration: still, object: none}\n", 1)
    path.write_text(text)
    assert main(["check", str(path)]) == 0, capsys.readouterr()
    out = capsys.readouterr().out
    assert ("    left\n      1. reach: configuration 'move' on: robot, traj, pid, logger\n"
            "      2. rest: 'move' -> 'still': off logger; on nothing\n") in out
    assert ("    left, path 1: if: then\n      1. reach: 'still' -> 'move': off nothing; on logger\n"
            "    left, path 2: if: else\n      1. rest: stays in 'still' (new object only)\n") in out
    # stage 2 may leave either configuration on: stage 3's first switch is from nothing known
    assert out.endswith("  stage 3, in parallel: left 1 step(s)\n"
                        "    left\n      1. reach: configuration 'move' on: robot, traj, pid, logger\n")


def test_a_subsystem_goes_on_after_a_stage_only_once_every_other_is_done_and_the_lag_has_passed(tmp_path):
    from pbo_runtime.supervisor.stages import run_stages
    from tests.fake_job_host import FakeJobHost, fake_subsystem

    host = FakeJobHost(fake_subsystem(tmp_path), "pd")
    host.tick = 0.001  # as on the simulated clock: the join is looked for every tick
    plan = tmp_path / "me.json"
    plan.write_text(json.dumps({"join": str(tmp_path), "me": "me", "everyone": ["me", "other"], "lag": 0.003,
                                "stages": [{"steps": ["dwell"]}, None]}))

    def other_is_done_at_0_2(h) -> None:
        if h.now() >= 0.2 and not (tmp_path / "1.other").exists():
            (tmp_path / "1.other").write_text(repr(0.2))
        if h.now() >= 0.3 and not (tmp_path / "2.other").exists():
            (tmp_path / "2.other").write_text(repr(0.3))
    host.on_pump = other_is_done_at_0_2
    said: list[str] = []
    assert run_stages(host.job_control, str(plan), said.append) == ["dwell"]
    joined = [m.time for m in host.job_control.marks if re.fullmatch(r"stage \d+ joined", m.label)]
    assert joined[0] >= 0.203 - 1e-9 and joined[1] >= 0.303 - 1e-9
    assert said == ["stage 1 done here; joining me, other", "stage 2 done here; joining me, other"]


def arms_behind_ros2_control(tmp_path, left: str, right: str, run: str):
    """configs/two_arms.yaml with each arm driven through ros2_control, its options given, and `run:`."""
    text = TWO_ARMS.read_text()
    head = text[:text.index("\nrun:\n")]
    mujoco = "{arm: {driver: mujoco_arm, mode: torque, exclusive: true}}"
    assert head.count(mujoco) == 2
    for options in (left, right):
        head = head.replace(mujoco, "{arm: {driver: ros2_control, mode: torque, exclusive: true" + options + "}}", 1)
    path = tmp_path / "arms.yaml"
    path.write_text(head + "\nrun:\n" + run)
    return check_application(path), path


BOTH = "  - parallel: {left: [reach: ready], right: [reach: ready]}\n"


@pytest.mark.parametrize("left, right, run", [
    ("", "", BOTH),
    (", commands: /cell/commands", ", commands: cell/commands/", BOTH),
    (", domain: 4", ", domain: 4", "  - parallel: {left: [reach: home]}\n" + BOTH),
    ("", "",
     "  - parallel:\n      left: {app: wave}\n      right:\n        - try: [reach: ready]\n          fallback: [reach: home]\n"),
])
def test_two_subsystems_of_a_stage_driving_one_arm_are_refused_at_the_stage(tmp_path, left, right, run):
    result, path = arms_behind_ros2_control(tmp_path, left, right, run)
    assert [e.code for e in result.errors] == ["E814"], result.errors
    [error] = result.errors
    assert re.fullmatch(r"run: stage \d: subsystems 'left' and 'right' both drive the arm commanded on /\S+ \(DDS domain \d\): "
                        r"device 'arm' of 'left' \(task 'robot'\) and device 'arm' of 'right' \(task 'robot'\)", error.message)
    assert "its own devices" in error.hint
    stage = int(error.message.split()[2].rstrip(":"))
    stages = [number for number, line in enumerate(path.read_text().splitlines(), 1) if line.startswith("  - parallel:")]
    assert (error.line, error.column) == (stages[stage - 1], 5)  # at the stage's `parallel:`


@pytest.mark.parametrize("left, right, run", [
    (", commands: /left/commands", ", commands: /right/commands", BOTH),  # two arms, two topics
    (", domain: 1", ", domain: 2", BOTH),  # one topic on two domains
    ("", "", "  - parallel: {left: [reach: ready]}\n  - parallel: {right: [reach: ready]}\n"),  # one after the other
])
def test_subsystems_of_a_stage_with_their_own_arms_are_accepted(tmp_path, left, right, run):
    result, _ = arms_behind_ros2_control(tmp_path, left, right, run)
    assert result.errors == [], result.errors


def test_simulated_arms_of_the_same_name_are_each_their_own_plants():
    result = check_application(TWO_ARMS)  # both subsystems name their arm 'arm', each in its own plant
    assert all(set(result.application.subsystems[key].devices) == {"arm"} for key in ("left", "right"))
    assert [e.code for e in result.errors] == []
