"""The global state variable table: layout, lock, metadata, attach checks, cleanup."""

from __future__ import annotations

import itertools
import os
import stat
import threading

import numpy as np
import posix_ipc
import pytest

from pbo_runtime import InVar, OutVar, PortBasedObject, TableLayoutError
from pbo_runtime.table.directory import DIRECTORY_RECORD, Entry, read_directory
from pbo_runtime.table.table import HEADER_WORDS, Header, StateTable, TableLayout
from pbo_runtime.task.transfer import LocalTable
from tests.support import allocation_peak, one_array, task_spec, unique_name, variables


class Copier(PortBasedObject):
    """Fake module: four inputs, two outputs (the benchmark's shape)."""

    a = InVar("a", shape=(6,))
    b = InVar("b", shape=(6,))
    c = InVar("c", shape=(6,))
    d = InVar("d", shape=(6,))
    x = OutVar("x", shape=(6,))
    y = OutVar("y", shape=(6,))


VARS = variables(*[(n, "float64", (6,)) for n in "abcdxy"], ("n", "int32", ()))


def test_table_segment_and_lock_are_created_owner_only(make_table):
    table = make_table(VARS)
    mode = os.stat("/dev/shm/" + table.name[1:]).st_mode
    assert stat.S_IMODE(mode) == 0o600
    assert stat.S_IMODE(os.stat("/dev/shm/sem." + table.lock_name[1:]).st_mode) == 0o600


def test_close_by_the_creator_unlinks_segment_and_lock():
    name = unique_name()
    table = StateTable.create(TableLayout.build(VARS, 1), name)
    table.close()
    with pytest.raises(posix_ipc.ExistentialError):
        posix_ipc.SharedMemory(name)
    with pytest.raises(posix_ipc.ExistentialError):
        posix_ipc.Semaphore(name + ".lock")


def test_attaching_with_another_layout_fails_clearly(make_table):
    table = make_table(VARS)
    other = TableLayout.build(variables(("a", "float64", (7,))), 1)
    with pytest.raises(TableLayoutError, match=r"another variable layout"):
        StateTable.attach(other, table.name)


def test_attaching_to_a_missing_table_says_so():
    with pytest.raises(TableLayoutError, match=r"^no state variable table"):
        StateTable.attach(TableLayout.build(VARS, 1), unique_name())


def test_variables_are_aligned_and_do_not_overlap():
    layout = TableLayout.build(VARS, 2)
    spans = sorted((s.data_byte, s.data_byte + s.nbytes) for s in layout.slots)
    assert all(start % 8 == 0 for start, _ in spans)
    assert all(end <= nxt for (_, end), (nxt, _) in itertools.pairwise(spans))
    assert layout.status_offset >= spans[-1][1]


def test_the_directory_reads_back_every_variable_as_the_layout_placed_it(make_table):
    long_name = "v" * 60  # longer than a record's name field: cut, as every reader sees it
    table = make_table(variables(("q_m", "float64", (6,)), ("n", "int32", ()), ("J", "float32", (6, 7)),
                                 ("flags", "bool", (2, 3, 4, 1)), (long_name, "uint8", (3,))))
    h = table.header
    found = read_directory(table.name, table._mapping, int(h[Header.N_VARIABLES]), int(h[Header.DIRECTORY_OFFSET]),
                           int(h[Header.TOTAL_BYTES]), HEADER_WORDS * 8)
    assert list(found.values()) == [Entry(s.name[:48], s.dtype, s.shape, s.meta_word, s.data_byte, s.nbytes)
                                    for s in table.layout.slots]


def test_a_directory_record_with_a_dtype_no_table_holds_is_refused(make_table):
    table = make_table(VARS)
    offset = table.layout.directory_offset
    record = bytearray(table._mapping[offset : offset + DIRECTORY_RECORD])
    record[48:64] = b"complex128".ljust(16, b"\0")
    with pytest.raises(TableLayoutError,
                       match=r"^table 'T', directory record 0 \('a'\): dtype 'complex128' is not one a table holds \(float64, "):
        read_directory("T", bytes(record), 1, 0, DIRECTORY_RECORD, 0)


def test_job_control_write_stamps_sequence_time_and_writer(make_table):
    table = make_table(VARS)
    table.write("a", np.arange(6.0), when=1.5)
    value, seq, when, writer = table.read("a")
    assert value.tolist() == [0, 1, 2, 3, 4, 5]
    assert (seq, when, writer) == (1, 1.5, -1)
    table.write("a", np.arange(6.0), when=2.5)
    assert table.read("a")[1:] == (2, 2.5, -1)
    table.write("n", 6, when=2.0)
    assert table.read("n")[0] == 6


def test_a_cycle_transfer_allocates_no_array(make_table):
    local = LocalTable(make_table(VARS), task_spec(Copier).bindings, 0)

    def transfer() -> None:
        local.read_inputs()
        local.write_outputs()

    assert allocation_peak(transfer) < one_array()


def test_a_cycle_transfer_moves_inputs_and_stamps_outputs(make_table):
    table = make_table(VARS)
    for name in "abcd":
        table.write(name, np.full(6, ord(name)), when=0.0)
    local = LocalTable(table, task_spec(Copier, index=2).bindings, task_index=2)
    a, b, c, d, x, y = local.port_arrays
    local.read_inputs()
    assert a[0] == ord("a") and d[5] == ord("d")
    assert local.input_writer.tolist() == [-1, -1, -1, -1]  # job control wrote them
    np.add(a, b, out=x)
    np.subtract(c, d, out=y)
    local.status[1] = 7  # the executive's cycle count and release time: the outputs' stamp
    local.status[7] = 3.25
    local.write_outputs()
    value, seq, when, writer = table.read("x")
    assert value[0] == ord("a") + ord("b")
    assert (seq, when, writer) == (7, 3.25, 2)
    assert table.header[Header.LOCK_HOLDER] == os.getpid()


def test_a_cycle_transfer_gives_up_a_lock_held_past_the_tables_wait_and_moves_nothing(make_table):
    table = make_table(VARS)
    table.write("a", np.full(6, 1.0), when=0.0)
    local = LocalTable(table, task_spec(Copier, index=2).bindings, task_index=2)
    a, _, _, _, x, _ = local.port_arrays
    table.cycle_lock_wait[0] = 0.0001  # as an RTPU hosting a critical task sets it
    table.acquire()  # held, as by a process that died holding it
    try:
        x[:] = 5.0
        assert local.read_inputs() is False and local.write_outputs() is False
        assert a[0] == 0.0 and table.read("x")[0][0] == 0.0
    finally:
        table.release()
    assert local.read_inputs() is True and a[0] == 1.0
    assert local.write_outputs() is True and table.read("x")[0][0] == 5.0


def test_the_values_on_and_off_leave_are_written_however_long_the_lock_is_held(make_table):
    table = make_table(VARS)
    local = LocalTable(table, task_spec(Copier, index=2).bindings, task_index=2)
    local.port_arrays[4][:] = 7.0
    table.cycle_lock_wait[0] = 0.0  # a per-cycle transfer would not wait at all
    table.acquire()
    releaser = threading.Timer(0.05, table.release)  # the holder lets go (or job control recovers the lock)
    releaser.start()
    local.publish_outputs()  # waits for it
    releaser.join()
    assert table.read("x")[0][0] == 7.0


def test_transfer_indices_do_not_grow_with_the_table(make_table):
    small = LocalTable(make_table(VARS), task_spec(Copier).bindings, 0)
    big_vars = VARS + variables(*[(f"z{i}", "float64", (6,)) for i in range(500)])[len(VARS):]
    big_vars = VARS + [v.__class__(v.name, len(VARS) + i, v.dtype, v.shape) for i, v in enumerate(big_vars[len(VARS):])]
    big = LocalTable(make_table(big_vars), task_spec(Copier).bindings, 0)
    assert [g.index.size for g in big._in_var.groups] == [g.index.size for g in small._in_var.groups]


@pytest.mark.parametrize("ceiling", [1, None])
def test_job_control_holds_the_lock_at_its_ceiling_priority_and_runs_as_before_after(make_table, ceiling):
    """A SCHED_OTHER holder preempted by any process would keep every RTPU waiting for the lock."""
    table = make_table(variables(("x", "float64", (3,))))
    table.lock_ceiling = ceiling
    seen: list[tuple[int, int]] = []

    def hold() -> None:  # (a thread of its own: the test's thread keeps its scheduling whatever happens)
        me = threading.get_native_id()
        table.acquire()
        try:
            seen.append((os.sched_getscheduler(me), os.sched_getparam(me).sched_priority))
        finally:
            table.release()
        seen.append((os.sched_getscheduler(me), os.sched_getparam(me).sched_priority))

    holder = threading.Thread(target=hold)
    holder.start()
    holder.join()
    if ceiling is not None and seen[0] == (os.SCHED_OTHER, 0):
        pytest.skip("SCHED_FIFO refused here: the holder runs as it did")
    held_at = (os.SCHED_FIFO, 1) if ceiling else (os.SCHED_OTHER, 0)
    assert seen == [held_at, (os.SCHED_OTHER, 0)]
