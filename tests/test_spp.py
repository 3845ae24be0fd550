"""The special-purpose processor (TR §4.6.3): an emulated accelerator in a process of its own, behind its driver.

In one process (the test's, as a task's would be): the driver starts the processor, downloads
the arm's Jacobian routine, and gets exactly what Pinocchio computes; a cycle's call allocates
nothing and never waits, even on a stopped processor; a dead processor is a named fault, and
nothing is left in /dev/shm whichever side dies. End to end on the simulated clock:
configs/visual_servoing_spp.yaml (Figure 13 with fk on the processor) tracks its target with the
processor's timing in the summary, and killing the processor mid-run puts fk in ERROR naming it.
On the real clock, under SCHED_FIFO RTPUs, the processor runs just below them once loaded and keeps up.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pinocchio
import pytest

from drivers.spp.driver import ProcessorError, SpecialPurposeProcessor
from modules.fk_jacobian_spp import FkJacobianSpp
from pbo_runtime import arm_model
from pbo_runtime.clock.clocks import ManualClock
from pbo_runtime.config.model import DeviceSpec
from pbo_runtime.ipc.shm import children_of, pid_alive
from pbo_runtime.reports.lexicon import drivers
from pbo_runtime.table.table import TaskState
from pbo_runtime.task.lifecycle import Task
from rtpu._executive import Executive
from tests.support import (
    PBO,
    REPO,
    RUNS,
    FakeSignals,
    Ticker,
    allocation_peak,
    arm_tables,
    assert_ended_well,
    assert_nothing_left,
    killed_on_failure,
    one_array,
    read_until,
    robot_state_table,
    run_output,
    run_processes,
    run_until,
    start_run,
    task_spec,
    unique_name,
    until,
)

CONFIG = REPO / "configs" / "visual_servoing_spp.yaml"
Q = np.array([0.1, -0.5, 0.4, 0.1, 0.2, 0.3])


def _registers() -> str:
    """A name like a run's plant registers (/pbo.<subsystem>.<run id>.plant): the processor's names derive from it."""
    return unique_name("plant")


def _left(spp_segment: str) -> list[str]:
    base = spp_segment.lstrip("/")
    return [n for n in os.listdir("/dev/shm") if base in n]


def _pinocchio(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    arm, ee = arm_tables("puma560")
    model = arm_model(arm, ee)
    data = model.createData()
    frame = model.getFrameId("ee")
    pinocchio.computeJointJacobians(model, data, q)
    placement = pinocchio.updateFramePlacement(model, data, frame)
    x = np.concatenate([placement.translation, pinocchio.log3(placement.rotation)])
    return x, pinocchio.getFrameJacobian(model, data, frame, pinocchio.LOCAL_WORLD_ALIGNED)


@pytest.fixture
def spp():
    arm, ee = arm_tables("puma560")
    processor = SpecialPurposeProcessor(_registers(), {})
    processor.download("jacobian", {"ARM": arm, "EE": ee})
    yield processor
    processor.close()
    assert _left(processor.segment) == []


@pytest.mark.parametrize("options, message", [
    ({"memory": 0}, r"spp option memory must be a whole number in \[1, 16777216\], got: 0"),
    ({"memory": 10**15}, r"spp option memory must be a whole number in \[1, 16777216\], got: 1000000000000000"),
    ({"start_timeout": -1}, r"spp option start_timeout must be a number of seconds in \(0, 3600\]"),
    ({"start_timeout": float("nan")}, r"spp option start_timeout must be a number of seconds in \(0, 3600\]"),
    ({"cores": 4}, r"unknown spp option\(s\) \['cores'\]; valid options: memory, download_bytes, start_timeout"),
])
def test_bad_spp_options_are_refused_before_any_processor_starts(options, message):
    with pytest.raises(ValueError, match=message):
        SpecialPurposeProcessor.check_options(options)


def test_pbo_lexicon_lists_the_spp_driver_as_a_special_purpose_processor():
    entries = {e["name"]: e for e in drivers()}
    assert entries["spp"]["kind"] == "special-purpose processor (TR 4.6.3)"
    assert entries["spp"]["class"] == "drivers.spp.driver:SpecialPurposeProcessor"


@pytest.mark.multiprocess
def test_the_downloaded_jacobian_is_what_pinocchio_computes(spp):
    out = np.zeros(42)
    spp.call_and_wait(Q, out)
    x, jacobian = _pinocchio(Q)
    np.testing.assert_allclose(out[:6], x, atol=1e-12)
    np.testing.assert_allclose(out[6:].reshape(6, 6), jacobian, atol=1e-12)
    figures = spp.figures()
    assert figures["routine"] == "jacobian" and figures["items"] >= 1 and figures["service_p99"] > 0


@pytest.mark.multiprocess
def test_a_batch_of_jacobians_is_one_work_item():
    arm, ee = arm_tables("puma560")
    processor = SpecialPurposeProcessor(_registers(), {})
    try:
        assert processor.download("jacobian_batch", {"ARM": arm, "EE": ee}, batch=3) == (18, 126)
        qs = np.stack([Q, -Q, 2 * Q])
        out = np.zeros(126)
        processor.call_and_wait(qs.ravel(), out)
        for k, q in enumerate(qs):
            np.testing.assert_allclose(out[k * 42 + 6:(k + 1) * 42].reshape(6, 6), _pinocchio(q)[1], atol=1e-12)
        assert processor.figures()["items"] == 1
    finally:
        processor.close()
    assert _left(processor.segment) == []


@pytest.mark.multiprocess
@pytest.mark.parametrize("routine, options, message", [
    ("fft", {},
     r"could not load routine 'fft': ValueError: no routine 'fft' on this processor; routines: jacobian, jacobian_batch"),
    ("jacobian_batch", {"batch": 0}, r"needs option batch, a whole number >= 1, got: 0"),
    ("jacobian", {"frame": "hand"}, r"the arm has no frame 'hand'"),
])
def test_a_download_the_processor_cannot_load_is_refused_with_its_reason(routine, options, message):
    arm, ee = arm_tables("puma560")
    processor = SpecialPurposeProcessor(_registers(), {})
    try:
        with pytest.raises(ProcessorError, match=message):
            processor.download(routine, {"ARM": arm, "EE": ee}, **options)
    finally:
        processor.close()
    assert _left(processor.segment) == []


@pytest.mark.multiprocess
def test_a_cycles_call_allocates_nothing(spp):
    out = np.zeros(42)
    spp.call_and_wait(Q, out)
    assert allocation_peak(lambda: spp.call(Q, out)) < one_array()


@pytest.mark.multiprocess
def test_a_call_never_waits_on_a_stopped_processor_and_says_how_old_its_result_is(spp):
    out = np.zeros(42)
    spp.call_and_wait(Q, out)
    os.kill(spp.process.pid, signal.SIGSTOP)
    try:
        ages = [spp.call(Q, out) for _ in range(50)]
    finally:
        os.kill(spp.process.pid, signal.SIGCONT)
    assert ages == list(range(1, 51))  # each call returned at once, with the same (ever older) result
    assert spp.fault == ""  # stopped is slow, not dead: the module decides what an old result means
    assert spp.figures()["late_calls"] >= 49


@pytest.mark.multiprocess
def test_a_killed_processor_is_a_named_fault_and_leaves_nothing(spp):
    out = np.zeros(42)
    spp.call_and_wait(Q, out)
    pid = spp.process.pid
    os.kill(pid, signal.SIGKILL)
    until(lambda: (spp.call(Q, out), spp.fault)[1] != "", "the driver sees the processor dead")
    assert spp.fault.startswith(f"the special-purpose processor (pid {pid}) died (killed by SIGKILL)")
    spp.close()
    assert spp.figures()["fault"] == spp.fault
    assert _left(spp.segment) == []


@pytest.mark.multiprocess
@pytest.mark.parametrize("grace, waits", [(3600.0, True), (1e-9, False)])
def test_a_task_on_its_way_to_error_waits_for_a_death_only_what_is_left_of_the_grace_since_the_newest_result(
        spp, monkeypatch, grace, waits):
    """On the real clock a task finds its result too old only after `max_age` cycles: the grace for a
    processor killed a moment ago has passed by then, and the cycle must not wait (its RTPU's other
    tasks would start late)."""
    import drivers.spp.driver as driver

    spp.call_and_wait(Q, np.zeros(42))
    waited: list[float] = []
    monkeypatch.setattr(driver.select, "select", lambda r, w, x, timeout: waited.append(timeout) or ([], [], []))
    assert spp.await_death(grace) == ""  # alive: stopped or slow is not dead
    assert bool(waited) == waits and all(0 < timeout <= grace for timeout in waited)


class PassingClock(ManualClock):
    """Fake clock: a wait for a release also lets a millisecond of real time pass (the processor
    starts in real time meanwhile)."""

    def sleep_until(self, deadline: float) -> float:
        time.sleep(0.001)
        return super().sleep_until(deadline)


@pytest.mark.multiprocess
def test_while_a_task_spawned_live_starts_its_processor_the_rtpus_other_tasks_go_on_cycling(make_table):
    RUNS.clear()
    table = robot_state_table(make_table, "puma560", ("o0", "float64", ()), ("q_m", "float64", (6,)),
                              ("x_m", "float64", (6,)), ("J", "float64", (6, 6)))
    clock = PassingClock(0.0)
    script = [(0.0, ["spawn", "a"]), (0.0, ["on", "a", 0.0]), (0.0025, ["spawn", "fk"]), (0.0035, ["kill", "fk"])]
    executive = Executive(clock, FakeSignals(clock, script), [].append, epoch=0.0)
    executive.cycles_between_steps = True  # as on the real clock
    a = Task(task_spec(Ticker, name="a", index=0, ports={"out": "o0"}), Ticker, table)
    executive.add(a)
    processors: list[SpecialPurposeProcessor] = []

    def open_processor(device, spec) -> SpecialPurposeProcessor:
        processors.append(SpecialPurposeProcessor(_registers(), {}))
        return processors[-1]

    spec = dataclasses.replace(task_spec(FkJacobianSpp, name="fk", index=1, dims={"NDOF": 6}, params={"device": "fpa"}),
                               resources=("fpa",))
    executive.factories["fk"] = lambda: Task(spec, FkJacobianSpp, table, {"NDOF": 6}, {"fpa": DeviceSpec("fpa", "spp")},
                                             open_processor)
    run_until(executive, clock, 0.003)
    assert executive.tasks["fk"].task.state is TaskState.OFF, executive.tasks["fk"].task.last_error
    started = len(RUNS)
    assert started > 10  # a's cycles while the processor's interpreter started, each at its release:
    assert [at for _, at in RUNS] == pytest.approx([0.001 * k for k in range(started)])
    scheduled = executive.tasks["a"]
    assert (scheduled.overruns, scheduled.missed) == (0, 0)
    run_until(executive, clock, clock.now() + 0.001)  # the kill: the wait for the processor's exit is handed off
    assert executive.tasks["fk"].task.state is TaskState.KILLED
    executive.stop()
    [processor] = processors
    assert processor.process is None and _left(processor.segment) == []


@pytest.mark.multiprocess
def test_a_killed_task_process_takes_its_processor_and_its_memory_with_it(tmp_path):
    script = textwrap.dedent(f"""
        import signal
        from drivers.spp.driver import SpecialPurposeProcessor
        spp = SpecialPurposeProcessor({_registers()!r}, {{}})
        print(spp.process.pid, spp.segment, flush=True)
        signal.pause()  # a task process at work, until the test kills it
    """)
    task = subprocess.Popen([sys.executable, "-c", script], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        pid, segment = task.stdout.readline().split()
        assert _left(segment)
        task.kill()  # no close, no finally: the processor must notice by itself
        task.wait()
        until(lambda: not pid_alive(int(pid)) and _left(segment) == [], "the processor gone and its memory unlinked")
    finally:
        if task.poll() is None:
            task.kill()
            task.wait()


# --- end to end: Figure 13 with fk on the processor, on the simulated clock -------------------------


def _config_copy(folder: Path, subsystem: str) -> Path:
    text = CONFIG.read_text().replace("subsystem: visual_servo_spp", f"subsystem: {subsystem}")
    path = folder / f"{subsystem}.yaml"
    path.write_text(text)
    return path


@pytest.mark.multiprocess
def test_figure_13_with_fk_on_the_processor_tracks_and_the_summary_shows_the_processors_timing(tmp_path):
    subsystem = "spp_fig13"
    done = subprocess.run([*PBO, "run", str(_config_copy(tmp_path, subsystem)), "--no-live", "--clock", "sim",
                           "--duration", "1", "--out", str(tmp_path / "out")],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert done.returncode == 0, done.stderr + done.stdout
    figures = report["tasks"]["fk"]["devices"]["fpa"]
    assert figures["routine"] == "jacobian" and figures["fault"] == ""
    assert figures["items"] > 0 and figures["calls"] == report["tasks"]["fk"]["cycles"] + 1  # + the one `on` waited for
    assert "special-purpose processor 'fpa' (task 'fk', routine jacobian): " in done.stdout
    final = {name: np.array(v["value"]) for name, v in report["variables"].items()}
    x, jacobian = _pinocchio(final["q_m"])
    np.testing.assert_allclose(final["J"], jacobian, atol=0.05)  # the answer to a q_m a cycle or so before the last
    np.testing.assert_allclose(final["x_m"], x, atol=0.01)
    assert np.linalg.norm(final["x_m"][:3] - final["x_d"][:3]) < 0.03  # the hand follows the target
    assert_nothing_left(report)
    assert [n for n in os.listdir("/dev/shm") if f"pbo.{subsystem}." in n] == []


@pytest.mark.multiprocess
def test_on_the_real_clock_the_processor_runs_just_below_the_rtpus_once_loaded_and_keeps_up(tmp_path):
    """At SCHED_OTHER it waited behind every ordinary process, a log encoder's start-up at a real-time
    priority among them, and fk found its result more than max_age cycles old."""
    subsystem = "spp_real"
    done = subprocess.run([*PBO, "run", str(_config_copy(tmp_path, subsystem)), "--no-live", "--duration", "1",
                           "--out", str(tmp_path / "out")], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert_ended_well(done.returncode, report, done.stderr + done.stdout)
    assert report["tasks"]["fk"]["state"] == "ON" and not [f for f in report["faults"] if "'fk'" in f or "'fpa'" in f]
    fifo = report["realtime"]["rtpu1"]["scheduler"].startswith("SCHED_FIFO")
    assert report["tasks"]["fk"]["devices"]["fpa"]["scheduler"] == ("SCHED_FIFO 1" if fifo else "SCHED_OTHER")
    assert_nothing_left(report)


@pytest.mark.multiprocess
def test_killing_the_processor_mid_run_puts_its_task_in_error_naming_it_and_leaves_nothing(tmp_path):
    subsystem = "spp_killed"
    run = start_run(_config_copy(tmp_path, subsystem), tmp_path, "--clock", "sim", "--duration", "600",
                    "--out", str(tmp_path / "out"))
    with killed_on_failure(run):
        rtpu = run_processes(run)["rtpu1"]
        processors = [pid for pid, command in children_of(rtpu).items() if "drivers.spp.processor" in command]
        assert len(processors) == 1
        os.kill(processors[0], signal.SIGKILL)
        said = read_until(run, "task 'fk' on rtpu1 is in ERROR")
        assert f"the special-purpose processor (pid {processors[0]}) died (killed by SIGKILL)" in said
        run.send_signal(signal.SIGINT)
        _out, err = run_output(run)
    assert run.returncode == 2, err
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["tasks"]["fk"]["state"] == "ERROR"
    assert "device 'fpa': the special-purpose processor" in report["tasks"]["fk"]["error"]
    assert any(f.startswith("device 'fpa' of task 'fk': the special-purpose processor") for f in report["faults"])
    assert children_of(run.pid) == {}
    assert_nothing_left(report)
    assert [n for n in os.listdir("/dev/shm") if f"pbo.{subsystem}." in n] == []
