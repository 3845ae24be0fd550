"""Data logs other tools open (issue 21): MCAP written by the data logger and read back with the
`mcap` library, logs cut short by a kill, `pbo plot`, `pbo log export --csv`, and where a run's
logs land (its output directory) and how `pbo run` says so."""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
import subprocess
import threading
import time

import numpy as np
import pytest
from mcap.reader import make_reader

from modules._mcap_encoder import McapLog
from modules.data_logger import DataLogger
from pbo_runtime import Status, open_log, read_log
from pbo_runtime.cli.main import main
from pbo_runtime.config.model import PortBinding, TaskSpec
from pbo_runtime.objects.waits import cycles_meanwhile
from pbo_runtime.reports.data_log import LogError
from pbo_runtime.reports.log_notes import split_unit
from pbo_runtime.reports.run_plot import csv_text, figure, load_run
from pbo_runtime.table.table import StateTable
from pbo_runtime.task.background import process_background
from pbo_runtime.task.lifecycle import Task
from tests.support import PBO, REPO, variables

DT = 0.01
LOGGED = variables(("x", "float64", (3,)), ("k", "int32", ()), ("m", "float64", (2, 2)))
NOTES = {"x": ("hand position", "m"), "k": ("a counter", ""), "m": ("a matrix", "N m")}
RUN = {"subsystem": "arm", "configuration": "joint_pid", "clock": "sim", "pbo-runtime": "0.1.0", "numpy": np.__version__,
       "mujoco": "3.0", "file": "/somewhere/arm.yaml", "yaml": "subsystem: arm\n"}


@pytest.fixture
def table(make_table) -> StateTable:
    return make_table(LOGGED)


def logger(table: StateTable, path, chunk: float = 1.0, restarted: bool = False) -> Task:
    params = {"variables": ["x", "k", "m"], "path": str(path), "chunk": chunk}
    built = DataLogger.build_params(params)
    bindings = tuple(PortBinding(p, p.variable, table.layout.slot(p.variable).shape) for p in DataLogger.ports_for(built))
    spec = TaskSpec(name="log", module="DataLogger", rtpu="rtpu0", period=DT, params=params, bindings=bindings, index=1)
    task = Task(spec, DataLogger, table, run_metadata=RUN, variable_notes=NOTES, restarted=restarted)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    return task


def kill_and_finish(task: Task) -> None:
    """Kill the logger and wait for the RTPU's background thread to finish its log (as the RTPU's stop does)."""
    task.kill()
    assert process_background().drain()


def run_cycles(table: StateTable, task: Task, cycles: int, x=None) -> list[tuple[float, list, int, list]]:
    written = []
    for i in range(cycles):
        t = 1.0 + i * DT
        value = np.array([i, -i, 0.5 * i]) if x is None else x(i)
        m = np.arange(4.0).reshape(2, 2) + i
        table.write("x", value, when=t)
        table.write("k", 10 * i - 3, when=t)
        table.write("m", m, when=t)
        assert task.run_cycle(t) is Status.CONTINUE
        task.module.wait_for_writer()
        written.append((t, value.tolist(), 10 * i - 3, m.tolist()))
    return written


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_an_mcap_log_reads_back_with_the_mcap_library_every_variable_with_its_unit_doc_and_the_run_metadata(table, tmp_path):
    path = tmp_path / "log.mcap"
    task = logger(table, path, chunk=3 * DT)
    written = run_cycles(table, task, 8)
    kill_and_finish(task)
    with open(path, "rb") as file:
        reader = make_reader(file)
        summary = reader.get_summary()
        channels = {c.topic: c for c in summary.channels.values()}
        assert list(channels) == ["x", "k", "m"]
        assert {name: (c.metadata["unit"], c.metadata["doc"]) for name, c in channels.items()} == {
            "x": ("m", "hand position"), "k": ("", "a counter"), "m": ("N m", "a matrix")}
        assert all(c.message_encoding == "json" for c in channels.values())
        assert {summary.schemas[c.schema_id].encoding for c in channels.values()} == {"jsonschema"}
        assert summary.statistics.message_count == 3 * 8 and summary.statistics.chunk_count == 3  # 3 + 3 + 2 rows
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert metadata["pbo-run"] == RUN
        by_topic: dict[str, list] = {"x": [], "k": [], "m": []}
        for _, channel, message in reader.iter_messages():
            body = json.loads(message.data)
            by_topic[channel.topic].append((message.log_time, body["time"], body["value"]))
    assert [v for _, _, v in by_topic["x"]] == [w[1] for w in written]
    assert [v for _, _, v in by_topic["k"]] == [w[2] for w in written]
    assert [v for _, _, v in by_topic["m"]] == [w[3] for w in written]
    assert [(stamp, t) for stamp, t, _ in by_topic["x"]] == [(round(w[0] * 1e9), w[0]) for w in written]
    log = open_log(path)
    assert log.complete and log.units == {"x": "m", "k": "", "m": "N m"} and log.metadata == RUN
    rows = read_log(path)
    assert rows.dtype.names == ("time", "x", "k", "m") and rows["k"].dtype == np.int32 and rows["m"].shape == (8, 2, 2)
    np.testing.assert_array_equal(rows["time"], [w[0] for w in written])
    np.testing.assert_array_equal(rows["m"], [w[3] for w in written])


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_an_mcap_log_whose_writer_was_killed_reads_up_to_its_last_whole_chunk(table, tmp_path):
    path = tmp_path / "log.mcap"
    task = logger(table, path, chunk=2 * DT)
    written = run_cycles(table, task, 7)  # three chunks of two rows written; the seventh row in the chunk begun
    cut = tmp_path / "killed.mcap"
    shutil.copy(path, cut)  # as a SIGKILL leaves it: no summary, no footer
    with open(cut, "ab") as file:
        file.write(b"\x06" + struct.pack("<Q", 4096) + b"half a chunk")  # and a chunk's record cut short
    kill_and_finish(task)
    log = open_log(cut)
    assert not log.complete and len(log.rows) == 6
    np.testing.assert_array_equal(log.rows["x"], [w[1] for w in written[:6]])
    assert log.units["x"] == "m" and log.metadata["subsystem"] == "arm"


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
@pytest.mark.parametrize("suffix", [".mcap", ".npy"])
def test_a_logger_restarted_with_its_rtpu_goes_on_in_the_same_log_after_its_last_whole_chunk(table, tmp_path, suffix):
    path = tmp_path / f"log{suffix}"
    first = logger(table, path, chunk=2 * DT)
    before = run_cycles(table, first, 5)  # two chunks of two rows written; the fifth row in the chunk begun
    cut = tmp_path / f"killed{suffix}"
    shutil.copy(path, cut)  # as the RTPU's SIGKILL leaves it
    kill_and_finish(first)
    again = logger(table, cut, chunk=2 * DT, restarted=True)
    assert again.module.written == 4  # the rows of the chunks written; the chunk begun died with the RTPU
    after = run_cycles(table, again, 3)
    kill_and_finish(again)
    rows = read_log(cut)
    np.testing.assert_array_equal(rows["x"], [w[1] for w in before[:4] + after])
    np.testing.assert_array_equal(rows["time"], [w[0] for w in before[:4] + after])
    if suffix == ".mcap":  # the run's metadata written once, and a second death and restart goes on again
        assert open_log(cut).metadata == RUN
        third = logger(table, cut, chunk=2 * DT, restarted=True)
        assert third.module.written == 7
        kill_and_finish(third)


def test_a_logger_not_restarted_replaces_a_file_left_at_its_path(table, tmp_path):
    path = tmp_path / "log.npy"
    run_cycles(table, (old := logger(table, path, chunk=2 * DT)), 4)
    kill_and_finish(old)
    fresh = logger(table, path, chunk=2 * DT)
    assert fresh.module.written == 0
    kill_and_finish(fresh)
    assert len(read_log(path)) == 0


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_an_mcap_log_killed_before_its_first_chunk_still_says_what_it_holds(table, tmp_path):
    path = tmp_path / "log.mcap"
    task = logger(table, path)
    run_cycles(table, task, 3)  # a second's chunk: nothing written yet
    log = open_log(path)
    assert len(log.rows) == 0 and log.variables == ["x", "k", "m"] and log.units["m"] == "N m"
    kill_and_finish(task)
    assert len(read_log(path)) == 3


@pytest.mark.multiprocess
def test_an_mcap_logs_encoder_process_ends_with_the_task_and_nothing_is_left(table, tmp_path):
    task = logger(table, tmp_path / "log.mcap", chunk=2 * DT)
    run_cycles(table, task, 3)
    encoder = task.module._file.encoder.process
    assert encoder.poll() is None
    kill_and_finish(task)
    assert encoder.poll() == 0 and open_log(tmp_path / "log.mcap").complete


@pytest.mark.multiprocess
def test_an_mcap_log_whose_encoder_process_dies_fails_the_next_chunk_naming_it_and_keeps_the_chunks_before(table, tmp_path):
    path = tmp_path / "log.mcap"
    task = logger(table, path, chunk=2 * DT)
    written = run_cycles(table, task, 2)
    task.module._file.encoder.process.kill()
    task.module._file.encoder.process.wait()
    for i in range(2, 4):
        assert task.run_cycle(1.0 + i * DT) is Status.CONTINUE
    task.module.wait_for_writer()
    assert task.run_cycle(1.0 + 4 * DT) is Status.ERROR
    assert re.fullmatch(r"cycle raised OutputError: cannot write log .*log\.mcap \(2 rows after the 2 written\): "
                        r"the log's encoder process ended \(killed by SIGKILL\) at data_logger\.py:\d+",
                        task.last_error), task.last_error
    kill_and_finish(task)
    log = open_log(path)
    assert not log.complete and [row.tolist() for row in log.rows["x"]] == [w[1] for w in written]


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_a_loggers_kill_returns_at_once_and_the_background_thread_writes_its_last_chunk_and_footer(table, tmp_path):
    path = tmp_path / "log.mcap"
    task = logger(table, path, chunk=2 * DT)
    written = run_cycles(table, task, 5)  # two chunks written; the fifth row in the chunk begun
    gate = threading.Event()
    process_background().hand_off(gate.wait, "test", "holding the background thread")
    task.kill()  # returns though the background thread cannot start on the log yet (off gave its writer the chunk begun)
    assert task.state.name == "KILLED" and not open_log(path).complete  # no summary and footer yet
    gate.set()
    assert process_background().drain()
    log = open_log(path)
    assert log.complete and [row.tolist() for row in log.rows["x"]] == [w[1] for w in written]


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_a_loggers_off_hands_the_chunk_begun_to_its_writer_and_on_goes_on_in_the_same_log(table, tmp_path):
    path = tmp_path / "log.mcap"
    task = logger(table, path)
    before = run_cycles(table, task, 3)  # a second's chunk: nothing written yet
    task.turn_off(1.5)
    task.module.wait_for_writer()
    assert len(read_log(path)) == 3  # on disk while the task is off, though its chunk was not full
    assert task.turn_on(2.0)
    after = run_cycles(table, task, 2)
    kill_and_finish(task)
    log = open_log(path)
    assert log.complete and [row.tolist() for row in log.rows["x"]] == [w[1] for w in before + after]


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_a_logger_spawned_at_the_path_of_one_still_being_finished_waits_for_that_file_to_end(table, tmp_path):
    path = tmp_path / "log.mcap"
    old = logger(table, path, chunk=2 * DT)
    run_cycles(table, old, 3)
    gate = threading.Event()
    process_background().hand_off(gate.wait, "test", "holding the background thread")
    old.kill()  # its chunk begun and footer wait behind the gate
    spawned: list[Task] = []
    spawning = threading.Thread(target=lambda: spawned.append(logger(table, path, chunk=2 * DT)))
    spawning.start()
    gate.set()
    spawning.join()
    [fresh] = spawned
    rows = run_cycles(table, fresh, 3)
    kill_and_finish(fresh)
    log = open_log(path)  # the new log alone, whole: the old one's end was written before it replaced the file
    assert log.complete and [row.tolist() for row in log.rows["x"]] == [w[1] for w in rows]


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_while_a_logger_spawned_live_waits_for_the_file_of_the_one_before_its_rtpus_cycles_go_on(table, tmp_path):
    path = tmp_path / "log.mcap"
    old = logger(table, path, chunk=2 * DT)
    run_cycles(table, old, 3)
    gate = threading.Event()
    process_background().hand_off(gate.wait, "test", "holding the background thread")
    old.kill()
    sleeps: list[float] = []

    def run_the_cycles_due(seconds: float) -> None:  # the executive's, in a live spawn: here, each is counted
        sleeps.append(seconds)
        if len(sleeps) == 5:
            gate.set()
        time.sleep(seconds)

    with cycles_meanwhile(run_the_cycles_due):
        fresh = logger(table, path, chunk=2 * DT)
    assert len(sleeps) >= 5  # the spawn waited in steps, cycles due run between them, until the old file ended
    kill_and_finish(fresh)
    assert open_log(path).complete


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_a_log_that_cannot_be_finished_is_reported_as_the_loggers_output_failure(table, tmp_path):
    directory = tmp_path / "gone"
    task = logger(table, directory / "log.mcap")
    run_cycles(table, task, 2)
    shutil.rmtree(directory)
    process_background().take_failures()  # (what other tests' logs left)
    kill_and_finish(task)
    [failure] = process_background().take_failures()
    assert failure.task == "log" and failure.what == f"finishing log {directory / 'log.mcap'}" and failure.output
    assert "OutputError: cannot write log" in failure.error and "the file was removed while the run wrote it" in failure.error


@pytest.mark.multiprocess  # an MCAP log is encoded by a process of its own
def test_non_finite_values_are_logged_as_json_null_and_read_back_as_nan(table, tmp_path):
    path = tmp_path / "log.mcap"
    task = logger(table, path)
    run_cycles(table, task, 2, x=lambda i: np.array([np.nan, np.inf, i]))
    kill_and_finish(task)
    with open(path, "rb") as file:
        bodies = [json.loads(m.data) for _, c, m in make_reader(file).iter_messages() if c.topic == "x"]
    assert bodies[0]["value"] == [None, None, 0.0]
    assert np.isnan(read_log(path)["x"][:, :2]).all()


@pytest.mark.parametrize(("doc", "split"), [
    ("measured joint position, rad", ("measured joint position", "rad")),
    ("measured joint velocity, rad/s", ("measured joint velocity", "rad/s")),
    ("joint torque command, N m", ("joint torque command", "N m")),
    ("hand Jacobian, linear rows first", ("hand Jacobian, linear rows first", "")),
    ("measured hand pose: position m, rotation vector rad", ("measured hand pose: position m, rotation vector rad", "")),
    ("number of joints", ("number of joints", "")),
])
def test_a_variables_unit_is_the_last_clause_of_its_doc_when_that_is_made_of_units(doc, split):
    assert split_unit(doc) == split


def test_a_variable_the_file_gives_no_doc_takes_the_unit_of_the_port_that_writes_it():
    from pbo_runtime.config.loader import load_subsystem
    from pbo_runtime.reports.log_notes import variable_notes

    notes = variable_notes(load_subsystem(str(REPO / "configs" / "pid_joint_minimal.yaml")))
    assert notes["q_m"] == ("measured joint position", "rad")  # robot_torque's out-var, no entry in the file
    assert notes["tau_u"] == ("joint torque command", "N m")  # pid_joint's out-var


# --- reading what is not a log ------------------------------------------------------------------


@pytest.mark.parametrize(("make", "message"), [
    (lambda d: d / "missing.mcap", r"no log .*missing\.mcap: no such file"),
    (lambda d: d, r"no log .*: it is a directory"),
    (lambda d: (d / "notes.txt").write_text("hello") and d / "notes.txt",
     r".*notes\.txt: not a data log \(neither MCAP nor \.npy\)"),
    (lambda d: np.save(d / "plain.npy", np.zeros(3)) or d / "plain.npy",
     r".*plain\.npy: not a data log \(a 1-D structured array with a time field\), got shape \(3,\) of float64"),
])
def test_open_log_refuses_what_is_not_a_log_naming_it(tmp_path, make, message):
    with pytest.raises(LogError, match=rf"^{message}$"):
        open_log(make(tmp_path))


# --- pbo plot, pbo log export ----------------------------------------------------------------------


@pytest.fixture
def run_dir(tmp_path):
    """A run's directory as `pbo run` leaves it: a log and report.json with the switches and jobs marked.

    The log is written by the logger's MCAP writer in this process (the logger itself runs it in
    a process of its own, tested above): 20 rows at DT from 1.0 s, in chunks of two."""
    directory = tmp_path / "runs" / "arm-1"
    directory.mkdir(parents=True)
    rows = np.zeros(20, dtype=[("time", np.float64), ("x", np.float64, (3,)), ("k", np.int32), ("m", np.float64, (2, 2))])
    i = np.arange(20)
    rows["time"] = 1.0 + i * DT
    rows["x"] = np.stack([i, -i, 0.5 * i], axis=1)
    rows["k"] = 10 * i - 3
    rows["m"] = np.arange(4.0).reshape(2, 2) + i[:, None, None]
    fd = os.open(directory / "log.mcap", os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        log = McapLog(fd, rows.dtype, NOTES, RUN, "log", DT)
        for start in range(0, 20, 2):
            log.append(rows[start:start + 2], 2)
        log.finish()
    finally:
        os.close(fd)
    marks = [{"time": 1.0, "kind": "configuration", "label": "joint_pid on"},
             {"time": 1.05, "kind": "job", "label": "job move starts"},
             {"time": 1.1, "kind": "switch", "label": "joint_pid -> pd"}]
    (directory / "report.json").write_text(json.dumps({"started_at": 1.0, "marks": marks, "variables": {}}))
    return directory


def test_the_plot_has_a_subplot_per_variable_a_line_per_element_units_and_the_marks_on_the_runs_clock(run_dir):
    fig = figure(load_run(run_dir))
    axes = fig.axes
    assert [ax.get_ylabel() for ax in axes] == ["x [m]", "k", "m [N m]"]
    assert [len([line for line in ax.lines if line.get_gid() != "mark"]) for ax in axes] == [3, 1, 4]
    assert [t.get_text() for t in axes[0].get_legend().get_texts()] == ["x[0]", "x[1]", "x[2]"]
    marks = [line for line in axes[2].lines if line.get_gid() == "mark"]
    assert [round(line.get_xdata()[0], 9) for line in marks] == [0.0, 0.05, 0.1]  # seconds since the configuration came on
    assert [t.get_text() for t in axes[0].texts if t.get_gid() == "mark"] == [
        "joint_pid on", "job move starts", "joint_pid -> pd"]
    first = next(line for line in axes[0].lines if line.get_gid() != "mark")
    assert first.get_xdata()[0] == pytest.approx(0.0)  # the first row's release is the configuration's start


def drawn(ax) -> list:
    return [line for line in ax.lines if line.get_gid() != "mark"]


def test_an_axis_overlays_variables_and_takes_elements_and_differences(run_dir):
    fig = figure(load_run(run_dir), ["x,k", "x[1]", "x-x", "m[0][1]"])
    assert [ax.get_ylabel() for ax in fig.axes] == ["x,k", "x[1] [m]", "x-x [m]", "m[0][1] [N m]"]  # one unit, or none
    assert [len(drawn(ax)) for ax in fig.axes] == [4, 1, 3, 1]
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["x[0]", "x[1]", "x[2]", "k"]
    assert list(drawn(fig.axes[1])[0].get_ydata()) == [-i for i in range(20)]
    assert all(not line.get_ydata().any() for line in drawn(fig.axes[2]))
    assert list(drawn(fig.axes[3])[0].get_ydata()) == [1.0 + i for i in range(20)]


def test_a_difference_of_variables_of_two_logs_takes_the_second_at_the_firsts_times(run_dir):
    rows = np.zeros(10, dtype=[("time", np.float64), ("y", np.float64, (3,))])
    i = np.arange(10)
    rows["time"] = 1.0 + 2 * i * DT  # half the rate of x's log
    rows["y"] = np.stack([2 * i, -2 * i, i], axis=1)  # x's own values at those times
    fd = os.open(run_dir / "slow.mcap", os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        log = McapLog(fd, rows.dtype, {"y": ("x again", "m")}, RUN, "slow", 2 * DT)
        log.append(rows, 10)
        log.finish()
    finally:
        os.close(fd)
    first = drawn(figure(load_run(run_dir), ["x-y"]).axes[0])[0].get_ydata()
    assert np.allclose(first[:19], 0.0)  # x's rows between y's are interpolated: x is linear in time


@pytest.mark.parametrize("axis, message", [
    ("x[3]", r"x\[3\]: 'x' has shape \[3\]: no such element"),
    ("k[0]", r"k\[0\]: 'k' has shape \[\]: no such element"),
    ("x-m", r"'x-m': x has shape \(3,\) and m \(2, 2\): a difference needs the same shape"),
    ("x+m", r"'x\+m': a curve is a variable \(q_m\), an element \(q_m\[1\]\) or a difference of two \(q_m-q_r\)"),
    ("x,q_x", r"no variable 'q_x' in \S+log\.mcap \(logged: x, k, m\)"),
])
def test_an_axis_that_cannot_be_drawn_is_one_line_and_exit_1(run_dir, capsys, axis, message):
    assert main(["plot", str(run_dir), axis, "-o", str(run_dir / "p.png")]) == 1
    assert re.fullmatch("error: " + message, capsys.readouterr().err.strip())
    assert not (run_dir / "p.png").exists()


def test_marks_at_one_instant_share_one_label_so_none_prints_over_another():
    from pbo_runtime.reports.run_plot import _side_by_side

    marks = [(2.0, "job reach starts", "job"), (0.0, "joint_pid on", "switch"), (1.9999, "job reach done", "job")]
    assert _side_by_side(marks, (0.0, 4.0)) == [(0.0, "joint_pid on", "switch"),
                                                (1.9999, "job reach done / job reach starts", "job")]


def test_pbo_plot_writes_a_png_of_the_run(run_dir, tmp_path, capsys):
    png = tmp_path / "plot.png"
    assert main(["plot", str(run_dir), "x", "m", "-o", str(png)]) == 0
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (1000, 560)  # 10 in wide, 1.2 + 2.2 in per subplot, at 100 dpi
    assert len(data) > 20_000
    assert capsys.readouterr().out.strip() == f"wrote {png}"


def test_pbo_plot_of_one_log_finds_the_report_beside_it(run_dir, tmp_path):
    run = load_run(run_dir / "log.mcap")
    assert run.origin == 1.0 and len(run.marks) == 3


@pytest.mark.parametrize(("arguments", "message"), [
    (["nowhere"], r"error: no run directory or log nowhere: no such file or directory"),
    (["RUN", "q_x"], r"error: no variable 'q_x' in \S+log\.mcap \(logged: x, k, m\)"),
    (["RUN/report.json"], r"error: \S+report\.json: not a data log \(neither MCAP nor \.npy\)"),
    (["EMPTY"], r"error: \S+empty: no data log in this directory \(no \*\.mcap or \*\.npy file\); give a run's directory "
                r"\(pbo run prints it\) or a log file"),
    (["RUN", "-o", "plot.gif"], r"error: -o plot\.gif: the plot is written as \.png, \.svg or \.pdf, got '\.gif'"),
    (["RUN"], r"error: no display to show the plot on: write it to a file with -o plot\.png \(or \.svg\)"),
])
def test_pbo_plot_refuses_bad_input_in_one_line(run_dir, tmp_path, capsys, monkeypatch, arguments, message):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    given = [a.replace("RUN", str(run_dir)).replace("EMPTY", str(tmp_path / "empty")) for a in arguments]
    assert main(["plot", *given]) == 1
    err = capsys.readouterr().err.strip()
    assert re.fullmatch(message, err), err
    assert not (tmp_path / "plot.gif").exists()


def test_pbo_log_export_writes_a_csv_with_a_column_per_element_and_units_in_the_header(run_dir, capsys):
    assert main(["log", "export", str(run_dir / "log.mcap"), "--csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "time [s],x[0] [m],x[1] [m],x[2] [m],k,m[0][0] [N m],m[0][1] [N m],m[1][0] [N m],m[1][1] [N m]"
    assert lines[1] == "1.0,0.0,0.0,0.0,-3,0.0,1.0,2.0,3.0"
    assert len(lines) == 21


def test_pbo_log_export_writes_the_file_named_and_says_so(run_dir, tmp_path, capsys):
    out = tmp_path / "log.csv"
    assert main(["log", "export", str(run_dir / "log.mcap"), "--csv", "-o", str(out)]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out} (20 rows)"
    assert out.read_text() == csv_text(open_log(run_dir / "log.mcap"))


def test_pbo_log_export_takes_the_run_directory_pbo_plot_takes(run_dir, capsys):
    assert main(["log", "export", str(run_dir), "--csv"]) == 0
    assert capsys.readouterr().out == csv_text(open_log(run_dir / "log.mcap"))


def test_pbo_log_export_of_a_run_of_several_logs_writes_one_csv_each_into_a_directory_or_says_how(run_dir, tmp_path, capsys):
    shutil.copy(run_dir / "log.mcap", run_dir / "other.mcap")
    assert main(["log", "export", str(run_dir), "--csv"]) == 1
    assert capsys.readouterr().err.strip() == (f"error: {run_dir} holds 2 logs (log.mcap, other.mcap): give one of them, "
                                               "or -o DIR (an existing directory) for one CSV each")
    out = tmp_path / "csv"
    out.mkdir()
    assert main(["log", "export", str(run_dir), "--csv", "-o", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["log.csv", "other.csv"]
    assert (out / "other.csv").read_text() == csv_text(open_log(run_dir / "log.mcap"))


def test_a_log_in_ros2_encoding_is_read_back_by_an_independent_ros2_reader_and_by_read_log(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    rows = np.zeros(5, dtype=[("time", np.float64), ("x", np.float64, (3,)), ("k", np.int32), ("m", np.float64, (2, 2))])
    rows["time"] = 1.0 + np.arange(5) * DT
    rows["x"] = np.arange(15.0).reshape(5, 3)
    rows["k"] = [-3, 7, 0, 1, 2]
    rows["m"] = np.arange(20.0).reshape(5, 2, 2)
    rows["x"][2, 1] = np.nan
    path = tmp_path / "ros.mcap"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        log = McapLog(fd, rows.dtype, NOTES, {**RUN, "unix_offset_ns": "1700000000000000000"}, "log", DT, encoding="ros2")
        log.append(rows, 5)
        log.finish()
    finally:
        os.close(fd)
    with open(path, "rb") as file:
        reader = make_reader(file, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        decoded = [(channel.topic, schema.name, channel.message_encoding, message.log_time, list(ros.data),
                    [(d.label, d.size, d.stride) for d in ros.layout.dim])
                   for schema, channel, message, ros in reader.iter_decoded_messages()]
    by_topic = {topic: [d for d in decoded if d[0] == topic] for topic in ("x", "k", "m")}
    assert [d[1:3] for d in (by_topic["x"][0], by_topic["k"][0], by_topic["m"][0])] == [
        ("std_msgs/msg/Float64MultiArray", "cdr"), ("std_msgs/msg/Int32MultiArray", "cdr"),
        ("std_msgs/msg/Float64MultiArray", "cdr")]
    assert [d[3] for d in by_topic["k"]] == [1_700_000_000_000_000_000 + round(t * 1e9) for t in rows["time"]]  # Unix ns
    assert [d[4] for d in by_topic["k"]] == [[-3], [7], [0], [1], [2]]  # a scalar: one element, no dimension
    assert by_topic["m"][1][4:] == ([4.0, 5.0, 6.0, 7.0], [("dim0", 2, 4), ("dim1", 2, 2)])  # ROS's strides
    back = read_log(path)
    assert np.allclose(back["time"], rows["time"], rtol=0, atol=1e-9)
    assert np.array_equal(back["x"], rows["x"], equal_nan=True) and np.array_equal(back["m"], rows["m"])
    assert back["k"].tolist() == rows["k"].tolist()


@pytest.mark.parametrize("changes, refusal", [
    ({"encoding": "cdr"}, "encoding must be one of json, ros2, got: 'cdr'"),
    ({"encoding": "ros2", "path": "log.npy"}, "encoding ros2 writes an MCAP log: path must end in .mcap, got: 'log.npy'"),
])
def test_a_logs_encoding_is_json_or_ros2_and_ros2_only_in_mcap(changes, refusal):
    from modules.data_logger import DataLoggerParams

    with pytest.raises(ValueError, match=re.escape(refusal)):
        DataLoggerParams(variables=("x",), **changes)


def test_pbo_log_info_says_what_ros2_bag_info_says_of_a_log_on_the_runs_clock(run_dir, capsys):
    assert main(["log", "info", str(run_dir)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"Files:             {run_dir / 'log.mcap'}"
    assert lines[2:7] == ["Storage id:        mcap", "Duration:          0.190000000s",
                          "Start:             1.000000000 s on the run's clock",
                          "End:               1.190000000 s on the run's clock", "Messages:          60"]
    assert lines[7:] == ["Topic information: Topic: x | Type: x (jsonschema) | Count: 20 | Serialization Format: json",
                         "                   Topic: k | Type: k (jsonschema) | Count: 20 | Serialization Format: json",
                         "                   Topic: m | Type: m (jsonschema) | Count: 20 | Serialization Format: json"]


@pytest.mark.multiprocess
def test_a_real_clock_logs_times_are_unix_time_and_its_rows_keep_the_runs_clock(tmp_path, capsys):
    from mcap.reader import make_reader

    from tests.support import demo_copy

    config = demo_copy(tmp_path, "unix_times")
    before, monotonic_before = time.time_ns(), time.monotonic()
    done = subprocess.run([*PBO, "run", str(config), "--duration", "0.3", "--no-live", "--out", str(tmp_path / "out")],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    after, monotonic_after = time.time_ns(), time.monotonic()
    assert done.returncode == 0, done.stderr
    log = next((tmp_path / "out").glob("*.mcap"))
    with open(log, "rb") as file:
        first = next(make_reader(file).iter_messages())[2]
    assert before <= first.log_time <= after  # Foxglove and rosbag2 line it up with their own recordings
    assert monotonic_before <= read_log(log)["time"][0] <= monotonic_after  # the run's clock, as the table has it
    assert main(["log", "info", str(tmp_path / "out")]) == 0
    start = capsys.readouterr().out.splitlines()[4]
    assert start.startswith("Start:             ") and start.endswith(f"({first.log_time // 10**9}.{first.log_time % 10**9:09d})")


def test_pbo_log_export_of_what_is_not_a_log_is_one_line_and_exit_1(tmp_path, capsys):
    assert main(["log", "export", str(tmp_path / "none.mcap"), "--csv"]) == 1
    assert capsys.readouterr().err.strip() == f"error: no log {tmp_path / 'none.mcap'}: no such file"


# --- a run's output directory ------------------------------------------------------------------


def switching_copy(folder, subsystem: str):
    """configs/switch_joint.yaml as `subsystem`, with a logger in both configurations: its app switches between jobs."""
    text = (REPO / "configs" / "switch_joint.yaml").read_text()
    for old, new in (("subsystem: puma_switch", f"subsystem: {subsystem}"),
                     ("\nconfigurations:\n", "\n  logger: {module: data_logger, rtpu: rtpu0, period: 10 ms, "
                                             "params: {variables: [q_m, q_d, tau_u], path: arm.mcap}}\n\nconfigurations:\n"),
                     ("pid: [robot, traj, pid]", "pid: [robot, traj, pid, logger]"),
                     ("pd:  [robot, traj, pd]", "pd:  [robot, traj, pd, logger]")):
        assert old in text, old
        text = text.replace(old, new)
    path = folder / f"{subsystem}.yaml"
    path.write_text(text)
    return path


@pytest.mark.multiprocess
def test_a_run_writes_its_report_and_mcap_log_into_its_own_directory_says_where_and_plots_with_its_switches(tmp_path):
    config = switching_copy(tmp_path, "datalog_dir")
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--no-live", "--app", "tour"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    (run_dir,) = (tmp_path / "runs").iterdir()
    assert re.fullmatch(r"datalog_dir-\d{8}-\d{6}", run_dir.name)
    assert sorted(os.listdir(run_dir)) == ["arm.mcap", "report.json"]
    report = json.loads((run_dir / "report.json").read_text())
    log = read_log(run_dir / "arm.mcap")
    tail = done.stdout.rstrip().splitlines()[-2:]
    assert tail == [f"log: runs/{run_dir.name}/arm.mcap ({len(log)} rows)", f"run directory: runs/{run_dir.name}"]
    with open(run_dir / "arm.mcap", "rb") as file:
        reader = make_reader(file)
        units = {c.topic: c.metadata["unit"] for c in reader.get_summary().channels.values()}
        run = {m.name: m.metadata for m in reader.iter_metadata()}["pbo-run"]
    assert units == {"q_m": "rad", "q_d": "rad", "tau_u": "N m"}
    assert run["subsystem"] == "datalog_dir" and run["clock"] == "sim" and run["application"] == "tour"
    assert run["configuration"] == "pid" and run["yaml"] == config.read_text() and run["file"] == str(config.resolve())
    assert {"pbo-runtime", "numpy", "mujoco", "python"} <= set(run)
    marks = report["marks"]
    assert [m["label"] for m in marks] == ["pid on", "job reach starts", "job reach done", "pid -> pd", "job settle starts",
                                           "job settle done", "pd -> pid", "job reach starts", "job reach done"]
    times = [m["time"] for m in marks]
    assert report["started_at"] == times[0] and times == sorted(times)
    assert log["time"][0] <= times[1] < times[-1] <= log["time"][-1] + 0.01
    # one clock: each job's object is in the log from its switch on
    first, second = marks[3]["time"], marks[6]["time"]
    np.testing.assert_allclose(log["q_d"][log["time"] < first - 0.05][-1], [0.3, -0.5, 0.5, 0.2, 0.4, 0.2])
    np.testing.assert_allclose(log["q_d"][(log["time"] > first) & (log["time"] < second - 0.05)][-1],
                               [0.0, -0.3, 0.3, 0.0, 0.2, 0.0])
    np.testing.assert_allclose(log["q_d"][-1], [-0.2, -0.6, 0.4, 0.1, 0.3, -0.1])
    png = tmp_path / "tour.png"
    plotted = subprocess.run([*PBO, "plot", str(run_dir), "-o", str(png)], cwd=tmp_path, capture_output=True, text=True,
                             timeout=120)
    assert plotted.returncode == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", plotted.stderr


def test_the_plot_of_an_npy_log_takes_its_units_from_the_runs_report(table, tmp_path):
    directory = tmp_path / "run"
    task = logger(table, directory / "log.npy")
    run_cycles(table, task, 5)
    kill_and_finish(task)
    (directory / "report.json").write_text(json.dumps({"started_at": 1.0, "marks": [],
                                                       "variables": {"x": {"unit": "m"}, "m": {"unit": "N m"}}}))
    fig = figure(load_run(directory / "log.npy"), ["x", "m"])
    assert [ax.get_ylabel() for ax in fig.axes] == ["x [m]", "m [N m]"]
    assert csv_text(open_log(directory / "log.npy")).splitlines()[0].startswith("time [s],x[0],x[1],x[2],k,m[0][0]")


def test_a_run_refused_before_it_starts_leaves_no_run_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    config = tmp_path / "arm.yaml"
    config.write_text((REPO / "configs" / "pid_joint.yaml").read_text())
    assert main(["run", str(config), "--clock", "sim", "--no-live", "--config", "no_such"]) == 1  # a wrong argument
    assert "no configuration 'no_such'" in capsys.readouterr().err
    assert list((tmp_path / "runs").iterdir()) == []
