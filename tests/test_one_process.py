"""`pbo run --clock sim --one-process`: the plant and every RTPU in one process, the same run as with processes.

Each file is run twice on the simulated clock, with processes and in one process, and what the
runs wrote is compared: every file of the output directory byte for byte, and the report but
for what names the run or times it on the wall clock.
"""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest

from pbo_runtime.cli.main import main
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.table.table import Header, StateTable, StatusWord, TableLayout
from tests.support import (
    DEMO,
    PBO,
    REPO,
    application_copy,
    assert_nothing_left,
    config_copy,
    demo_copy,
    ipc_names,
    killed_on_failure,
    start_run,
    table_of,
    until,
)

# What differs between any two runs of one file: the run's id and the names made from it, and wall times.
RUN_OWN = ("run_id", "objects", "startup", "wall_seconds", "running_wall_seconds")

# Shipped subsystem files that do not run on the simulated clock by themselves, and why.
NOT_ON_THE_SIMULATED_CLOCK = {
    "follower": "its tasks open an application's links: it runs in leader_follower.yaml",
    "leader": "its tasks open an application's links: it runs in leader_follower.yaml",
    "ros2_control": "its robot is a ros2_control peer on DDS, which this test does not start",
    "visual_servoing_spp": "its special-purpose processor is a process of its own on wall time, never waited for: "
                           "two runs with processes differ too",
}


def subsystem_files() -> list[Path]:
    files = sorted(path for path in (REPO / "configs").glob("*.yaml")
                   if any(line.startswith("subsystem:") for line in path.read_text().splitlines()))
    return [path for path in files if path.stem not in NOT_ON_THE_SIMULATED_CLOCK]


def run_sim(config: Path, folder: Path, out: str, *arguments: str) -> tuple[dict, dict[str, bytes]]:
    """A run on the simulated clock: its report with what is the run's own taken out, and every other file it wrote."""
    directory = folder / out
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--no-live", "--out", str(directory), *arguments],
                          cwd=folder, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert_nothing_left(json.loads((directory / "report.json").read_text()))
    files = {str(path.relative_to(directory)): path.read_bytes()
             for path in sorted(directory.rglob("*")) if path.is_file() and path.name != "report.json"}
    return _comparable(directory / "report.json", directory), files


def _comparable(report: Path, directory: Path, own: tuple[str, ...] = RUN_OWN) -> dict:
    """A run's report without what is the run's own, its output directory written OUT."""
    return {key: value for key, value in json.loads(report.read_text().replace(str(directory), "OUT")).items()
            if key not in own}


def assert_same_run(config: Path, folder: Path, *arguments: str) -> tuple[dict, dict[str, bytes]]:
    processes = run_sim(config, folder, "processes", *arguments)
    one = run_sim(config, folder, "one", "--one-process", *arguments)
    assert one[1].keys() == processes[1].keys()
    for name in processes[1]:
        assert one[1][name] == processes[1][name], name
    assert one[0] == processes[0]
    return one


@pytest.mark.multiprocess
def test_figure_8_in_one_process_is_the_run_of_processes_bit_for_bit(tmp_path):
    report, files = assert_same_run(config_copy(DEMO, tmp_path, "oneproc_fig8"), tmp_path, "--duration", "2")
    assert report["plant"]["steps"] == 2001 and report["tasks"]["pid"]["cycles"] == 2001
    assert len(files["pid_joint.mcap"]) > 0


@pytest.mark.multiprocess
def test_twenty_switches_in_one_process_are_the_run_of_processes_bit_for_bit(tmp_path):
    """Job control's plans, the executives' switches at a boundary, and each switch's report."""
    config = config_copy(REPO / "configs" / "switch_joint.yaml", tmp_path, "oneproc_switch")
    report, _ = assert_same_run(config, tmp_path, "--alternate", "pid,pd", "--switches", "20", "--interval", "0.02")
    assert len(report["switches"]) == 20


@pytest.mark.multiprocess
def test_an_application_that_decides_runs_the_same_jobs_in_one_process(tmp_path):
    """branches.yaml's `pick`: a try that times out, a repeat, a wait and an if, decided on the table's values."""
    config = config_copy(REPO / "configs" / "branches.yaml", tmp_path, "oneproc_pick")
    report, _ = assert_same_run(config, tmp_path, "--app", "pick")
    assert report["jobs_done"]


@pytest.mark.multiprocess
@pytest.mark.parametrize("config", subsystem_files(), ids=lambda path: path.stem)
def test_every_shipped_subsystem_runs_the_same_in_one_process(tmp_path, config):
    assert_same_run(config_copy(config, tmp_path, f"oneproc_{config.stem}"), tmp_path, "--duration", "0.5")


def test_one_process_is_refused_without_the_simulated_clock(tmp_path, capsys):
    assert main(["run", str(DEMO), "--one-process", "--no-live", "--out", str(tmp_path / "out")]) == 1
    said = capsys.readouterr().err
    assert "--one-process" in said and "add --clock sim" in said
    assert not (tmp_path / "out").exists()


@pytest.mark.multiprocess
def test_an_application_with_a_process_a_subsystem_is_the_run_of_processes_bit_for_bit(tmp_path):
    """leader_follower.yaml: three subsystems joined by links, each subsystem in its supervisor's process."""
    app = application_copy(tmp_path, "oneproc")
    outputs: dict[str, dict[str, bytes]] = {}
    reports: dict[str, dict[str, dict]] = {}
    for out, arguments in (("processes", ()), ("one", ("--one-process",))):
        done = subprocess.run([*PBO, "run", str(app), "--clock", "sim", "--duration", "1", "--no-live",
                               "--out", str(tmp_path / out), *arguments], cwd=tmp_path, capture_output=True, text=True,
                              timeout=600)
        assert done.returncode == 0, done.stdout + done.stderr
        outputs[out] = {str(path.relative_to(tmp_path / out)): path.read_bytes()
                        for path in sorted((tmp_path / out).rglob("*.mcap"))}
        # (the links' objects are named after the application's run)
        reports[out] = {path.parent.name: _comparable(path, path.parent, (*RUN_OWN, "links"))
                        for path in (tmp_path / out).glob("*/report.json")}
    assert len(outputs["processes"]) == 3 and len(reports["processes"]) == 3
    assert outputs["one"] == outputs["processes"]
    assert reports["one"] == reports["processes"]


@pytest.mark.multiprocess
def test_a_task_failing_in_init_fails_the_run_in_one_process_as_with_processes(tmp_path):
    """follower.yaml alone: its link receiver finds no application's link in init, and the run fails (exit 2)."""
    config = config_copy(REPO / "configs" / "follower.yaml", tmp_path, "oneproc_fails")
    said, reports = {}, {}
    for out, arguments in (("processes", ()), ("one", ("--one-process",))):
        done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--duration", "0.5", "--no-live",
                               "--out", str(tmp_path / out), *arguments], cwd=tmp_path, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 2, done.stdout + done.stderr
        said[out] = [line for line in done.stderr.splitlines() if line.startswith("error:")]
        reports[out] = _comparable(tmp_path / out / "report.json", tmp_path / out)
        assert_nothing_left(json.loads((tmp_path / out / "report.json").read_text()))
    assert said["one"] == said["processes"] and "opens link 'arm_state'" in said["one"][0]
    assert reports["one"] == reports["processes"]


@pytest.mark.multiprocess
def test_a_cycle_that_never_returns_in_one_process_is_ended_by_a_second_ctrl_c(tmp_path):
    """In one process a hung cycle holds the whole run: the first Ctrl-C cannot be served, the second ends it at once."""
    config = demo_copy(tmp_path, "oneproc_hang", stuck={"module": "fault_injector", "rtpu": "rtpu0", "period": "2 ms",
                                                         "params": {"fail_after": 50, "fault": "hang"}})
    subsystem = load_subsystem(config)
    run = start_run(config, tmp_path, "--clock", "sim", "--one-process", "--duration", "60", "--out", str(tmp_path / "out"))
    with killed_on_failure(run):
        table = StateTable.attach(TableLayout.of(subsystem), table_of(run, "oneproc_hang"))
        index = subsystem.tasks["stuck"].index
        try:  # the tick of its 51st release (every 2 ms from 0) has begun, and it has not ended that cycle
            until(lambda: table.header[Header.SIM_TIME_NS] >= 100_000_000, "the stuck task's 51st release")
            assert table.status[index][StatusWord.CYCLES] == 50
        finally:
            table.close()
        run.send_signal(signal.SIGINT)
        run.send_signal(signal.SIGTERM)  # (a second SIGINT sent at once could be taken as one with the first)
        _, said = run.communicate(timeout=60)
    assert run.returncode == 2 and "stopped at once" in said and "Traceback" not in said
    assert ipc_names("oneproc_hang") == []
