"""`pbo svar`: reading a live run's table through its own directory, without the YAML file.

Each test makes a real table with StateTable.create, named like a run of this (live) process.
"""

from __future__ import annotations

import math
import os
import time
import uuid
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from rich.console import Console

from pbo_runtime import PboError, TableLayoutError
from pbo_runtime.cli import operator
from pbo_runtime.ipc import messages, shm
from pbo_runtime.table.svar import format_value, open_table, svar_rows, svar_table
from pbo_runtime.table.table import MAGIC, VERSION, Flag, Header, StateTable, StatusWord, TableLayout, TaskState
from tests.support import variables

VARS = variables(("q_m", "float64", (3,)), ("n", "int32", ()), ("DH", "float64", (2, 4)), ("gain", "float32", ()))


@pytest.fixture
def run() -> Iterator[Any]:
    """A live run's table: (subsystem, table); closed and unlinked after the test."""
    made: list[StateTable] = []

    def make(var_specs=VARS, n_tasks: int = 3) -> tuple[str, StateTable]:
        subsystem = f"svar{uuid.uuid4().hex[:6]}"
        table = StateTable.create(TableLayout.build(var_specs, n_tasks),
                                  messages.table_name(subsystem, f"{os.getpid()}-{uuid.uuid4().hex[:6]}"))
        made.append(table)
        return subsystem, table

    yield make
    for table in made:
        table.close()


def test_open_table_reads_names_values_sequence_and_job_control_as_writer(run):
    subsystem, table = run()
    table.write("q_m", [0.1, -0.2, 0.3], when=time.monotonic())
    table.write("q_m", [0.5, -0.2, 0.3], when=time.monotonic())
    table.write("n", 6, when=time.monotonic())
    with open_table(subsystem) as view:
        assert view.variables() == ["q_m", "n", "DH", "gain"]
        value, seq, _when, writer = view.read("q_m")
        assert value.tolist() == [0.5, -0.2, 0.3]
        assert (seq, writer) == (2, -1)
        assert value.dtype == np.float64 and value.flags.writeable  # a copy, not a view of the table
        n, seq, _, _ = view.read("n")
        assert (n.item(), n.dtype, seq) == (6, np.int32, 1)
        assert view.read("DH")[0].shape == (2, 4)


def test_age_is_seconds_since_the_write_on_the_monotonic_clock(run):
    subsystem, table = run()
    written = time.monotonic()
    table.write("q_m", [1, 2, 3], when=written)
    with open_table(subsystem) as view:
        assert view.age("q_m") >= 0
        assert view.age("q_m", now=written + 0.25) == pytest.approx(0.25)
        assert view.age("n") == math.inf  # never written


def test_on_a_simulated_clock_run_age_is_counted_on_its_simulated_time(run):
    subsystem, table = run()
    table.header[Header.SIM_TICK] = 40  # as the supervisor releases ticks of a --clock sim run
    table.header[Header.SIM_TIME_NS] = 2_000_000_000
    table.write("q_m", [1, 2, 3], when=1.75)
    with open_table(subsystem) as view:
        assert view.age("q_m") == pytest.approx(0.25)
        [row] = svar_rows(view, ["q_m"])
        assert row["age_ms"] == pytest.approx(250.0)


def test_on_a_simulated_clock_run_before_its_first_tick_age_is_counted_from_time_zero(run):
    subsystem, table = run()
    table.set_flag(Flag.SIM_CLOCK, True)  # as the lockstep marks a --clock sim run's table before any tick
    table.write("q_m", [1, 2, 3], when=0.0)  # job control's initial value, at simulated time 0
    with open_table(subsystem) as view:
        assert view.now() == 0.0
        [row] = svar_rows(view, ["q_m"])
        assert row["age_ms"] == 0.0


def test_a_task_written_variable_takes_sequence_and_time_from_the_tasks_status_block(run):
    subsystem, table = run()
    table.write("q_m", [1, 2, 3], when=1.0, writer=2)
    table.status[2][StatusWord.CYCLES] = 42
    table.status[2][StatusWord.RELEASE] = 7.5
    with open_table(subsystem) as view:
        assert view.read("q_m")[1:] == (42, 7.5, 2)


def test_task_status_reads_every_tasks_block(run):
    subsystem, table = run(n_tasks=2)
    table.status[1][StatusWord.STATE] = TaskState.ON
    table.status[1][StatusWord.CYCLES] = 1000
    table.status[1][StatusWord.JITTER_MAX] = 90e-6
    with open_table(subsystem) as view:
        rows = view.task_status()
    assert [r["index"] for r in rows] == [0, 1]
    assert rows[0]["state"] == "NOT_CREATED"
    assert (rows[1]["state"], rows[1]["cycles"], rows[1]["jitter_max"]) == ("ON", 1000, 90e-6)


def test_an_unknown_variable_names_the_choices(run):
    subsystem, _ = run()
    with (open_table(subsystem) as view,
          pytest.raises(KeyError, match=r"no variable 'q_x' in the table of 'svar\w+' \(variables: q_m, n, DH, gain\)")):
        view.read("q_x")


def test_a_segment_with_a_wrong_magic_fails_clearly():
    subsystem = f"svar{uuid.uuid4().hex[:6]}"
    name = messages.table_name(subsystem, f"{os.getpid()}-{uuid.uuid4().hex[:6]}")
    _shm_object, mapping = shm.create_segment(name, 4096)
    try:
        with pytest.raises(TableLayoutError,
                           match=rf"^'{name}' is not a pbo state variable table \(magic 0x0, expected {MAGIC:#x}\)"):
            open_table(subsystem)
    finally:
        mapping.close()
        shm.unlink_quietly("shm", name)


def test_a_table_of_another_version_fails_clearly(run):
    subsystem, table = run()
    table.header[Header.VERSION] = 99
    with pytest.raises(TableLayoutError, match=rf"has layout version 99, this pbo reads version {VERSION}"):
        open_table(subsystem)


def test_a_directory_pointing_outside_the_segment_fails_clearly(run):
    subsystem, table = run()
    table.header[Header.N_VARIABLES] = 10_000
    with pytest.raises(TableLayoutError, match=r"its directory \(10000 records at byte \d+\) lies outside the segment"):
        open_table(subsystem)


def test_open_table_without_a_run_says_no_subsystem_is_running():
    with pytest.raises(PboError, match=r"^subsystem 'nosuch' is not running"):
        open_table("nosuch")


# --- what pbo svar shows --------------------------------------------------------------------


def test_values_show_four_decimals_and_integers_as_they_are():
    assert format_value(np.array([0.1, -0.25])) == "[+0.1000, -0.2500]"
    assert format_value(np.float64(2.0)) == "+2.0000"
    assert format_value(np.array(6, dtype=np.int32)) == "6"
    assert "..." in format_value(np.zeros(100))


def test_svar_rows_show_age_sequence_and_writer_by_name_or_index(run):
    subsystem, table = run()
    now = time.monotonic()
    table.write("q_m", [0.1, 0.2, 0.3], when=now - 0.5)
    table.write("n", 6, when=now - 0.5, writer=1)
    table.status[1][StatusWord.CYCLES] = 9
    table.status[1][StatusWord.RELEASE] = now - 0.002
    table.write("gain", 2.0, when=now, writer=2)
    with open_table(subsystem) as view:
        rows = {r["name"]: r for r in svar_rows(view, writers={1: "pid"}, now=now)}
    assert rows["q_m"]["value"] == "[+0.1000, +0.2000, +0.3000]"
    assert (rows["q_m"]["writer"], rows["q_m"]["sequence"]) == ("job control", 1)
    assert rows["q_m"]["age_ms"] == pytest.approx(500.0)
    assert (rows["n"]["writer"], rows["n"]["sequence"], rows["n"]["age_ms"]) == ("pid", 9, pytest.approx(2.0))
    assert rows["gain"]["writer"] == "task #2"
    assert (rows["DH"]["age_ms"], rows["DH"]["writer"]) == (None, "—")
    console = Console(record=True, width=200, color_system=None)
    console.print(svar_table(list(rows.values())))
    assert "never" in console.export_text()


def test_pbo_svar_prints_the_table_when_no_supervisor_answers(run):
    subsystem, table = run()
    table.write("q_m", [0.1, 0.2, 0.3], when=time.monotonic(), writer=0)
    console = Console(record=True, width=200, color_system=None)
    assert operator.svar(console, ["q_m", "n"], watch=False, subsystem=subsystem) == 0
    text = console.export_text()
    assert "+0.1000" in text and "task #0" in text and "DH" not in text


def test_pbo_svar_watch_refreshes_and_returns_zero(run):
    subsystem, _ = run()
    console = Console(record=True, width=200, color_system=None)
    assert operator.svar(console, [], watch=True, interval=0.01, subsystem=subsystem, updates=2) == 0
    assert "gain" in console.export_text()


def test_pbo_svar_says_table_busy_when_a_writer_stopped_mid_write_and_never_waits_on_it(run):
    # Issue 18: a writer stopped mid-write leaves the table's write sequence odd. The one-shot
    # read gives up with "table busy"; the watch keeps going and says so in its title.
    subsystem, table = run()
    table.acquire()
    before = table.begin_write()
    try:
        with pytest.raises(PboError, match=r"^table busy: "):
            operator.svar(Console(record=True), ["q_m"], watch=False, subsystem=subsystem)
        console = Console(record=True, width=200, color_system=None)
        assert operator.svar(console, [], watch=True, interval=0.01, subsystem=subsystem, updates=2) == 0
        assert "table busy (a writer stopped mid-write), last values shown" in " ".join(console.export_text().split())
    finally:
        table.end_write(before)
        table.release()


def test_pbo_svar_suggests_a_close_name_for_an_unknown_variable(run):
    subsystem, _ = run()
    with pytest.raises(PboError, match=r"^no variable 'q_n' in 'svar\w+' \(did you mean 'q_m'\?\); variables: q_m, n, DH, gain$"):
        operator.svar(Console(record=True), ["q_n"], watch=False, subsystem=subsystem)
