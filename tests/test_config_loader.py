"""Loading a subsystem file: YAML with locations, includes, the frozen model, and never a traceback."""

from __future__ import annotations

import re
import string
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pbo_runtime import ConfigError, ConfigErrors, InConst, InVar, ModuleError, OutVar, PortBasedObject, PortKind
from pbo_runtime.config.loader import CheckResult, check_file, format_diagnostics, load_subsystem
from pbo_runtime.config.yaml_nodes import YList, YMap, load_text, plain


class FakeSensor(PortBasedObject):
    n = InConst("N", dtype="int32")
    y = OutVar("y", shape=("N",))


class FakeFilter(PortBasedObject):
    y = InVar("y", shape=("N",))
    out = OutVar("y_f", shape=("N",))


FAKES: dict[str, type] = {"fake_sensor": FakeSensor, "fake_filter": FakeFilter}


def fake_lookup(name: str) -> type:
    if name not in FAKES:
        raise ModuleError(f"no module named '{name}'")
    return FAKES[name]


FULL = """\
subsystem: bench
rtpus: {rtpu0: {cpu: 0}, rtpu1: {cpu: 1}}
bus: {bandwidth: 40 MB/s, lock_overhead: 16 B}
plant: {model: puma560, timestep: 1 ms, seed: 3}
devices:
  cam: {driver: camera, latency: 4}
dims: {N: 3}
variables:
  N:   {type: int32, initial: 3}
  y:   {type: float64, shape: [N], doc: raw signal}
  y_f: {type: float64, shape: [N], object: filtered, initial: [0, 0, 0]}
tasks:
  filter: {module: fake_filter, rtpu: rtpu1, rate: 500 Hz, priority: 2}
  sensor: {module: fake_sensor, rtpu: rtpu0, period: 1 ms, critical: true, resources: [cam]}
configurations:
  run: [sensor, filter]
jobs:
  go: {configuration: run, object: y_f, pre: "max(abs(y_f)) >= 0", timeout: 1.5 s}
applications:
  demo:
    - go: {y_f: [1, 2, 3]}
"""


def write(tmp_path: Path, text: str, name: str = "bench.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_legal_file_loads_into_the_frozen_model(tmp_path: Path) -> None:
    sub = load_subsystem(write(tmp_path, FULL), fake_lookup)
    assert sub.name == "bench"
    assert [(r.name, r.index, r.cpu) for r in sub.rtpus] == [("rtpu0", 0, 0), ("rtpu1", 1, 1)]
    assert (sub.bus.bandwidth, sub.bus.lock_overhead) == (40e6, 16.0)
    assert sub.plant is not None and sub.plant.type == "mujoco_arm" and sub.plant.timestep == pytest.approx(1e-3)
    assert sub.plant.options == {"seed": 3}
    assert sub.devices["cam"].driver == "camera" and sub.devices["cam"].options == {"latency": 4}
    assert not sub.devices["cam"].exclusive
    assert sub.dims == {"N": 3}
    assert [(v.name, v.index, v.dtype, v.shape) for v in sub.variables.values()] == [
        ("N", 0, "int32", ()),
        ("y", 1, "float64", (3,)),
        ("y_f", 2, "float64", (3,)),
    ]
    assert sub.variables["y_f"].object == "filtered" and sub.variables["y"].doc == "raw signal"
    filt = sub.tasks["filter"]
    assert (filt.index, filt.period, filt.priority, filt.critical) == (0, pytest.approx(2e-3), 2, False)
    assert [(b.port.name, b.port.kind, b.variable, b.shape) for b in filt.bindings] == [
        ("y", PortKind.IN_VAR, "y", (3,)),
        ("out", PortKind.OUT_VAR, "y_f", (3,)),
    ]
    assert sub.tasks["sensor"].resources == ("cam",) and sub.tasks["sensor"].critical
    assert sub.configurations["run"].tasks == ("sensor", "filter")
    assert sub.jobs["go"].timeout == pytest.approx(1.5) and sub.jobs["go"].object == "y_f"
    assert sub.applications["demo"].steps[0].job == "go"
    assert sub.applications["demo"].steps[0].arguments == {"y_f": [1, 2, 3]}
    assert sub.init_order == ("filter", "sensor")
    assert sub.tasks["sensor"].loc.line == 14 and sub.tasks["sensor"].loc.column == 3


def test_check_file_returns_the_initial_values_as_arrays(tmp_path: Path) -> None:
    result = check_file(write(tmp_path, FULL), fake_lookup)
    assert result.errors == []
    assert result.initial_values["N"].dtype.name == "int32" and int(result.initial_values["N"]) == 3
    assert result.initial_values["y_f"].tolist() == [0.0, 0.0, 0.0]


def test_load_subsystem_raises_every_error_at_once(tmp_path: Path) -> None:
    text = FULL.replace("rtpu: rtpu1", "rtpu: rtpu7").replace("period: 1 ms", "period: 1 kg")
    with pytest.raises(ConfigErrors) as info:
        load_subsystem(write(tmp_path, text, "bad.yaml"), fake_lookup)
    assert [e.line for e in info.value.errors] == [13, 14]
    assert re.match(r"^.*bad\.yaml:13:39: error\[E203\]: task 'filter' runs on RTPU 'rtpu7'", str(info.value))


# --- YAML with locations -------------------------------------------------------------------


def test_every_mapping_key_sequence_and_scalar_keeps_its_location() -> None:
    doc = load_text("a: 1\nb:\n  - x\n  - {c: 2}\n", "f.yaml")
    assert isinstance(doc, YMap) and (doc.loc.line, doc.loc.column) == (1, 1)
    assert (doc.key_loc("b").line, doc.key_loc("b").column) == (2, 1)
    assert (doc.value_loc("a").line, doc.value_loc("a").column) == (1, 4)
    items = doc["b"]
    assert isinstance(items, YList) and (items.loc.line, items.loc.column) == (3, 3)
    assert (items.item_loc(0).line, items.item_loc(0).column) == (3, 5)
    assert (items[1].key_loc("c").line, items[1].key_loc("c").column) == (4, 6)
    assert str(items[1].value_loc("c")) == "f.yaml:4:9"


def test_a_yaml_syntax_error_is_a_config_error_at_its_mark() -> None:
    with pytest.raises(ConfigError, match=r"^f\.yaml:2:2: error\[E101\]: invalid YAML: expected ',' or ']'"):
        load_text("a: [1, 2\nb: 3\n", "f.yaml")


def test_a_duplicate_key_is_an_error_at_the_second_key() -> None:
    with pytest.raises(ConfigError,
                       match=r"^f\.yaml:3:3: error\[E102\]: duplicate key 'x' in tasks \(first at line 2, column 3\)\n"
                             r"  hint: task names are unique"):
        load_text("tasks:\n  x: 1\n  x: 2\n", "f.yaml")


def test_unsafe_tags_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"^f\.yaml:1:4: error\[E101\]: invalid YAML: could not determine a constructor"):
        load_text("a: !!python/name:os.system x\n", "f.yaml")
    with pytest.raises(ConfigError,
                       match=r"^f\.yaml:1:4: error\[E103\]: YAML tag '.*python/object/apply:os\.system' is not supported here"):
        load_text("a: !!python/object/apply:os.system [echo hi]\n", "f.yaml")


def test_merge_keys_take_defaults_and_explicit_keys_win() -> None:
    doc = load_text("d: &d {rtpu: rtpu0, period: 1 ms}\nt: {<<: *d, period: 2 ms}\n", "f.yaml")
    assert doc["t"] == {"period": "2 ms", "rtpu": "rtpu0"}
    assert doc["t"].key_loc("rtpu").line == 1


def test_a_recursive_alias_is_an_error_not_a_hang() -> None:
    with pytest.raises(ConfigError, match=r"recursive structure"):
        load_text("&a [*a]", "f.yaml")


def test_an_alias_bomb_is_an_error_not_a_hang() -> None:
    bomb = "a: &a [x, x, x, x, x, x, x, x, x, x]\n"
    for i, name in enumerate("bcdefgh"):
        prev = "abcdefgh"[i]
        bomb += f"{name}: &{name} [*{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}]\n"
    with pytest.raises(ConfigError, match=r"expands to more than"):
        load_text(bomb, "f.yaml")


# --- files that are not subsystems ----------------------------------------------------------


def test_a_missing_file_is_an_error_not_a_traceback(tmp_path: Path) -> None:
    result = check_file(tmp_path / "nope.yaml", fake_lookup)
    assert result.subsystem is None
    assert re.match(r"^.*nope\.yaml: error\[E100\]: cannot read file: No such file", str(result.errors[0]))
    with pytest.raises(ConfigErrors):
        load_subsystem(tmp_path / "nope.yaml", fake_lookup)


def test_a_binary_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    result = check_file(path, fake_lookup)
    assert re.match(r"^.*x\.yaml:1:1: error\[E100\]: not UTF-8 text", str(result.errors[0]))


def test_a_list_at_the_top_level_is_an_error(tmp_path: Path) -> None:
    result = check_file(write(tmp_path, "- a\n- b\n"), fake_lookup)
    assert [e.message for e in result.errors] == [
        "the top level must be a mapping, got: a list",
    ]


def test_an_empty_file_is_an_error(tmp_path: Path) -> None:
    result = check_file(write(tmp_path, "# nothing\n"), fake_lookup)
    assert re.match(r"^.*bench\.yaml:1:1: error\[E110\]: the file is empty", str(result.errors[0]))


def test_numbers_where_mappings_belong_are_errors(tmp_path: Path) -> None:
    text = "subsystem: 5\nrtpus: 3\nvariables: 1\ntasks: 2\nconfigurations: [1]\nbus: 4\n"
    result = check_file(write(tmp_path, text), fake_lookup)
    assert [e.line for e in result.errors] == [1, 2, 3, 4, 5, 6]


# --- includes ------------------------------------------------------------------------------


def test_an_include_merges_sections_and_keeps_their_locations(tmp_path: Path) -> None:
    common = "dims: {N: 3}\nvariables:\n  N: {type: int32, initial: 3}\n  y: {type: float64, shape: [N]}\n"
    (tmp_path / "common").mkdir()
    write(tmp_path, common, "common/vars.yaml")
    main = FULL.replace("dims: {N: 3}\n", "include: [common/vars.yaml]\n")
    main = main.replace("  N:   {type: int32, initial: 3}\n  y:   {type: float64, shape: [N], doc: raw signal}\n", "")
    result = check_file(write(tmp_path, main), fake_lookup)
    assert result.errors == [], format_diagnostics(result)
    assert result.subsystem is not None
    assert list(result.subsystem.variables) == ["N", "y", "y_f"]
    assert result.subsystem.variables["y"].loc.file.endswith("vars.yaml")
    assert result.subsystem.variables["y"].loc.line == 4


def test_a_name_defined_in_an_include_and_the_file_is_an_error(tmp_path: Path) -> None:
    write(tmp_path, "variables:\n  y: {type: float64}\n", "part.yaml")
    main = FULL.replace("dims: {N: 3}\n", "dims: {N: 3}\ninclude: [part.yaml]\n")
    result = check_file(write(tmp_path, main), fake_lookup)
    assert any(re.match(r"^'y' in 'variables' is defined twice: here and at .*part\.yaml:2:3$", e.message) for e in result.errors)


def test_a_missing_include_is_an_error_at_the_include(tmp_path: Path) -> None:
    main = FULL.replace("dims: {N: 3}\n", "dims: {N: 3}\ninclude: [nothere.yaml]\n")
    result = check_file(write(tmp_path, main), fake_lookup)
    assert [e.message.split(" (")[0] for e in result.errors] == ["included file 'nothere.yaml' does not exist"]
    assert (result.errors[0].line, result.errors[0].column) == (8, 11)


def test_an_include_with_a_nul_character_is_an_error_at_the_include_not_an_internal_one(tmp_path: Path) -> None:
    main = FULL.replace("dims: {N: 3}\n", 'dims: {N: 3}\ninclude: ["a\\0b.yaml"]\n')
    result = check_file(write(tmp_path, main), fake_lookup)
    assert [e.message for e in result.errors] == [
        "an include must be a file path, got: 'a\\x00b.yaml', which holds a NUL character"]
    assert (result.errors[0].line, result.errors[0].column) == (8, 11)


def test_an_include_cycle_is_an_error(tmp_path: Path) -> None:
    write(tmp_path, "include: [b.yaml]\n", "a.yaml")
    write(tmp_path, "include: [a.yaml]\n", "b.yaml")
    result = check_file(tmp_path / "a.yaml", fake_lookup)
    assert any("includes itself" in e.message for e in result.errors)


# --- diagnostics ---------------------------------------------------------------------------


def test_diagnostics_are_in_line_order_with_a_count_line(tmp_path: Path) -> None:
    text = FULL.replace("configurations:\n", "  idle: {module: fake_filter, rtpu: rtpu9, period: 1 ms}\nconfigurations:\n")
    text = text.replace("priority: 2", "priority: high")
    result = check_file(write(tmp_path, text), fake_lookup)
    report = format_diagnostics(result)
    lines = [line for line in report.splitlines() if not line.startswith("  ")]
    assert re.match(r"^.*:13:\d+: error\[E116\]: priority of task 'filter' must be an integer", lines[0])
    assert re.match(r"^.*:15:3: warning\[W201\]: task 'idle' is in no configuration", lines[1])
    assert re.match(r"^.*:15:\d+: error\[E203\]: task 'idle' runs on RTPU 'rtpu9'", lines[2])
    assert lines[-1] == "2 errors, 1 warning"


def test_a_config_error_formats_as_a_warning_when_it_is_one() -> None:
    assert ConfigError("x", "f.yaml", 3, 4, "h", severity="warning").format() == "f.yaml:3:4: warning: x\n  hint: h"
    assert ConfigError("x", "f.yaml", 3, 4).format() == "f.yaml:3:4: error: x"  # a message no rule claims has no code
    assert ConfigError("x", "f.yaml", 3, 4, code="E503").format() == "f.yaml:3:4: error[E503]: x"
    assert ConfigError("x", "f.yaml", 3, 4, severity="warning", code="W501").format() == "f.yaml:3:4: warning[W501]: x"
    with pytest.raises(ValueError):
        ConfigError("x", code="503")
    with pytest.raises(ValueError):
        ConfigError("x", severity="fatal")


def test_a_clean_file_reports_zero_counts(tmp_path: Path) -> None:
    assert format_diagnostics(check_file(write(tmp_path, FULL), fake_lookup)) == "0 errors, 0 warnings"


# --- nothing but ConfigErrors, whatever the input ------------------------------------------


def _never_raises(path: Path) -> CheckResult:
    result = check_file(path, fake_lookup)
    assert all(isinstance(e, ConfigError) for e in result.errors + result.warnings)
    # not the text echoed
    assert not any(e.message.startswith("internal error") for e in result.errors), format_diagnostics(result)
    assert all(re.match(r"^[EW]\d{3}$", d.code) for d in result.errors + result.warnings), format_diagnostics(result)
    if result.subsystem is None:
        with pytest.raises(ConfigErrors):
            load_subsystem(path, fake_lookup)
    return result


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(alphabet=string.printable + "{}[]:-&*!|>'\"#%@`\u00b5\x00\x07", max_size=300))
def test_arbitrary_text_never_raises_anything_but_config_errors(tmp_path: Path, text: str) -> None:
    path = tmp_path / "fuzz.yaml"
    path.write_text(text, encoding="utf-8")
    _never_raises(path)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=200))
def test_arbitrary_bytes_never_raise_anything_but_config_errors(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "fuzz.yaml"
    path.write_bytes(data)
    _never_raises(path)


_NAMES = st.sampled_from(
    [
        "subsystem", "rtpus", "bus", "plant", "devices", "dims", "variables", "tasks", "configurations",
        "jobs", "applications", "include", "type", "shape", "module", "rtpu", "period", "rate", "params",
        "ports", "resources", "initial", "object", "configuration", "N", "y", "y_f", "sensor", "filter",
        "fake_sensor", "fake_filter", "rtpu0", "float64", "int32", "1 ms", "cpu", "exclusive", "driver",
    ]
)
_SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.floats(allow_nan=True),
                     _NAMES, st.text(max_size=8))
_TREES = st.recursive(
    _SCALARS,
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(_NAMES, children, max_size=5)),
    max_leaves=40,
)


def _same(a: Any, b: Any) -> bool:
    """Equal, with NaN equal to itself and 1 distinct from True (YAML tells them apart)."""
    if isinstance(a, float) and isinstance(b, float) and a != a and b != b:
        return True
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


# Texts that read as other types unless quoted, beside those types: a memo keyed by text alone would mix them up
_LOOKALIKES = st.sampled_from([1, "1", True, "true", None, "null", 1.5, "1.5", "~", "yes", 0, "0"])
_MIXED_TREES = st.recursive(
    st.one_of(_LOOKALIKES, _SCALARS),
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(_NAMES, children, max_size=5)),
    max_leaves=40,
)


@settings(max_examples=200, deadline=None)
@given(tree=st.dictionaries(_NAMES, _MIXED_TREES, max_size=8), flow=st.booleans())
def test_the_memoised_loader_reads_what_the_safe_loader_reads(tree: dict[str, Any], flow: bool) -> None:
    text = yaml.safe_dump(tree, default_flow_style=flow)
    assert _same(plain(load_text(text, "f.yaml")), yaml.safe_load(text))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(tree=st.dictionaries(_NAMES, _TREES, max_size=8))
def test_arbitrary_yaml_structures_never_raise_anything_but_config_errors(tmp_path: Path, tree: dict[str, Any]) -> None:
    path = tmp_path / "fuzz.yaml"
    path.write_text(yaml.safe_dump(tree), encoding="utf-8")
    _never_raises(path)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(section=st.sampled_from(["variables", "tasks", "configurations", "jobs", "applications", "rtpus",
                                "devices"]), value=_TREES)
def test_a_legal_file_with_one_section_replaced_by_garbage_never_raises(tmp_path: Path, section: str, value: Any) -> None:
    doc = yaml.safe_load(FULL)
    doc[section] = value
    path = tmp_path / "fuzz.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    _never_raises(path)


# --- docs/error-codes.md cannot rot -------------------------------------------------------

ERROR_CODES_DOC = Path(__file__).resolve().parents[1] / "docs" / "error-codes.md"
NO_EXAMPLE = "—"  # a module's or the checker's own bug: no YAML triggers it with the shipped modules
_ROW = re.compile(r"^\| (?P<code>[EW]\d{3}) \| (?P<meaning>.*?) \| (?P<example>`.*?`|—) \| (?P<message>`.*`|—) \|$")


def doc_rows(text: str) -> list[dict[str, str]]:
    rows = []
    for line in text.splitlines():
        match = _ROW.match(line)
        if match:
            row = {k: v.replace("\\|", "|") for k, v in match.groupdict().items()}
            row["example"] = row["example"].strip("`") if row["example"] != NO_EXAMPLE else ""
            row["message"] = row["message"][1:-1] if row["message"] != NO_EXAMPLE else ""
            rows.append(row)
    return rows


def doc_reference(text: str) -> str:
    """The reference file every mapping example is merged into: the first yaml block."""
    return text.split("```yaml\n", 1)[1].split("```", 1)[0]


def _merge(base: Any, change: Any) -> Any:
    """`change` over `base`: mappings merge key by key, a null removes the key, anything else replaces."""
    if not (isinstance(base, dict) and isinstance(change, dict)):
        return change
    merged = dict(base)
    for key, value in change.items():
        if value is None:
            merged.pop(key, None)
        else:
            merged[key] = _merge(base.get(key), value)
    return merged


def run_example(directory: Path, reference: str, example: str) -> CheckResult:
    """Check `example` merged into the reference file (saved too as base.yaml), or alone if it is no mapping."""
    (directory / "base.yaml").write_text(reference)
    path = directory / "example.yaml"
    if example == "<no such file>":
        return check_file(path)
    try:
        change = plain(load_text(example, "example"))  # our loader: it refuses duplicate keys, PyYAML's does not
    except ConfigError:
        change = None
    if isinstance(change, dict):
        text = yaml.safe_dump(_merge(yaml.safe_load(reference), change), sort_keys=False, default_flow_style=None, width=1000)
    else:
        text = example
    path.write_text(text)
    return check_file(path)


def run_stage_example(directory: Path, reference: str, example: str) -> Any:
    """An application code's example: two subsystems made from the reference with `example` merged in,
    `left` and `right`, whose `demo`s run in one parallel stage."""
    from pbo_runtime.config.application import check_application

    merged = _merge(yaml.safe_load(reference), plain(load_text(example, "example")))
    for key in ("left", "right"):
        (directory / f"{key}.yaml").write_text(yaml.safe_dump({**merged, "subsystem": key}, sort_keys=False))
    path = directory / "application.yaml"
    path.write_text(yaml.safe_dump({"application": "example", "subsystems": {"left": "left.yaml", "right": "right.yaml"},
                                    "run": [{"parallel": {"left": {"app": "demo"}, "right": {"app": "demo"}}}]}, sort_keys=False))
    return check_application(path)


def example_messages(directory: Path, reference: str, example: str, code: str) -> list[str]:
    if code.startswith("E8"):
        return [e.message for e in run_stage_example(directory, reference, example).errors if e.code == code]
    result = run_example(directory, reference, example)
    located = sorted([*result.errors, *result.warnings], key=lambda d: (d.line, d.column))
    return [d.message.replace(str(directory), "<dir>") for d in located if d.code == code]


def test_the_reference_file_of_the_error_codes_is_clean(tmp_path: Path) -> None:
    result = run_example(tmp_path, doc_reference(ERROR_CODES_DOC.read_text()), "{}")
    assert result.errors == [] and result.warnings == [], format_diagnostics(result)


def test_every_code_in_the_doc_is_produced_by_its_example_with_the_message_shown(tmp_path: Path) -> None:
    text = ERROR_CODES_DOC.read_text()
    reference = doc_reference(text)
    rows = doc_rows(text)
    assert len(rows) > 50
    for row in rows:
        if not row["example"]:
            continue
        directory = tmp_path / row["code"]
        directory.mkdir()
        messages = example_messages(directory, reference, row["example"], row["code"])
        assert row["message"] in messages, f"{row['code']}: {row['example']!r} gives {messages}"


def test_every_code_the_checker_uses_is_in_the_doc_and_only_those() -> None:
    import pbo_runtime.config.checker as checker_module
    import pbo_runtime.config.loader as loader_module
    import pbo_runtime.errors as errors_module

    checker_files = Path(checker_module.__file__).parent.glob("*.py")  # the checker is a package
    used = set(re.findall(r'"([EW]\d{3})"', "".join(p.read_text() for p in checker_files)))
    used |= set(re.findall(r'code="([EW]\d{3})"', Path(loader_module.__file__).read_text()))
    used |= set(re.findall(r'"([EW]\d{3})"\)', Path(errors_module.__file__).read_text()))
    import pbo_runtime.config.application as application_module
    import pbo_runtime.config.parallel as parallel_module

    used |= set(re.findall(r'"(E8\d{2})"',
                           Path(application_module.__file__).read_text() + Path(parallel_module.__file__).read_text()))
    rows = doc_rows(ERROR_CODES_DOC.read_text())
    documented = [row["code"] for row in rows]
    assert len(documented) == len(set(documented)), "a code is listed twice"
    assert set(documented) == used
    application_codes = {f"E8{n:02d}" for n in range(1, 14)}  # examples in tests/test_application*.py, test_parallel_stages.py
    # (E814's example runs here: run_stage_example)
    without_example = {row["code"] for row in rows if not row["example"]}
    assert without_example == {"E106", "E107", "E306", "E307", "E406", "E901"} | application_codes
