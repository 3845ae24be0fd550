"""Fuzz the checker with broken versions of every shipped configuration: never a traceback.

Hypothesis (seeded) mutates each file in configs/ one to three times: a key deleted or renamed to
a non-text key, a value replaced by one of the wrong type or a huge number, a line indented by
1-3 spaces or a tab, unicode inserted (emoji, RTL marks, NUL and other control characters,
combining marks, a BOM) or raw bytes that are not UTF-8, the file truncated at a byte, a line
duplicated, two lines swapped. `check_file`, with the real module library, must return
diagnostics that each carry a code and a location in the file checked; `pbo check` must exit 0
or 1 without a traceback.
"""

from __future__ import annotations

import itertools
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from pbo_runtime.config.loader import check_file

REPO = Path(__file__).resolve().parent.parent
SHIPPED = sorted((REPO / "configs").glob("*.yaml"))
CLI_RUNS = max(3, 10 // max(1, len(SHIPPED)))  # about ten `pbo check` processes in all (~0.3 s each)

# --- mutations ---------------------------------------------------------------------------------

INDEX = st.integers(0, 10**6)  # taken modulo the number of lines, keys, bytes ...

HUGE = [1e308, -1e308, 10**40, -(10**40), -1, 0, 2**31, 2**63, float("inf"), float("-inf"), float("nan")]
WRONG_VALUES = st.one_of(
    st.lists(st.one_of(st.integers(-3, 3), st.text(max_size=3)), max_size=3),
    st.dictionaries(st.text(max_size=4), st.integers(-3, 3), max_size=2),
    st.text(max_size=8),
    st.integers(-10, 10),
    st.floats(),
    st.sampled_from(HUGE),
    st.none(),
    st.booleans(),
)
WRONG_KEYS = st.one_of(st.integers(-2, 2), st.none(), st.booleans(), st.floats(allow_nan=False))
HUGE_TEXT = ["1e308", "-1e308", "1" + "0" * 40, "-1", "0", "1e999", ".nan", "-.inf", "0x7fffffffffffffff"]
UNICODE = [
    "\U0001f916",  # emoji
    "\u200f", "\u202e", "\u2066",  # right-to-left mark, override, isolate
    "\x00", "\x07", "\x1b", "\x7f", "\x85", "\x0b", "\r",  # NUL and other control characters
    "\u0301", "\u20dd",  # combining marks
    "\ufeff", "\u2028", "\ufffe", "\U0010ffff",
]
NOT_UTF8 = [b"\xff", b"\xfe\xff", b"\xc3\x28", b"\x80", b"\xe9", b"\xed\xa0\x80", b"\xf4\x90\x80\x80"]

MUTATION = st.one_of(
    st.tuples(st.just("delete key"), INDEX),
    st.tuples(st.just("wrong value"), INDEX, WRONG_VALUES),
    st.tuples(st.just("wrong key"), INDEX, WRONG_KEYS),
    st.tuples(st.just("indent"), INDEX, st.integers(1, 3)),
    st.tuples(st.just("tab"), INDEX, INDEX),
    st.tuples(st.just("huge number"), INDEX, st.sampled_from(HUGE_TEXT)),
    st.tuples(st.just("unicode"), INDEX, INDEX, st.sampled_from(UNICODE)),
    st.tuples(st.just("not utf-8"), INDEX, st.sampled_from(NOT_UTF8)),
    st.tuples(st.just("truncate"), INDEX),
    st.tuples(st.just("duplicate line"), INDEX),
    st.tuples(st.just("swap lines"), INDEX, INDEX),
)
MUTATIONS = st.lists(MUTATION, min_size=1, max_size=3)


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key of every mapping and index of every list, depth first."""
    found: list[tuple[Any, ...]] = []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        found.append((*prefix, key))
        found.extend(_paths(value, (*prefix, key)))
    return found


def _structural(data: bytes, mutation: tuple[Any, ...]) -> bytes:
    """Delete a key, replace a value or a key, in the YAML's data; the file is written anew."""
    try:
        doc = yaml.safe_load(data)
    except (yaml.YAMLError, ValueError):
        return data  # an earlier mutation broke the YAML: nothing to walk
    paths = _paths(doc)
    if not paths:
        return data
    path = paths[mutation[1] % len(paths)]
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    last = path[-1]
    if mutation[0] == "delete key":
        del parent[last]
    elif mutation[0] == "wrong value":
        parent[last] = mutation[2]
    elif isinstance(parent, dict) and mutation[2] not in parent:
        parent[mutation[2]] = parent.pop(last)
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True, default_flow_style=None).encode("utf-8")


def _textual(data: bytes, mutation: tuple[Any, ...]) -> bytes:
    kind = mutation[0]
    if kind == "truncate":
        return data[: mutation[1] % (len(data) + 1)]
    lines = data.split(b"\n")
    i = mutation[1] % len(lines)
    line = lines[i]
    if kind == "indent":
        lines[i] = b" " * mutation[2] + line
    elif kind == "tab":
        at = mutation[2] % (len(line) + 1)
        lines[i] = line[:at] + b"\t" + line[at:]
    elif kind == "huge number":
        lines[i] = re.sub(rb"-?\d+(\.\d+)?", mutation[2].encode(), line, count=1)
    elif kind == "unicode":
        at = mutation[2] % (len(line) + 1)
        lines[i] = line[:at] + mutation[3].encode("utf-8") + line[at:]
    elif kind == "not utf-8":
        at = len(line) // 2
        lines[i] = line[:at] + mutation[2] + line[at:]
    elif kind == "duplicate line":
        lines.insert(i, line)
    elif kind == "swap lines":
        j = mutation[2] % len(lines)
        lines[i], lines[j] = lines[j], lines[i]
    return b"\n".join(lines)


def mutate(data: bytes, mutations: list[tuple[Any, ...]]) -> bytes:
    for mutation in mutations:
        if mutation[0] in ("delete key", "wrong value", "wrong key"):
            data = _structural(data, mutation)
        else:
            data = _textual(data, mutation)
    return data


_DIR = tempfile.TemporaryDirectory(prefix="pbo-checker-fuzz-")  # @given does not mix with tmp_path
_COUNTER = itertools.count()


def write_mutant(config: Path, mutations: list[tuple[Any, ...]]) -> tuple[Path, bytes]:
    data = mutate(config.read_bytes(), mutations)
    path = Path(_DIR.name) / f"{next(_COUNTER)}-{config.name}"
    path.write_bytes(data)
    return path, data


# --- the properties ----------------------------------------------------------------------------

_CODE = re.compile(r"^[EW]\d{3}$")


@pytest.mark.parametrize("config", SHIPPED, ids=lambda p: p.name)
@seed(20240611)
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutations=MUTATIONS)
def test_a_mutated_shipped_config_gets_located_diagnostics_never_an_exception(config: Path,
                                                                             mutations: list[tuple[Any, ...]]) -> None:
    path, data = write_mutant(config, mutations)
    result = check_file(path)  # raising here fails the test
    try:
        text: str | None = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = None
    last_line = (text if text is not None else data.decode("utf-8", "replace")).count("\n") + 1
    for diagnostic in [*result.errors, *result.warnings]:
        shown = diagnostic.format()
        assert _CODE.match(diagnostic.code), shown
        assert diagnostic.code != "E901", f"the checker failed on its own:\n{shown}"
        assert diagnostic.file == str(path), shown
        if diagnostic.line == 0:
            assert diagnostic.code == "E100", shown
        if text is not None:
            assert diagnostic.line >= 1 and diagnostic.column >= 1, shown
        assert diagnostic.line <= last_line, shown
    if result.errors:
        assert result.subsystem is None


@pytest.mark.multiprocess
@pytest.mark.parametrize("config", SHIPPED, ids=lambda p: p.name)
@seed(20240612)
@settings(max_examples=CLI_RUNS, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutations=MUTATIONS)
def test_pbo_check_of_a_mutated_shipped_config_exits_0_or_1_without_a_traceback(config: Path,
                                                                                mutations: list[tuple[Any, ...]]) -> None:
    path, _ = write_mutant(config, mutations)
    run = subprocess.run(
        [sys.executable, "-m", "pbo_runtime.cli", "check", str(path)],
        capture_output=True, cwd=REPO, timeout=120,
    )
    output = (run.stdout + run.stderr).decode("utf-8", "replace")
    assert run.returncode in (0, 1), output
    assert "Traceback" not in output, output
