"""A dead RTPU restarted on the simulated clock (`--clock sim`), deterministically.

First the lockstep ring's recovery, with threads as its participants: wherever a participant dies
in tick N (holding the turn, handed it, or waiting while a live one holds it), the master brings
the ring to a stop, says who has yet to run tick N, and runs it for them; the new participant
joins from tick N + 1. Then whole runs: Figure 8 (configs/pid_joint.yaml, at its own speed) with a
restart policy and a fault_injector that aborts the controller's RTPU at three simulated times
mid-move: the robot interface on the other RTPU loses no cycle, the arm keeps to its path and
ends on its goal, and a second run writes the same log, bit for bit. Past the policy the run
stops and says why.
"""

from __future__ import annotations

import json
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

from pbo_runtime import read_log
from pbo_runtime.clock.lockstep import LockstepMaster, LockstepParticipant, RingStop, RingStuck
from pbo_runtime.ipc import shm
from pbo_runtime.table.table import HEADER_WORDS
from tests.support import (
    DEMO,
    DEMO_GOAL,
    PBO,
    assert_nothing_left,
    config_copy,
    excursion_from_path,
    kill_and_await_restart,
    killed_on_failure,
    run_output,
    start_run,
)

ROLES = ["plant", "a", "b"]


class Died(Exception):
    """The master noticed a participant's death (a fake of `RtpuDied`, for the ring's unit tests)."""


class Ring:
    """A lockstep master with threads as its participants; each logs (role, tick) of each tick it runs.

    A participant may die in tick `dies_in` (holding the turn: no hand-over), after tick
    `dies_after` (waiting: a turn handed to it never comes back), in its first step between ticks
    (`dies_in_step`: a module that aborts in init), or hold tick `holds` until `release` is set.
    """

    def __init__(self) -> None:
        self.run_id = shm.new_run_id()
        self.header = np.zeros(HEADER_WORDS, dtype=np.int64)
        self.master = LockstepMaster("ringtest", self.run_id, ROLES, 0.001, self.header)
        self.ran: list[tuple[str, int]] = []
        self.threads: dict[str, threading.Thread] = {}
        self.stopping = False
        self.release = threading.Event()

    def join(self, role: str, dies_in: int = 0, dies_after: int = 0, holds: int = 0, dies_in_step: bool = False) -> None:
        participant = LockstepParticipant("ringtest", self.run_id, role, self.header, ROLES)

        def serve() -> None:
            try:
                while True:
                    new_tick = participant.wait()
                    tick = participant.last_tick
                    if self.stopping:
                        participant.done()
                        return
                    if (new_tick and tick == dies_in) or (not new_tick and dies_in_step):
                        return  # dead, with the turn
                    if new_tick:
                        self.ran.append((role, tick))
                    if new_tick and tick == holds:
                        self.release.wait(10)
                    participant.done()
                    if new_tick and tick == dies_after:
                        return  # dead, waiting for a turn
            finally:
                participant.close()

        self.threads[role] = threading.Thread(target=serve, daemon=True)
        self.threads[role].start()

    def death_of(self, role: str):
        def while_waiting() -> None:
            if not self.threads[role].is_alive():
                raise Died(role)
        return while_waiting

    def ticks_of(self, role: str) -> list[int]:
        return [tick for who, tick in self.ran if who == role]

    def close(self) -> None:
        self.stopping = True
        for role, thread in self.threads.items():
            if thread.is_alive():
                self.master.step(role, lambda: None)
            thread.join(timeout=5)
        self.master.close()


@pytest.fixture
def ring():
    made = Ring()
    yield made
    made.close()


@pytest.mark.parametrize("death", [{"dies_in": 3}, {"dies_after": 2}], ids=["holding the turn", "handed the turn"])
def test_a_participant_dead_in_tick_n_costs_the_others_no_tick_and_its_new_one_runs_from_tick_n_plus_one(ring, death):
    ring.join("plant")
    ring.join("a", **death)
    ring.join("b")
    with pytest.raises(Died):
        ring.master.advance(ring.death_of("a"), ticks=5)
    stop = ring.master.recover("a", lambda: None)
    assert stop == RingStop(tick=3, unfinished=("b",), stuck_at_dead=True)
    assert ring.master._go["a"].value == 0  # a turn handed to the dead one is not its successor's
    ring.master.finish_tick(stop, lambda: None)
    ring.join("a")  # its new process: ticks 1 to 3 are behind it
    ring.master.step("a", lambda: None)  # a step between ticks (spawning its tasks) is no tick
    assert ring.master.advance(lambda: None, ticks=2) == 2
    assert ring.ticks_of("plant") == ring.ticks_of("b") == [1, 2, 3, 4, 5]
    assert ring.ticks_of("a") == [1, 2, 4, 5]  # its tick 3 is lost with it
    assert ring.master.ticks == 5 and ring.master.now == pytest.approx(0.004)


def test_a_turn_a_live_participant_held_when_the_ring_stopped_comes_back_and_the_tick_goes_on_after_it(ring):
    ring.join("plant", holds=3)
    ring.join("a", dies_after=2)
    ring.join("b")
    with pytest.raises(Died):
        ring.master.advance(ring.death_of("a"), ticks=5)  # the plant holds tick 3 while a's death is noticed

    def let_the_plant_go() -> None:
        ring.release.set()

    stop = ring.master.recover("a", let_the_plant_go)  # the plant ends its turn after the ring's end was cleared
    assert stop == RingStop(tick=3, unfinished=("b",), stuck_at_dead=False)
    ring.master.finish_tick(stop, lambda: None)
    ring.join("a")
    ring.master.advance(lambda: None, ticks=1)
    assert ring.ticks_of("plant") == ring.ticks_of("b") == [1, 2, 3, 4]
    assert ring.ticks_of("a") == [1, 2, 4]


def test_a_live_participant_that_never_hands_the_turn_back_fails_the_recovery_when_the_master_gives_up(ring):
    ring.join("plant", holds=3)
    ring.join("a", dies_after=2)
    ring.join("b")
    with pytest.raises(Died):
        ring.master.advance(ring.death_of("a"), ticks=5)
    with pytest.raises(RingStuck, match=r"^plant did not hand the turn back after a died$"):
        ring.master.recover("a", lambda: True)
    ring.release.set()  # (for the fixture's stop)


def test_a_participant_dead_in_a_step_between_ticks_leaves_no_tick_to_finish(ring):
    ring.join("plant")
    ring.join("a", dies_in_step=True)  # as a module aborting in init while its task is spawned
    ring.join("b")
    ring.master.advance(lambda: None, ticks=2)
    with pytest.raises(Died):
        ring.master.step("a", ring.death_of("a"))
    assert ring.master.recover("a", lambda: None) == RingStop(tick=2, unfinished=(), stuck_at_dead=True)
    ring.join("a")
    ring.master.advance(lambda: None, ticks=1)
    assert ring.ticks_of("a") == [1, 2, 3] and ring.ticks_of("b") == [1, 2, 3]


# --- whole runs ------------------------------------------------------------------------------

POLICY = ("rtpus: [rtpu0, rtpu1]", "rtpus: [rtpu0, rtpu1]\nrestart: {max: 3, within: 10 min}")
LOGGER_BESIDE_THE_ROBOT = ("logger: {module: data_logger, rtpu: rtpu0", "logger: {module: data_logger, rtpu: rtpu1")
REACHED = 0.005  # rad: every joint within this of its goal at the end, as on the real clock
EXCURSION_LIMIT = 0.05  # rad
CRASH_TIMES = (0.3, 0.4, 0.5)  # s: mid-move, at the demo's own speed (0.3 s in, it cruises at 1 rad/s)
DURATION = 8.0  # s simulated: the move and its settling end well before
RUN_SAFETY_NET = 300.0  # wall seconds: a net for a run that never ends, not a timing


def crashing_copy(folder: Path, subsystem: str, policy: tuple[str, str] = POLICY) -> Path:
    """configs/pid_joint.yaml with a restart policy and a fault_injector aborting rtpu0 at CRASH_TIMES."""
    at = ", ".join(f"{t:g}" for t in CRASH_TIMES)
    return config_copy(DEMO, folder, subsystem, (
        policy, LOGGER_BESIDE_THE_ROBOT,
        ("  logger: {module: data_logger", f"  crash: {{module: fault_injector, rtpu: rtpu0, period: 10 ms, "
                                           f"params: {{fault: abort, at: [{at}]}}}}\n  logger: {{module: data_logger"),
        ("joint_pid: [robot, traj, pid, logger]", "joint_pid: [robot, traj, pid, crash, logger]")))


def run_sim(folder: Path, config: Path, out: str) -> tuple[subprocess.CompletedProcess, dict]:
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--no-live", "--duration", f"{DURATION:g}",
                           "--out", str(folder / out)], cwd=folder, capture_output=True, text=True, timeout=300)
    assert "Traceback" not in done.stderr, done.stderr
    return done, json.loads((folder / out / "report.json").read_text())


@pytest.mark.multiprocess
def test_on_the_simulated_clock_three_crashes_cost_the_robot_no_cycle_and_replay_bit_for_bit(tmp_path):
    config = crashing_copy(tmp_path, "simrestart_thrice")
    first, report = run_sim(tmp_path, config, "first")
    assert first.returncode == 0, first.stdout + first.stderr
    assert report["failure"] == "" and report["stopped_by"] == "duration"
    restarts = report["restarts"]
    assert [(r["rtpu"], r["cause"]) for r in restarts] == [("rtpu0", "killed by SIGABRT")] * 3
    assert [r["died_at"] for r in restarts] == pytest.approx(list(CRASH_TIMES))
    assert all(r["seconds"] == 0 for r in restarts)  # between two ticks: no simulated time
    assert all(r["tasks_on"] == ["traj", "pid", "crash"] for r in restarts)
    # the robot interface ran every release: ticks 0 .. DURATION, one cycle each
    robot = report["tasks"]["robot"]
    assert robot["state"] == "ON" and robot["cycles"] == round(DURATION / 0.001) + 1
    assert report["plant"]["steps"] == round(DURATION / 0.001) + 1
    log = read_log(tmp_path / "first" / "pid_joint.mcap")
    assert excursion_from_path(log["q_m"], log["q_m"][0], DEMO_GOAL) < EXCURSION_LIMIT
    # A restart takes no simulated time, so the new controller takes over an arm still moving: the
    # trajectory goes on from the reference its predecessor wrote a tick before, and the PID fades
    # the torque it left out. The arm gets there and stays: nothing of the dead one's torque is left.
    assert np.abs(log["q_m"][-1] - DEMO_GOAL).max() < REACHED and np.abs(log["q_m"][-1] - log["q_m"][-100]).max() < 0.0005
    assert_nothing_left(report)
    # the same crashes at the same ticks: the same run, bit for bit
    second, again = run_sim(tmp_path, config, "second")
    assert second.returncode == 0, second.stderr
    assert (tmp_path / "first" / "pid_joint.mcap").read_bytes() == (tmp_path / "second" / "pid_joint.mcap").read_bytes()
    assert again["variables"] == report["variables"]
    assert [r["died_at"] for r in again["restarts"]] == [r["died_at"] for r in restarts]
    assert_nothing_left(again)


@pytest.mark.multiprocess
def test_on_the_simulated_clock_an_rtpu_killed_anywhere_in_a_tick_costs_the_robot_no_cycle(tmp_path):
    """SIGKILL lands wherever the ring is: in rtpu0's turn, or while it waits and the turn is handed to it."""
    config = config_copy(DEMO, tmp_path, "simrestart_killed", (POLICY, LOGGER_BESIDE_THE_ROBOT))
    report_path = tmp_path / "report.json"
    # it ends by its duration, not Ctrl-C (which may cut its last tick after the plant's step); a
    # restart takes no simulated time, so the kills use little of it
    run = start_run(config, tmp_path, "--clock", "sim", "--duration", "10", "--report", str(report_path),
                    "--out", str(tmp_path / "out"))
    with killed_on_failure(run):
        killed = [kill_and_await_restart(run) for _ in range(3)]
        _, err = run_output(run, RUN_SAFETY_NET)
    assert "Traceback" not in err, err
    report = json.loads(report_path.read_text())
    assert report["failure"] == "" and report["stopped_by"] == "duration"
    assert [r["pid"] for r in report["restarts"]] == killed
    assert report["tasks"]["robot"]["cycles"] == report["plant"]["steps"] == 10_001  # ticks 0 .. 10 s, each ran in full
    assert report["tasks"]["pid"]["state"] == "ON"
    assert_nothing_left(report)


@pytest.mark.multiprocess
def test_on_the_simulated_clock_a_death_past_the_policy_stops_the_run_and_says_why(tmp_path):
    config = crashing_copy(tmp_path, "simrestart_once", ("rtpus: [rtpu0, rtpu1]",
                                                         "rtpus: [rtpu0, rtpu1]\nrestart: {max: 1, within: 10 min}"))
    done, report = run_sim(tmp_path, config, "out")
    assert done.returncode == 2, done.stderr
    assert "RTPU 'rtpu0'" in done.stderr and "died (killed by SIGABRT)" in done.stderr
    assert "it died 2 times within 600 s, more than its restart policy allows (restart: {max: 1, within: 600 s})" in done.stderr
    assert [(r["died_at"], r["seconds"] is None) for r in report["restarts"]] == [(pytest.approx(CRASH_TIMES[0]), False),
                                                                                  (pytest.approx(CRASH_TIMES[1]), True)]
    assert_nothing_left(report)
