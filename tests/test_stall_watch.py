"""A task ON whose cycle never returns is seen from outside, reported, and ends the run as a failure."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from pbo_runtime.config.model import TaskSpec
from pbo_runtime.supervisor.stall_watch import STALL_FLOOR, StallWatch
from tests.support import read_until


def spec(name: str, index: int, period: float = 0.001, aperiodic: bool = False) -> TaskSpec:
    return TaskSpec(name=name, module="fault_injector", rtpu="rtpu0", period=period, index=index, aperiodic=aperiodic)


class FakeCycleCounts:
    """The table's cycle counts, as a unit test sets them (a fake, in this test only)."""

    def __init__(self) -> None:
        self.counts: dict[int, float] = {}

    def __call__(self, index: int) -> float:
        return self.counts.get(index, 0.0)


def test_a_task_whose_cycle_count_stops_moving_is_reported_once_and_again_when_it_moves():
    counts, said = FakeCycleCounts(), []
    watch = StallWatch([spec("pid", 0)], counts, said.append)
    on = {"pid": "ON"}
    for step in range(5):  # cycling: no stall
        counts.counts[0] = step * 100
        watch.check(step * 0.1, on)
    for now in (0.5, 0.7, 0.85):  # stuck since 0.4 s: within the half-second floor
        watch.check(now, on)
    assert watch.episodes == [] and said == []
    watch.check(0.91 + STALL_FLOOR, on)
    watch.check(2.0, on)
    assert [(s.task, s.since, s.until) for s in watch.episodes] == [("pid", 0.4, None)]
    assert said == ["task 'pid' (rtpu0, 1 ms period) has finished no cycle for 1.01 s: its module's cycle has not "
                    "returned, or rtpu0 gets no CPU"]
    counts.counts[0] = 401
    watch.check(2.5, on)
    assert (watch.episodes[0].until, watch.open) == (2.5, {})
    assert said[-1] == "task 'pid' (rtpu0) finishes cycles again, after 2.10 s without one"


def test_a_task_off_or_aperiodic_is_never_stalled_and_a_slow_task_waits_ten_periods():
    counts, said = FakeCycleCounts(), []
    tasks = [spec("off", 0), spec("server", 1, aperiodic=True), spec("slow", 2, period=0.2)]
    watch = StallWatch(tasks, counts, said.append)
    states = {"off": "OFF", "server": "ON", "slow": "ON"}
    for now in (0.0, 1.0, 1.99):
        watch.check(now, states)
    assert watch.episodes == []  # 'slow' has 2 s (10 periods) before it counts
    watch.check(2.01, states)
    assert [s.task for s in watch.episodes] == ["slow"]
    states["slow"] = "OFF"  # turned off: its count may rest, and it is watched afresh when ON again
    watch.check(5.0, states)
    states["slow"] = "ON"
    watch.check(5.1, states)
    assert [s.task for s in watch.episodes] == ["slow"] and len(said) == 1


HANGING_MODULE = textwrap.dedent('''
    from pbo_runtime import InVar, NoParams, PortBasedObject, Status


    class HangsAfter500(PortBasedObject):
        """Cycles 500 times, then never returns from its cycle (a module with an endless loop)."""

        Params = NoParams
        watched = InVar("q_m", dtype="any", shape=None, doc="read, not used")

        def init(self, params):
            self.cycles = 0

        def cycle(self):
            self.cycles += 1
            while self.cycles > 500:
                pass
            return Status.CONTINUE
''')

SUBSYSTEM = textwrap.dedent('''
    subsystem: hang_test
    rtpus: [rtpu0, rtpu1]
    dims: {NDOF: 6}
    variables:
      q_m: {type: float64, shape: [NDOF], initial: 0.0, doc: "a joint position, rad"}
    tasks:
      stuck: {module: hangs_after_500, rtpu: rtpu0, period: 1 ms, ports: {watched: q_m}}
      fine: {module: fault_injector, rtpu: rtpu1, period: 1 ms, params: {fail_after: 1000000000}, ports: {watched: q_m}}
    configurations:
      both: [stuck, fine]
''')


@pytest.fixture
def library_with_a_hanging_module(tmp_path) -> dict[str, str]:
    """A third-party module library on PYTHONPATH, registered through the pbo.modules entry point."""
    library = tmp_path / "library"
    (library / "hang_library-0.1.dist-info").mkdir(parents=True)
    (library / "hang_library.py").write_text(HANGING_MODULE)
    (library / "hang_library-0.1.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: hang-library\nVersion: 0.1\n")
    (library / "hang_library-0.1.dist-info" / "entry_points.txt").write_text(
        "[pbo.modules]\nhangs_after_500 = hang_library:HangsAfter500\n")
    return {**os.environ, "PYTHONPATH": str(library)}


@pytest.mark.multiprocess
def test_a_module_that_never_returns_is_reported_stalled_and_the_run_fails_with_its_figures(tmp_path,
                                                                                           library_with_a_hanging_module):
    # The run waits until the stall is reported, then Ctrl-C: on a slow machine the 500 cycles take longer, nothing else
    (tmp_path / "hang.yaml").write_text(SUBSYSTEM)
    report_path = tmp_path / "report.json"
    run = subprocess.Popen([sys.executable, "-m", "pbo_runtime.cli", "run", "hang.yaml", "--duration", "0",
                            "--report", str(report_path), "--no-live"], cwd=tmp_path, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, env=library_with_a_hanging_module)
    try:
        seen = read_until(run, "has finished no cycle for").splitlines()
        if not seen or "has finished no cycle for" not in seen[-1]:  # its output ended: the run did too
            pytest.fail("the run ended without reporting a stall:\n" + "\n".join(seen) + run.communicate(timeout=60)[1])
        assert seen[-1].startswith("pbo: task 'stuck' (rtpu0, 1 ms period) has finished no cycle for"), seen
        run.send_signal(signal.SIGINT)
        out, err = run.communicate(timeout=90)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 2 and "Traceback" not in err, out + err
    assert "task 'stuck' (rtpu0) finished no cycle from" in out
    assert "error: rtpu0 did not stop within 5 s and was killed: the kill components of its tasks did not run " \
           "(stalled: stuck)" in err
    report = json.loads(report_path.read_text())
    [stall] = report["stalls"]
    assert (stall["task"], stall["rtpu"], stall["to"], stall["rtpu_killed"]) == ("stuck", "rtpu0", None, True)
    assert stall["from"] >= 0.0 and report["unstopped"] == ["rtpu0"]
    assert report["tasks"]["stuck"]["cycles"] == 500 and report["tasks"]["stuck"]["from_table"] is True
    # the other RTPU went on and reported its task's figures itself
    assert report["tasks"]["fine"]["cycles"] > 0 and "from_table" not in report["tasks"]["fine"]
    assert [n for n in os.listdir("/dev/shm") if report["run_id"] in n] == []


@pytest.mark.multiprocess
def test_on_the_simulated_clock_a_tick_that_never_ends_is_reported_and_ctrl_c_still_stops_the_run(
        tmp_path, library_with_a_hanging_module):
    (tmp_path / "hang.yaml").write_text(SUBSYSTEM)
    report_path = tmp_path / "report.json"
    run = subprocess.Popen([sys.executable, "-m", "pbo_runtime.cli", "run", "hang.yaml", "--clock", "sim", "--duration", "3",
                            "--report", str(report_path), "--no-live"], cwd=tmp_path, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, env=library_with_a_hanging_module)
    try:
        # the notice comes 2 s of wall time into the tick that never ends
        seen = read_until(run, "has not finished the tick").splitlines()
        if not seen or "has not finished the tick" not in seen[-1]:  # its output ended: the run did too
            pytest.fail("the run ended without reporting the tick:\n" + "\n".join(seen) + run.communicate(timeout=60)[1])
        assert seen[-1].startswith("pbo: rtpu0 has not finished the tick at 0.500 s for 2.0 s of wall time: a cycle there "
                                   "has not returned (Ctrl-C stops the run)"), seen
        run.send_signal(signal.SIGINT)
        out, err = run.communicate(timeout=90)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 2 and "Traceback" not in err, out + err
    assert "(stopped by Ctrl-C)" in out and "error: rtpu0 did not stop within 5 s and was killed" in err
    report = json.loads(report_path.read_text())
    assert report["unstopped"] == ["rtpu0"] and report["tasks"]["stuck"]["cycles"] == 500
    assert [n for n in os.listdir("/dev/shm") if report["run_id"] in n] == []
