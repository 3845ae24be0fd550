"""Shared fixtures: real tables in real shared memory, removed after each test.

Plain helpers (names, specs, fakes) are in tests/support.py; test files import those, never each other.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pbo_runtime.config.model import VariableSpec
from pbo_runtime.table.table import StateTable, TableLayout
from tests.support import unique_name


@pytest.fixture
def make_table():
    """Create real tables; every one is closed and unlinked after the test."""
    made: list[StateTable] = []

    def make(var_specs: list[VariableSpec], n_tasks: int = 4) -> StateTable:
        table = StateTable.create(TableLayout.build(var_specs, n_tasks), unique_name())
        made.append(table)
        return table

    yield make
    for table in made:
        table.close()


@pytest.fixture(autouse=True)
def no_leftover_ipc():
    """Fail any test that leaves behind a segment, semaphore or queue named with this test process's pid.

    That is every name `unique_name` makes (`pbo.test.<pid>-...`) and every run this process starts or
    fakes (`pbo.<subsystem>.<pid>-...`); objects of other processes, other test runs on the machine
    included, do not count. Autouse, and so set up before and torn down after every fixture a test
    asks for: whatever made the object has closed it by then. Leftovers are removed before the
    failure is reported, so one test's leak does not fail the next.
    """
    mine = f".{os.getpid()}-"

    def ours() -> set[Path]:
        found: set[Path] = set()
        for folder in (Path("/dev/shm"), Path("/dev/mqueue")):
            if folder.is_dir():
                found |= {folder / entry for entry in os.listdir(folder) if mine in entry}
        return found

    before = ours()
    yield
    left = ours() - before
    for path in left:
        path.unlink(missing_ok=True)
    assert not left, f"left behind: {sorted(map(str, left))}"
