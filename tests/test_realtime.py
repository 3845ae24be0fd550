"""An RTPU's real-time settings are asked for and reported, never assumed (run in a child process)."""

from __future__ import annotations

import ctypes
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import REPO, assert_ended_well

APPLY = ("import json, sys; from rtpu import _realtime; print(json.dumps(_realtime.apply({cpu}, {fifo}, "
         "_realtime.fifo_priority({critical}))))")


def applied(cpu, fifo: bool, critical: bool = False) -> dict:
    done = subprocess.run([sys.executable, "-c", APPLY.format(cpu=cpu, fifo=fifo, critical=critical)],
                          capture_output=True, text=True,
                          cwd=REPO, timeout=60)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.multiprocess
def test_an_rtpu_is_pinned_to_the_cpu_its_yaml_names():
    assert applied(0, False) == {"timer_slack": "1 ns", "cpu": "0", "scheduler": "SCHED_OTHER"}


@pytest.mark.multiprocess
def test_a_cpu_the_machine_does_not_have_is_reported_not_fatal():
    assert applied(4096, False)["cpu"].startswith("not pinned: CPU 4096: ")


@pytest.mark.multiprocess
def test_sched_fifo_is_reported_as_granted_or_refused_with_the_reason():
    scheduler = applied(None, True)["scheduler"]
    assert scheduler == "SCHED_FIFO 50" or scheduler.startswith("SCHED_OTHER: SCHED_FIFO refused (")


@pytest.mark.multiprocess
def test_an_rtpu_hosting_a_critical_task_runs_above_the_others_and_below_the_plant():
    from pbo_runtime.supervisor.plant_host import PLANT_FIFO_PRIORITY
    from rtpu._realtime import CRITICAL_FIFO_PRIORITY, FIFO_PRIORITY

    scheduler = applied(None, True, critical=True)["scheduler"]
    assert scheduler == f"SCHED_FIFO {CRITICAL_FIFO_PRIORITY}" or scheduler.startswith("SCHED_OTHER: SCHED_FIFO refused (")
    assert FIFO_PRIORITY < CRITICAL_FIFO_PRIORITY < PLANT_FIFO_PRIORITY


CHILD_POLICY = ("import json, os, subprocess, sys; from rtpu import _realtime; "
                "granted = _realtime.apply(None, True)['scheduler']; "
                "child = subprocess.run([sys.executable, '-c', 'import os; print(os.sched_getscheduler(0))'], "
                "capture_output=True, text=True).stdout; print(json.dumps([granted, int(child)]))")


@pytest.mark.multiprocess
def test_a_process_a_task_starts_begins_at_sched_other_not_at_the_rtpus_sched_fifo():
    """A log's encoder or a special-purpose processor inheriting SCHED_FIFO 50 held the executive off its
    CPU for its interpreter's start-up (a 108 ms late release and the arm's watchdog in `make run`)."""
    done = subprocess.run([sys.executable, "-c", CHILD_POLICY], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert done.returncode == 0, done.stderr
    granted, child_policy = json.loads(done.stdout)
    assert child_policy == os.SCHED_OTHER, (granted, child_policy)


POSTING = """
import json, os
from pbo_runtime.supervisor.posting import POSTING_FIFO_PRIORITY, at_realtime_priority
before = os.sched_getscheduler(0)
with at_realtime_priority() as raised:
    inside = [os.sched_getscheduler(0), os.sched_getparam(0).sched_priority]
print(json.dumps([raised, before, inside, os.sched_getscheduler(0), POSTING_FIFO_PRIORITY]))
"""


@pytest.mark.multiprocess
def test_a_plan_is_posted_at_real_time_priority_below_the_rtpus_and_the_supervisor_goes_back_after():
    from rtpu._realtime import FIFO_PRIORITY

    done = subprocess.run([sys.executable, "-c", POSTING], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert done.returncode == 0, done.stderr
    raised, before, inside, after, priority = json.loads(done.stdout)
    assert after == before == os.SCHED_OTHER
    assert priority < FIFO_PRIORITY
    # refused (no CAP_SYS_NICE, no ulimit -r): the block runs all the same, as the supervisor ran
    assert inside == ([os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, priority] if raised else [os.SCHED_OTHER, 0])


def test_the_real_clock_asks_for_sched_fifo_by_default_and_the_simulated_clock_does_not():
    from pbo_runtime.cli.main import _parser
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.supervisor.run_options import RunOptions
    from pbo_runtime.supervisor.supervisor import Supervisor

    subsystem = load_subsystem(REPO / "configs" / "pid_joint.yaml")
    assert Supervisor(subsystem).fifo is True
    assert Supervisor(subsystem, options=RunOptions(clock="sim")).fifo is False  # it waits on ticks, not on time
    assert Supervisor(subsystem, options=RunOptions(fifo=False)).fifo is False
    assert Supervisor(subsystem, options=RunOptions(clock="sim", fifo=True)).fifo is True
    fifo_of = {tuple(flags): _parser().parse_args(["run", "x.yaml", *flags]).fifo for flags in ([], ["--no-fifo"], ["--fifo"])}
    assert fifo_of == {(): None, ("--no-fifo",): False, ("--fifo",): True}


def _without_cap_sys_nice() -> None:
    """In the child before exec: drop CAP_SYS_NICE from the bounding set, so root execs without it."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP, CAP_SYS_NICE)")


PR_CAPBSET_DROP, CAP_SYS_NICE = 24, 23  # <linux/prctl.h>, <linux/capability.h>


@pytest.mark.multiprocess
def test_a_run_the_os_refuses_sched_fifo_runs_on_under_sched_other_and_says_what_it_needs(tmp_path):
    if os.geteuid() != 0 and _fifo_allowed_here():
        pytest.skip("this user may use SCHED_FIFO without root: nothing here makes the OS refuse it")
    report_path = tmp_path / "report.json"
    done = subprocess.run([sys.executable, "-m", "pbo_runtime.cli", "run", str(REPO / "configs" / "pid_joint.yaml"),
                           "--duration", "1", "--report", str(report_path), "--no-live"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=180,
                          preexec_fn=_without_cap_sys_nice if os.geteuid() == 0 else None)
    assert "Traceback" not in done.stderr, done.stdout + done.stderr
    report = json.loads(report_path.read_text())
    assert_ended_well(done.returncode, report, done.stdout + done.stderr)
    assert report["stopped_by"] == "duration" and set(report["realtime"]) == {"rtpu0", "rtpu1"}
    for rtpu, settings in report["realtime"].items():
        assert settings["scheduler"].startswith("SCHED_OTHER: SCHED_FIFO refused ([Errno 1] Operation not permitted); "
                                                "it needs CAP_SYS_NICE (root has it) or a real-time priority limit "
                                                "(ulimit -r) of 60"), settings
        assert f"{rtpu}: cpu any, SCHED_OTHER: SCHED_FIFO refused (" in done.stdout


def _fifo_allowed_here() -> bool:
    return applied(None, True)["scheduler"].startswith("SCHED_FIFO")


SLOW_PLANT = """
subsystem: slow_plant
rtpus: [rtpu0]
plant: {type: fake_slow_plant, model: none, timestep: 1 ms}
dims: {NDOF: 6}
variables:
  q_m: {type: float64, shape: [NDOF], initial: 0.0, doc: "a joint position, rad"}
tasks:
  watch: {module: fault_injector, rtpu: rtpu0, period: 1 ms, params: {fail_after: 1000000000}, ports: {watched: q_m}}
configurations:
  c: [watch]
"""

FAKE_SLOW_PLANT = '''"""A fake plant for one test: each step sleeps three timesteps, so it falls behind on any machine."""

import time


class FakeSlowPlant:
    def __init__(self, registers_name, model, timestep, options):
        self.timestep = timestep

    def step(self):
        time.sleep(3 * self.timestep)

    def close(self):
        pass
'''


def register_fake_slow_plant(folder: Path) -> dict[str, str]:
    """Install the fake plant in `folder` under the entry point `pbo.plants: fake_slow_plant`; the env that finds it."""
    (folder / "fake_slow_plant.py").write_text(FAKE_SLOW_PLANT)
    dist_info = folder / "fake_slow_plant-0.dist-info"
    dist_info.mkdir()
    (dist_info / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-slow-plant\nVersion: 0\n")
    (dist_info / "entry_points.txt").write_text("[pbo.plants]\nfake_slow_plant = fake_slow_plant:FakeSlowPlant\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(folder), os.environ.get("PYTHONPATH")]))}


@pytest.mark.multiprocess
def test_a_plant_that_cannot_keep_up_leaves_sched_fifo_instead_of_holding_a_cpu_and_says_so(tmp_path):
    # Each step of the fake plant takes three timesteps, so every step after the first is late and the
    # plant falls at least two timesteps further behind each time: 0.1 s behind within 50 steps, on any machine.
    env = register_fake_slow_plant(tmp_path)
    (tmp_path / "slow.yaml").write_text(SLOW_PLANT)
    done = subprocess.run([sys.executable, "-m", "pbo_runtime.cli", "run", "slow.yaml", "--duration", "1.5",
                           "--report", "report.json", "--no-live"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    report = json.loads((tmp_path / "report.json").read_text())
    # (a loaded machine may starve the plant's first steps: a timing fault, exit 2, not this test's matter)
    assert_ended_well(done.returncode, report, done.stdout + done.stderr)
    if not report["realtime"]["rtpu0"]["scheduler"].startswith("SCHED_FIFO"):
        pytest.skip("SCHED_FIFO is refused here: the plant never had it to leave")
    plant = report["plant"]
    # late is counted before a step and steps after it, so the step the stop interrupted may be late but not counted
    assert plant["steps"] - 1 <= plant["late"] <= plant["steps"] and plant["left_fifo_behind"] >= 0.1, plant
    assert "and left SCHED_FIFO, so as not to hold a CPU above the RTPUs" in done.stdout.replace("\n", " ")


@pytest.mark.multiprocess
def test_every_thread_of_a_running_rtpu_but_its_executive_runs_below_every_executive(tmp_path):
    """A log's writer, the background work: threads that share the executive's GIL run at the lowest
    SCHED_FIFO priority, so no process of the machine preempts one while it holds the GIL."""
    from tests.support import demo_copy, run_output, run_processes, start_run

    run = start_run(demo_copy(tmp_path, "threads_below"), tmp_path, "--duration", "30")
    try:
        policies = {}
        for role, pid in run_processes(run).items():
            if role == "plant":
                continue
            for thread in sorted(int(name) for name in os.listdir(f"/proc/{pid}/task")):
                policies[(role, thread == pid)] = policies.get((role, thread == pid), set()) | {
                    (os.sched_getscheduler(thread) & ~os.SCHED_RESET_ON_FORK, os.sched_getparam(thread).sched_priority)}
    finally:
        run.send_signal(2)
        run_output(run)
    if policies[("rtpu0", True)] != {(os.SCHED_FIFO, 50)}:
        pytest.skip(f"SCHED_FIFO refused here: rtpu0 runs {policies[('rtpu0', True)]}")
    assert policies[("rtpu0", False)] == {(os.SCHED_FIFO, 1)}  # its logger's writer and the background thread
    assert policies[("rtpu1", False)] == {(os.SCHED_FIFO, 1)}
