"""The simulated clock (`pbo run --clock sim`): lockstep ticks, bit-for-bit replay, --out DIR.

The barrier is tested in-process with threads standing in for the plant and an RTPU; the rest
runs the real processes on the arm. Nothing here asserts a wall-clock time: the speed of a
simulated run is a benchmark figure (docs/performance.md), not a test.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest

from pbo_runtime import read_log
from pbo_runtime.cli.main import main
from pbo_runtime.clock.lockstep import LockstepMaster, LockstepParticipant
from pbo_runtime.clock.run_clock import PACE_TURN
from pbo_runtime.ipc import shm
from pbo_runtime.table.table import HEADER_WORDS, Header
from tests.support import DEMO, PBO, REPO, assert_nothing_left, children_of, read_until


def run_sim(tmp_path, config, *arguments: str, out: str = "out") -> tuple[subprocess.CompletedProcess, dict]:
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--no-live", "--out", str(tmp_path / out), *arguments],
                          cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    return done, json.loads((tmp_path / out / "report.json").read_text())


# --- the barrier -------------------------------------------------------------------------------


@pytest.fixture
def barrier():
    """A master with two participants ('plant', 'rtpu0') served by threads that log what they saw; a
    tick whose time (ns) is in `event_at` has an event queued for job control."""
    run_id = shm.new_run_id()
    header = np.zeros(HEADER_WORDS, dtype=np.int64)
    master = LockstepMaster("locktest", run_id, ["plant", "rtpu0"], 0.001, header)
    seen: list[tuple[str, bool, int]] = []
    event_at: set[int] = set()
    stop = threading.Event()

    def serve(role: str) -> None:
        participant = LockstepParticipant("locktest", run_id, role, header, ["plant", "rtpu0"],
                                          lambda: int(header[Header.SIM_TIME_NS]) in event_at)
        try:
            while not stop.is_set():
                new_tick = participant.wait()
                seen.append((role, new_tick, int(header[Header.SIM_TIME_NS])))
                participant.done()
        finally:
            participant.close()

    threads = [threading.Thread(target=serve, args=(role,), daemon=True) for role in ("plant", "rtpu0")]
    for thread in threads:
        thread.start()
    yield master, seen, event_at
    stop.set()
    for role in ("plant", "rtpu0"):
        master.step(role, lambda: None)  # let each thread see the stop
    master.close()
    for thread in threads:
        thread.join(timeout=5)


def test_each_tick_releases_the_plant_then_the_rtpus_in_turn(barrier):
    master, seen, _ = barrier
    for _ in range(3):
        master.advance(lambda: None)
    assert seen == [("plant", True, 0), ("rtpu0", True, 0),
                    ("plant", True, 1_000_000), ("rtpu0", True, 1_000_000),
                    ("plant", True, 2_000_000), ("rtpu0", True, 2_000_000)]
    assert master.now == pytest.approx(0.002)


def test_a_step_without_a_new_tick_only_serves_signals(barrier):
    master, seen, _ = barrier
    master.advance(lambda: None)
    master.step("rtpu0", lambda: None)
    assert seen[-1] == ("rtpu0", False, 0)


def test_the_participants_run_the_ticks_asked_for_among_themselves_in_the_same_order(barrier):
    master, seen, _ = barrier
    assert master.advance(lambda: None, ticks=3) == 3
    assert seen == [("plant", True, 0), ("rtpu0", True, 0),
                    ("plant", True, 1_000_000), ("rtpu0", True, 1_000_000),
                    ("plant", True, 2_000_000), ("rtpu0", True, 2_000_000)]
    assert master.ticks == 3 and master.now == pytest.approx(0.002)
    master.step("rtpu0", lambda: None)  # and a step between ticks is still one participant's, no new tick
    assert seen[-1] == ("rtpu0", False, 2_000_000) and master.ticks == 3


def test_a_tick_that_queued_an_event_hands_the_turn_back_to_job_control_after_that_tick(barrier):
    master, seen, event_at = barrier
    event_at.add(1_000_000)
    assert master.advance(lambda: None, ticks=5) == 2  # ticks 0 and 1 ms: job control takes the event now
    assert seen[-1] == ("rtpu0", True, 1_000_000) and master.now == pytest.approx(0.001)
    event_at.clear()
    assert master.advance(lambda: None, ticks=3) == 3
    assert [time for _, _, time in seen] == [t * 1_000_000 for t in range(5) for _ in range(2)]


def test_the_barrier_semaphores_are_private_and_gone_after_close():
    run_id = shm.new_run_id()
    master = LockstepMaster("locktest", run_id, ["rtpu0"], 0.001, np.zeros(HEADER_WORDS, dtype=np.int64))
    names = [n for n in os.listdir("/dev/shm") if run_id in n]
    assert len(names) == 2 and all(os.stat(f"/dev/shm/{n}").st_mode & 0o777 == 0o600 for n in names)
    master.close()
    assert [n for n in os.listdir("/dev/shm") if run_id in n] == []


# --- runs on the arm ---------------------------------------------------------------------------


@pytest.mark.multiprocess
def test_two_simulated_runs_write_identical_logs_even_under_load(tmp_path):
    """The replay promise: the second run shares the two CPUs with busy loops, and nothing changes."""
    _, quiet = run_sim(tmp_path, DEMO, "--duration", "3", out="quiet")
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        _, loaded = run_sim(tmp_path, DEMO, "--duration", "3", out="loaded")
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    first = (tmp_path / "quiet" / "pid_joint.mcap").read_bytes()
    second = (tmp_path / "loaded" / "pid_joint.mcap").read_bytes()
    assert first == second
    log = read_log(tmp_path / "quiet" / "pid_joint.mcap")
    assert len(log["time"]) == 301 and np.allclose(np.diff(log["time"]), 0.01)  # 0 to 3 s, every 10 ms, on its tick
    assert quiet["variables"]["q_m"] == loaded["variables"]["q_m"]
    assert quiet["clock"] == "sim" and quiet["tick"] == 0.001
    assert_nothing_left(quiet)
    assert_nothing_left(loaded)


@pytest.mark.multiprocess
def test_a_simulated_run_releases_every_cycle_and_steps_the_plant_once_per_tick(tmp_path):
    done, report = run_sim(tmp_path, DEMO, "--duration", "2")
    assert report["duration"] == pytest.approx(2.0)
    assert report["plant"]["steps"] == 2001  # ticks 0 .. 2000 ms
    for name, period in {"robot": 0.001, "pid": 0.001, "traj": 0.002, "logger": 0.01}.items():
        task = report["tasks"][name]
        assert task["cycles"] == round(2.0 / period) + 1, name
        assert task["overruns"] == task["missed"] == 0 and task["jitter_max"] < 1e-9  # rounding only
    assert "clock: simulated, 1 ms ticks; 2.00 s simulated in" in done.stdout
    assert sorted(os.listdir(tmp_path / "out")) == ["pid_joint.mcap", "report.json"]
    assert not (tmp_path / "runs").exists()  # with --out, the YAML's directory is not used


@pytest.mark.multiprocess
def test_a_paced_run_is_the_same_run_and_no_faster_than_its_pace(tmp_path):
    """`--pace 4`: one simulated second takes a quarter of a wall second at least (the last look at
    the wall clock is one turn of the ring before the end), and the run writes what an unpaced one does."""
    _, fast = run_sim(tmp_path, DEMO, "--duration", "1", out="fast")
    done, paced = run_sim(tmp_path, DEMO, "--duration", "1", "--pace", "4", out="paced")
    assert paced["running_wall_seconds"] >= (1.0 - PACE_TURN * 4) / 4
    assert (paced["pace"], fast["pace"]) == (4.0, None)
    assert "clock: simulated, 1 ms ticks, paced at 4x real time at most; 1.00 s simulated in" in done.stdout
    assert (tmp_path / "paced" / "pid_joint.mcap").read_bytes() == (tmp_path / "fast" / "pid_joint.mcap").read_bytes()
    assert paced["variables"] == fast["variables"] and paced["plant"]["steps"] == fast["plant"]["steps"]
    assert_nothing_left(paced)


@pytest.mark.parametrize("arguments, said", [
    (("--clock", "sim", "--pace", "0"), "--pace 0 is out of range: give simulated seconds per wall second from 0.01 to 1000"),
    (("--clock", "sim", "--pace", "nan"), "--pace nan is out of range"),
    (("--clock", "sim", "--pace", "5000"), "--pace 5000 is out of range"),
    (("--pace", "1"), "--pace slows the simulated clock; the real clock already runs at real time: add --clock sim"),
])
def test_a_pace_out_of_range_or_on_the_real_clock_is_refused_before_anything_starts(tmp_path, capsys, arguments, said):
    assert main(["run", str(DEMO), *arguments, "--no-live", "--out", str(tmp_path / "out")]) == 1
    assert said in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.multiprocess
def test_two_hundred_switches_on_the_arm_read_no_stale_input(tmp_path):
    """Issue 4's acceptance run, exact: no cycle of the critical task lost, no stale read, arm in tolerance."""
    config = REPO / "configs" / "switch_joint.yaml"
    _done, report = run_sim(tmp_path, config, "--alternate", "pid,pd", "--switches", "200", "--interval", "0.02")
    switches = report["switches"]
    assert len(switches) == 200
    assert [s["cycles_lost"]["robot"] for s in switches] == [0] * 200
    assert [s["stale_reads"]["robot"] for s in switches] == [0] * 200
    robot = report["tasks"]["robot"]
    assert robot["stale_reads"] == robot["cycles_lost_to_switches"] == robot["stable_cycles"] == 0
    assert all(s["latency"] == pytest.approx(0.001) for s in switches)  # the next tick on the grid
    q_m = np.array(report["variables"]["q_m"]["value"])
    q_d = np.array(report["variables"]["q_d"]["value"])
    assert np.max(np.abs(q_m - q_d)) < 0.02
    assert_nothing_left(report)


@pytest.mark.multiprocess
def test_a_consumer_that_switches_before_its_producers_is_counted_as_losing_a_cycle(tmp_path):
    """The count above can fail. In each tick rtpu0 runs before rtpu1: with the robot on rtpu0 and
    the controllers on rtpu1, at the switch's tick the robot reads the torque of the controller
    that is leaving, once per switch. (The shipped file puts the robot last for this reason.)"""
    config = tmp_path / "robot_first.yaml"
    text = (REPO / "configs" / "switch_joint.yaml").read_text()
    text = text.replace("robot: {module: robot_torque, rtpu: rtpu1,", "robot: {module: robot_torque, rtpu: rtpuX,")
    text = text.replace("rtpu: rtpu0,", "rtpu: rtpu1,").replace("rtpu: rtpuX,", "rtpu: rtpu0,")
    config.write_text(text)
    _, report = run_sim(tmp_path, config, "--alternate", "pid,pd", "--switches", "20", "--interval", "0.02")
    assert [s["cycles_lost"]["robot"] for s in report["switches"]] == [1] * 20
    robot = report["tasks"]["robot"]
    assert robot["cycles_lost_to_switches"] == 20
    assert "tau_u" in robot["last_cycle_lost"] and "still written by task" in robot["last_cycle_lost"]


@pytest.mark.multiprocess
def test_an_application_runs_its_jobs_on_the_simulated_clock(tmp_path):
    _, report = run_sim(tmp_path, REPO / "configs" / "switch_joint.yaml", "--app", "tour")
    assert report["jobs_done"] == ["reach", "settle", "reach"]
    q_m = np.array(report["variables"]["q_m"]["value"])
    assert np.max(np.abs(q_m - np.array([-0.2, -0.6, 0.4, 0.1, 0.3, -0.1]))) < 0.01


@pytest.mark.multiprocess
def test_periods_off_the_plant_timestep_are_refused_for_the_simulated_clock(tmp_path):
    config = tmp_path / "odd.yaml"
    config.write_text(DEMO.read_text().replace("period: 2 ms", "period: 2.5 ms"))
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--no-live"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode != 0
    assert "--clock sim steps the plant every 1 ms" in done.stderr
    assert "traj (2.5 ms)" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.multiprocess
def test_an_rtpu_killed_in_a_simulated_run_stops_the_run_and_leaves_nothing(tmp_path):
    report_path = tmp_path / "report.json"
    pbo = subprocess.Popen([*PBO, "run", str(DEMO), "--clock", "sim", "--duration", "600", "--no-live",
                            "--report", str(report_path)], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True)
    try:
        read_until(pbo, "is on")  # past the start: tasks spawned and on, ticks running
        (rtpu,) = [pid for pid, command in children_of(pbo.pid).items() if "--rtpu rtpu1" in command]
        os.kill(rtpu, signal.SIGKILL)
        out, err = pbo.communicate(timeout=60)
    finally:
        if pbo.poll() is None:
            pbo.kill()
    assert pbo.returncode == 2, out + err
    assert f"RTPU 'rtpu1' (pid {rtpu}) died (killed by SIGKILL) while hosting tasks: robot" in err
    assert_nothing_left(json.loads(report_path.read_text()))
