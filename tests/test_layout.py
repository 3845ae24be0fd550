"""The house: pbo_runtime's wings, the one-way imports between them, and the public surface.

A newcomer finds where a change goes by the folder names alone; these tests keep it so. Wings are
ranked low to high, and a file may import its own wing or a lower one only: config/ (the format and
its checker) under analysis/ (what a file predicts) under edit/ (changing a file and writing it back).
"""

from __future__ import annotations

import ast
import graphlib
import re
import tomllib
from pathlib import Path

import pytest

import pbo_runtime
from tests.support import REPO

PACKAGE = REPO / "pbo_runtime"

# low to high; wings of one rank do not import each other
WING_RANK = {
    "errors": 0,
    "objects": 1,
    "ipc": 1,
    "links": 2,
    "config": 3,
    "analysis": 4,
    "table": 4,
    "reports": 4,
    "edit": 5,
    "clock": 5,
    "task": 5,
    "supervisor": 6,
    "api": 7,
    "cli": 8,
    "__init__": 9,
}

# wings of files, not code: the browser HMI's page, served by api/ and shipped in the package
ASSET_WINGS = ("hmi",)

PUBLIC_NAMES = [
    "ANY_DTYPE", "ARM_COLUMNS", "Arm", "EE_COLUMNS", "GRAVITY", "ROBOT_OPTIONS", "ROBOT_SUFFIXES", "MAX_PRIORITY", "ConfigError",
    "ConfigErrors", "DdsProcess", "DeviceDriver", "InBoth", "InConst", "InVar",
    "InternalError", "LifecycleError", "LinkFullError", "ModuleError", "NoParams", "OutBoth", "OutConst", "OutVar",
    "OperatorInput", "OutputError", "ParamError", "PboError", "PortBasedObject", "PortKind", "PortSpec",
    "ResourceLimitError", "Status",
    "TableLayoutError", "Waypoints",
    "arm_gains", "arm_model", "attach_segment", "below_the_cycle", "create_segment", "format_channels", "inertia_range",
    "is_robot_file", "module_class", "open_log", "param", "process_below_the_cycle", "read_log",
    "registered_robot", "require_extra", "ros2_messages", "serve_dds_process", "sleep_while_cycling", "unlink_quietly",
]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path, known: set[str]) -> set[str]:
    """Every module `path` imports, wherever the import stands (a function, `if TYPE_CHECKING:`)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                submodule = f"{node.module}.{alias.name}"
                found.add(submodule if submodule in known else node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found


def runtime_imports() -> dict[str, set[str]]:
    files = {module_name(path): path for path in PACKAGE.rglob("*.py")}
    known = set(files)
    return {name: {m for m in imported_modules(path, known) if m.startswith("pbo_runtime")} - {name}
            for name, path in files.items()}


def wing_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_the_package_root_holds_only_the_public_surface_and_the_wings():
    files = sorted(p.name for p in PACKAGE.iterdir() if p.is_file() and p.suffix == ".py")
    wings = sorted(p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert files == ["__init__.py", "errors.py"]
    assert wings == sorted([*(w for w in WING_RANK if w not in ("errors", "__init__")), *ASSET_WINGS])


def test_every_wing_and_file_says_what_it_is_for():
    missing = [str(p.relative_to(REPO)) for p in PACKAGE.rglob("*.py") if ast.get_docstring(ast.parse(p.read_text())) is None
               and p.name != "__main__.py"]
    assert missing == []


def test_no_module_of_the_runtime_imports_one_that_imports_it_back():
    graphlib.TopologicalSorter(runtime_imports()).prepare()  # raises CycleError, naming the cycle


def test_a_wing_imports_only_its_own_and_lower_wings():
    upward = sorted(f"{module} imports {imported}"
                    for module, imports in runtime_imports().items() for imported in imports
                    if wing_of(module) != wing_of(imported) and WING_RANK[wing_of(imported)] >= WING_RANK[wing_of(module)])
    assert upward == []


def test_the_format_imports_neither_what_a_file_predicts_nor_how_a_file_is_edited():
    """config/ is the format and its checker; analysis/ and edit/ are built on it, never the other way."""
    wrong = sorted(f"{module} imports {imported}" for module, imports in runtime_imports().items() if wing_of(module) == "config"
                   for imported in imports if wing_of(imported) in ("analysis", "edit"))
    assert wrong == []


def test_a_subsystem_file_is_written_back_in_one_place():
    """A draft is moved over a subsystem file by edit/write_back.py alone; the rest of edit/ writes through it."""
    movers = sorted(p.relative_to(PACKAGE).as_posix() for p in (PACKAGE / "edit").rglob("*.py") if "os.replace(" in p.read_text())
    assert movers == ["edit/write_back.py"]


def test_the_hmis_files_are_served_from_their_wing_and_every_one_is_shipped():
    from pbo_runtime.api import app

    patterns = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["pbo_runtime"]
    shipped = {path for pattern in patterns for path in PACKAGE.glob(pattern) if path.is_file()}
    assert app.STATIC == PACKAGE / "hmi"
    assert shipped == {path for path in app.STATIC.rglob("*") if path.is_file()}


@pytest.mark.parametrize("folder", ["modules", "drivers"])
def test_modules_and_drivers_use_only_the_public_surface_and_never_each_other(folder):
    other = {"modules": "drivers", "drivers": "modules"}[folder]
    wrong = []
    for path in (REPO / folder).rglob("*.py"):
        for imported in imported_modules(path, set()):
            top = imported.split(".")[0]
            if (top == "pbo_runtime" and imported != "pbo_runtime") or top in (other, "rtpu"):
                wrong.append(f"{path.relative_to(REPO)} imports {imported}")
    assert wrong == []


def test_the_runtime_finds_modules_drivers_and_plants_by_name_never_by_import():
    wrong = [f"{module} imports {imported}" for module, path in
             ((module_name(p), p) for p in PACKAGE.rglob("*.py"))
             for imported in imported_modules(path, set())
             if imported.split(".")[0] in ("modules", "drivers", "rtpu")]
    assert wrong == []


# Files still to split by concept; each leaves this list when its split lands
LONG_FILES_BEING_SPLIT: set[str] = set()
MAX_LINES = 600


def test_no_file_of_the_runtime_or_the_rtpu_is_over_600_lines():
    """A file that long holds more than one concept: split it by concept, as its wing is split."""
    long = sorted(f"{path.relative_to(REPO)}: {lines} lines"
                  for folder in ("pbo_runtime", "rtpu") for path in (REPO / folder).rglob("*.py")
                  if (lines := len(path.read_text().splitlines())) > MAX_LINES
                  and str(path.relative_to(REPO)) not in LONG_FILES_BEING_SPLIT)
    assert long == []


def test_the_public_surface_is_pinned():
    assert sorted(pbo_runtime.__all__) == sorted(PUBLIC_NAMES)
    assert all(hasattr(pbo_runtime, name) for name in PUBLIC_NAMES)


# --- the test suite ----------------------------------------------------------------------------

# `from tests.test_x import ...`, `from tests import test_x`, `from .test_x import ...`, and the same of conftest,
# anywhere in a file's text: a script a test runs in a fresh interpreter counts too
IMPORT_OF_A_TEST_FILE = re.compile(
    r"^\s*(?:from|import)\s+(?:tests)?\.?(?P<module>test_\w+|conftest)\b"
    r"|^\s*from\s+(?:tests|\.)\s+import\s+[^\n]*?\b(?P<named>test_\w+|conftest)\b",
    re.MULTILINE,
)


def test_no_test_file_imports_another_test_file_or_the_conftest():
    """Shared helpers are in tests/support.py and fixtures in conftest.py (pytest hands them over by name),
    so each test file reads, runs and moves on its own."""
    wrong = sorted(f"{path.name} imports {match['module'] or match['named']}"
                   for path in (REPO / "tests").glob("*.py")
                   for match in IMPORT_OF_A_TEST_FILE.finditer(path.read_text()))
    assert wrong == []
