"""The JSON Schema of the subsystem file: well formed, complete, and agreeing with the checker.

`jsonschema` validates when it is installed; otherwise a small validator of the keywords the
schema uses (below) checks that the demo conforms and that an unknown key does not.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from pbo_runtime.config.checker import BUS_KEYS, JOB_KEYS, TASK_KEYS, TOP_KEYS, VARIABLE_KEYS
from pbo_runtime.config.file_kind import is_application_file
from pbo_runtime.objects import registry
from pbo_runtime.reports.schema import json_schema, quantity_pattern, schema_text, write_schema

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "configs" / "pid_joint.yaml"

try:
    import jsonschema
except ImportError:  # not a dependency: the structural tests and the small validator stand in
    jsonschema = None


def _nodes(node: Any, path: str = "#"):
    """Every schema node (dicts reachable through schema keywords), with its JSON pointer."""
    if isinstance(node, dict):
        yield path, node
        for key, value in node.items():
            if key in ("properties", "$defs"):
                for name, sub in value.items():
                    yield from _nodes(sub, f"{path}/{key}/{name}")
            elif key in ("items", "additionalProperties", "not", "if", "then", "else", "propertyNames"):
                yield from _nodes(value, f"{path}/{key}")
            elif key in ("oneOf", "anyOf", "allOf", "prefixItems"):
                for i, sub in enumerate(value):
                    yield from _nodes(sub, f"{path}/{key}/{i}")


def _resolve(root: dict, ref: str) -> dict:
    node: Any = root
    for part in ref.removeprefix("#/").split("/"):
        node = node[part]
    return node


def _errors(instance: Any, schema: dict, root: dict, path: str = "$") -> list[str]:
    """A small draft 2020-12 validator: the keywords `json_schema()` uses, nothing more."""
    out: list[str] = []
    if "$ref" in schema:
        out += _errors(instance, _resolve(root, schema["$ref"]), root, path)
    types = schema.get("type")
    if types is not None:
        names = [types] if isinstance(types, str) else types
        checks = {
            "object": lambda v: isinstance(v, dict),
            "array": lambda v: isinstance(v, list),
            "string": lambda v: isinstance(v, str),
            "boolean": lambda v: isinstance(v, bool),
            "null": lambda v: v is None,
            "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
            "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
        }
        if not any(checks[t](instance) for t in names):
            return [*out, f"{path}: {instance!r} is not of type {types}"]
    if "enum" in schema and instance not in schema["enum"]:
        out.append(f"{path}: {instance!r} is not one of {schema['enum']}")
    if "const" in schema and instance != schema["const"]:
        out.append(f"{path}: {instance!r} is not {schema['const']!r}")
    if isinstance(instance, str):
        if "pattern" in schema and not re.search(schema["pattern"], instance):
            out.append(f"{path}: {instance!r} does not match {schema['pattern']}")
        if len(instance) < schema.get("minLength", 0):
            out.append(f"{path}: too short")
    if isinstance(instance, (int, float)) and not isinstance(instance, bool):
        if "minimum" in schema and instance < schema["minimum"]:
            out.append(f"{path}: below minimum")
        if "exclusiveMinimum" in schema and instance <= schema["exclusiveMinimum"]:
            out.append(f"{path}: not above exclusiveMinimum")
    if isinstance(instance, dict):
        props = schema.get("properties", {})
        for key in schema.get("required", []):
            if key not in instance:
                out.append(f"{path}: '{key}' is a required property")
        for key, value in instance.items():
            if key in props:
                out += _errors(value, props[key], root, f"{path}.{key}")
            elif schema.get("additionalProperties") is False:
                out.append(f"{path}: additional property '{key}' is not allowed")
            elif isinstance(schema.get("additionalProperties"), dict):
                out += _errors(value, schema["additionalProperties"], root, f"{path}.{key}")
            if "propertyNames" in schema:
                out += _errors(key, schema["propertyNames"], root, f"{path}.{key} (name)")
        if len(instance) < schema.get("minProperties", 0) or len(instance) > schema.get("maxProperties", 1 << 30):
            out.append(f"{path}: wrong number of properties")
    if isinstance(instance, list):
        if "items" in schema:
            for i, item in enumerate(instance):
                out += _errors(item, schema["items"], root, f"{path}[{i}]")
        if schema.get("uniqueItems") and len({json.dumps(i, sort_keys=True) for i in instance}) != len(instance):
            out.append(f"{path}: items are not unique")
        if len(instance) < schema.get("minItems", 0):
            out.append(f"{path}: too few items")
    if "oneOf" in schema:
        passing = [s for s in schema["oneOf"] if not _errors(instance, s, root, path)]
        if len(passing) != 1:
            out.append(f"{path}: {instance!r} matches {len(passing)} of oneOf, not exactly one")
    if "anyOf" in schema and all(_errors(instance, s, root, path) for s in schema["anyOf"]):
        out.append(f"{path}: {instance!r} matches none of anyOf")
    for sub in schema.get("allOf", []):
        out += _errors(instance, sub, root, path)
    if "not" in schema and not _errors(instance, schema["not"], root, path):
        out.append(f"{path}: must not match {schema['not']}")
    if "if" in schema:
        branch = "then" if not _errors(instance, schema["if"], root, path) else "else"
        if branch in schema:
            out += _errors(instance, schema[branch], root, path)
    return out


def validate(instance: Any, schema: dict) -> list[str]:
    if jsonschema is not None:
        validator = jsonschema.Draft202012Validator(schema)
        return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(instance)]
    return _errors(instance, schema, schema)


@pytest.fixture(scope="module")
def schema() -> dict:
    return json_schema()


def demo() -> dict:
    return yaml.safe_load(DEMO.read_text())


# --- the schema itself ------------------------------------------------------------------------


def test_schema_is_valid_json_schema(schema):
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    json.dumps(schema)  # JSON-able
    if jsonschema is not None:
        jsonschema.Draft202012Validator.check_schema(schema)
    for path, node in _nodes(schema):
        if "$ref" in node:
            assert node["$ref"].startswith("#/$defs/"), path
            _resolve(schema, node["$ref"])  # resolves
        for key in ("properties", "$defs"):
            assert isinstance(node.get(key, {}), dict), path
        if "pattern" in node:
            re.compile(node["pattern"])


def test_every_object_node_has_a_type_and_closed_sections_reject_unknown_keys(schema):
    for path, node in _nodes(schema):
        conditional = "/if" in path or "/then" in path  # applicators on a node that is typed already
        if "properties" in node and not conditional:
            assert node.get("type") == "object", f"{path} has properties but no type: object"
    closed = {
        "#": TOP_KEYS,
        "#/properties/bus": BUS_KEYS,
        "#/$defs/variable": VARIABLE_KEYS,
        "#/$defs/task": TASK_KEYS,
        "#/$defs/job": JOB_KEYS,
    }
    nodes = dict(_nodes(schema))
    for path, keys in closed.items():
        node = nodes[path]
        assert node["additionalProperties"] is False, path
        assert set(keys) <= set(node["properties"]), f"{path} misses {set(keys) - set(node['properties'])}"
        for key, sub in node["properties"].items():
            assert sub.get("description"), f"{path}/properties/{key} has no description"
    assert {"wcet", "aperiodic", "min_interarrival"} <= set(nodes["#/$defs/task"]["properties"])
    # every key of the nested sections is described too
    for path, node in nodes.items():
        if path.startswith(("#/properties/", "#/$defs/")) and "properties" in node and "/if" not in path and "/then" not in path:
            for key, sub in node["properties"].items():
                assert sub.get("description"), f"{path}/properties/{key} has no description"


def test_every_module_has_a_params_branch_from_its_params_dataclass(schema):
    modules = list(registry.names(registry.MODULES))
    task = schema["$defs"]["task"]
    assert task["properties"]["module"]["enum"] == modules
    branches = {b["if"]["properties"]["module"]["const"]: b["then"] for b in task["allOf"]}
    assert sorted(branches) == modules
    for module in modules:
        ref = branches[module]["properties"]["params"]["$ref"]
        params = _resolve(schema, ref)
        assert params["type"] == "object" and params["additionalProperties"] is False
    pid = schema["$defs"]["params_pid_joint"]["properties"]
    gain = {"type": "number", "minimum": 0.0, "maximum": 1e6}  # its declared range, each gain of a list too
    assert pid["kp"]["oneOf"] == [gain, {"type": "array", "items": gain}]
    trajectory = schema["$defs"]["params_joint_trajectory"]["properties"]
    assert trajectory["max_velocity"]["exclusiveMinimum"] == 0.0 and trajectory["max_velocity"]["maximum"] == 100.0
    assert pid["kp"]["default"] == 400.0
    assert pid["gravity_feedforward"]["type"] == "boolean"
    logger = schema["$defs"]["params_data_logger"]
    assert logger["required"] == ["variables"]
    assert logger["properties"]["variables"] == {
        "type": "array", "items": {"type": "string"}, "description": logger["properties"]["variables"]["description"]}
    assert schema["properties"]["devices"]["additionalProperties"]["properties"]["driver"]["enum"] == list(
        registry.names(registry.DRIVERS))


@pytest.mark.parametrize(
    "kind, good, bad",
    [
        ("time", ["1 ms", "500 us", "2µs", "1.5e-3 s", "0.001", "10 min"], ["1 kHz", "fast", "1 m s", ""]),
        ("frequency", ["1 kHz", "50 Hz", "1MHz"], ["1 ms", "1 kB"]),
        ("data_rate", ["40 MB/s", "1 GiB/s", "100 B/s"], ["40 MB", "1 Hz"]),
        ("size", ["16 B", "4 KiB", "1 GB"], ["16 B/s", "4 k"]),
    ],
)
def test_quantity_patterns_follow_the_units_parser(kind, good, bad):
    pattern = re.compile(quantity_pattern(kind))
    for text in good:
        assert pattern.search(text), text
    for text in bad:
        assert not pattern.search(text), text


# --- files against it -------------------------------------------------------------------------


def test_the_demo_conforms(schema):
    assert DEMO.read_text().splitlines()[0] == "# yaml-language-server: $schema=pbo-subsystem.schema.json"
    assert validate(demo(), schema) == []


SUBSYSTEM_FILES = [path for path in sorted([*(REPO / "configs").glob("*.yaml"), *(REPO / "bench").glob("*.yaml")])
                   if not is_application_file(path)]  # the schema describes subsystem files, not applications


@pytest.mark.parametrize("path", SUBSYSTEM_FILES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_subsystem_file_names_the_committed_schema_by_a_path_that_exists(path):
    first = re.fullmatch(r"# yaml-language-server: \$schema=(\S+)", path.read_text().splitlines()[0])
    assert first, f"{path.name}: its first line must be '# yaml-language-server: $schema=<path to the schema>'"
    assert (path.parent / first.group(1)).resolve() == (REPO / "configs" / "pbo-subsystem.schema.json").resolve()


def test_an_application_that_decides_conforms_and_a_misspelt_step_does_not(schema):
    doc = yaml.safe_load((REPO / "configs" / "branches.yaml").read_text())
    assert validate(doc, schema) == []
    doc["applications"]["pick"][0]["fallbak"] = doc["applications"]["pick"][0].pop("fallback")
    assert validate(doc, schema) != []


def test_an_unknown_key_does_not_conform(schema):
    doc = demo()
    doc["tasks"]["pid"]["prio"] = 3
    assert any("prio" in e for e in validate(doc, schema))
    doc = demo()
    doc["tasks"]["pid"]["params"]["kq"] = 1.0  # not a field of PidJointParams
    assert any("kq" in e for e in validate(doc, schema))
    doc = demo()
    doc["variabels"] = {}
    assert any("variabels" in e for e in validate(doc, schema))


@pytest.mark.parametrize(("options", "conforms"), [
    ({"q0": [0.0, 0.1, 0.2, 0.0, 0.0, 0.0], "adc_noise": 0.01, "seed": 3}, True),  # declared by the plant's Options
    ({"q_0": [0.0] * 6}, False),  # not an option of mujoco_arm
    ({"seed": "three"}, False),  # an option of the wrong type
    ({"type": "mujoco_arm", "adc_noise": -0.5}, False),  # below its declared range: the schema's minimum, as the checker's E320
])
def test_a_plants_options_are_checked_against_what_the_plant_declares(schema, options, conforms):
    doc = demo()
    doc["plant"].update(options)
    assert (validate(doc, schema) == []) is conforms, validate(doc, schema)


@pytest.mark.parametrize(("place", "restart", "conforms"), [
    ("top", {"max": 3, "within": "10 s"}, True),
    ("rtpu", {"max": 0}, True),
    ("top", {"max": 3, "within": "10 kHz"}, False),
    ("rtpu", {"within": "10 s"}, False),  # max is required
    ("top", {"max": 3, "witin": "10 s"}, False),
])
def test_a_restart_policy_conforms_at_the_top_or_in_an_rtpu(schema, place, restart, conforms):
    doc = demo()
    if place == "top":
        doc["restart"] = restart
    else:
        doc["rtpus"] = {name: ({"restart": restart} if i == 0 else None) for i, name in enumerate(doc["rtpus"])}
    assert (validate(doc, schema) == []) is conforms, validate(doc, schema)


def test_wrong_values_do_not_conform(schema):
    for change in (
        lambda d: d["tasks"]["robot"].update(period="1 kHz"),
        lambda d: d["tasks"]["robot"].update(module="robot_torqe"),
        lambda d: d["variables"]["q_m"].update(type="double"),
        lambda d: d["tasks"]["pid"]["params"].update(kp="high"),
        lambda d: d["tasks"]["pid"]["ports"].update(torque="tau_u"),
        lambda d: d["bus"].update(bandwidth="40 MB"),
        lambda d: d.pop("tasks"),
    ):
        doc = demo()
        change(doc)
        assert validate(doc, schema), change


def test_an_included_part_need_not_be_whole(schema):
    assert validate({"include": ["common.yaml"], "dims": {"NDOF": 6}}, schema) == []


def test_write_schema_is_deterministic_and_matches_the_committed_file(tmp_path, schema):
    first = write_schema(tmp_path / "a.json").read_text()
    second = write_schema(tmp_path / "b.json").read_text()
    assert first == second == schema_text()
    assert first.endswith("}\n") and '\n  "$defs": {' in first
    assert json.loads(first) == schema
    committed = REPO / "configs" / "pbo-subsystem.schema.json"  # beside the example configs, and shipped with them
    assert committed.read_text() == first, "regenerate it: pbo schema -o configs/pbo-subsystem.schema.json"
