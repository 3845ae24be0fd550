"""`pbo lexicon` as data: every registered module with its ports and parameters."""

from __future__ import annotations

import json
import subprocess
import sys
import typing

import pytest
from rich.console import Console
from rich.table import Table

from pbo_runtime.objects import registry
from pbo_runtime.reports.lexicon import as_table, drivers, lexicon, shape_text, type_text
from tests.support import REPO


def _by_name() -> dict[str, dict]:
    return {e["name"]: e for e in lexicon()}


def test_every_module_appears_with_its_ports_and_params():
    entries = lexicon()
    assert [e["name"] for e in entries] == list(registry.names(registry.MODULES))
    for entry in entries:
        cls = registry.module_class(entry["name"])
        assert "error" not in entry
        assert entry["summary"], entry["name"]
        assert [p["name"] for p in entry["ports"]] == [p.name for p in cls.ports()]
        for port in entry["ports"]:
            assert set(port) == {"name", "kind", "variable", "dtype", "shape", "doc"}
        for param in entry["params"]:
            assert {"name", "type", "default", "required", "doc"} <= set(param)
    json.loads(json.dumps(entries))  # JSON-able as it is


def test_pid_joint_shows_its_ports_and_gains():
    pid = _by_name()["pid_joint"]
    assert pid["summary"] == "PID joint position controller."
    params = {p["name"]: p for p in pid["params"]}
    assert params["kp"]["default"] == 400.0 and params["kp"]["type"] == "float | tuple[float, ...]"
    assert params["kp"]["doc"] == "N m / rad" and not params["kp"]["required"]
    assert params["kp"]["range"] == "in [0, 1e+06]" and params["integral_limit"]["range"] == "in [0, 10000]"
    assert params["gravity_feedforward"] == {"name": "gravity_feedforward", "type": "bool", "default": True,
                                             "required": False, "doc": "", "range": ""}
    ports = {p["name"]: p for p in pid["ports"]}
    assert ports["tau"] == {"name": "tau", "kind": "out-var", "variable": "tau_u", "dtype": "float64", "shape": "[NDOF]",
                            "doc": "joint torque command, N m"}
    assert ports["ndof"]["kind"] == "in-const" and ports["ndof"]["shape"] == "[]"
    assert pid["note"] is None


def test_modules_whose_ports_depend_on_params_say_so():
    logger = _by_name()["data_logger"]
    assert logger["note"] and "params.variables" in logger["note"]
    params = {p["name"]: p for p in logger["params"]}
    assert params["variables"]["required"] and params["variables"]["default"] is None
    assert params["variables"]["type"] == "tuple[str, ...]"


def test_every_driver_declares_its_kind_its_options_and_whether_it_needs_the_plant():
    entries = {e["name"]: e for e in drivers()}
    assert all(e["device_kind"] and e["options"] is not None for e in entries.values()), entries
    assert (entries["mujoco_arm"]["device_kind"], entries["mujoco_arm"]["options"], entries["mujoco_arm"]["needs_plant"]) == (
        "arm", ["mode"], True)
    assert (entries["spp"]["device_kind"], entries["spp"]["needs_plant"]) == ("spp", False)  # a process of its own


def test_texts():
    assert shape_text(None) == "as variable"
    assert shape_text(("NDOF", 4)) == "[NDOF, 4]"
    assert type_text(float | tuple[float, ...]) == "float | tuple[float, ...]"
    assert type_text(str | None) == "str | None"
    assert type_text(typing.Literal["raise", "hang"]) == '"raise" | "hang"'


def test_table_shows_every_module():
    table = as_table(lexicon())
    assert isinstance(table, Table)
    console = Console(width=160, record=True, color_system=None)
    console.print(table)
    text = console.export_text()
    for name in registry.names(registry.MODULES):
        assert name in text
    assert "kp: float | tuple[float, ...]" in text and "400.0" in text
    assert "as variable" in text or "(none declared)" in text


IMPORT_LIBRARY = """
import json, sys
from importlib import metadata
from pbo_runtime.objects import registry
failed = registry.import_library()
left = [ep.value for group in (registry.MODULES, registry.DRIVERS) for ep in metadata.entry_points(group=group)
        if ep.module not in sys.modules]
print(json.dumps([failed, left]))
"""


@pytest.mark.multiprocess
def test_an_rtpu_can_import_the_whole_library_before_its_tasks_run_so_a_live_spawn_imports_nothing():
    done = subprocess.run([sys.executable, "-c", IMPORT_LIBRARY], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == [[], []]
