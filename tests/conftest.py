"""Shared fixtures: real tables in real shared memory, removed after each test."""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import pytest

from pbo_runtime.config.model import PortBinding, TaskSpec, VariableSpec
from pbo_runtime.objects.module import PortBasedObject
from pbo_runtime.table.table import StateTable, TableLayout

REPO = Path(__file__).resolve().parent.parent


def unique_name(part: str = "table") -> str:
    """A run-style object name no other test or run uses."""
    return f"/pbo.test.{os.getpid()}-{uuid.uuid4().hex[:6]}.{part}"


def variables(*specs: tuple[str, str, tuple[int, ...]]) -> list[VariableSpec]:
    return [VariableSpec(name, i, dtype, shape) for i, (name, dtype, shape) in enumerate(specs)]


def task_spec(module: type[PortBasedObject], name: str = "t", index: int = 0, ports: dict[str, str] | None = None,
              dims: dict[str, int] | None = None, params: dict | None = None, period: float = 0.001) -> TaskSpec:
    """A TaskSpec binding each declared port to its default variable (or `ports[name]`)."""
    ports = ports or {}
    bindings = tuple(
        PortBinding(p, ports.get(p.name, p.variable), p.resolved_shape(dims or {})) for p in module.ports()
    )
    return TaskSpec(name=name, module=module.__name__, rtpu="rtpu0", period=period, params=params or {},
                    bindings=bindings, index=index)


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


@pytest.fixture
def no_leftover_ipc():
    """Fail the test if it leaves behind a segment, semaphore or queue named by this test process.

    Only names with this pytest process's pid count (`unique_name`), so objects of other test
    runs on the machine do not. Leftovers are removed before the failure is reported.
    """
    mine = f"pbo.test.{os.getpid()}-"

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
