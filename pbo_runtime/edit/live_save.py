"""`pbo save FILE`: the live subsystem as YAML, the original file's comments and key order kept.

The original file is read again by ruamel.yaml's round-trip mode, which keeps comments, key
order and flow style, and each live change (`LiveDescription.edits`) is replayed on it in order:
a spawned task's entry appended to `tasks:` and its configuration, a killed one removed from
both, a replaced one's entry put in its place, a set parameter changed where it is written, an
application run with its steps (`pbo app NAME --steps`) written under `applications:`.
ruamel.yaml only writes here: every file is still loaded by the project's own safe loader
(`config.yaml_nodes`), and the saved file is checked by it before `pbo save` says it is done.

ruamel.yaml re-flows what it writes (the alignment of `q_m:   {...}`, a flow mapping over two
lines), so the saved text takes from the round trip only what the changes touched: the entries of
`tasks:`, `configurations:` and `applications:` that changed; every other section and entry is the
original's text. `round_trip` and `merged` serve the HMI's saves too (`edit.workspace_file`).
"""

from __future__ import annotations

import io
import os
import re
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap, CommentedSeq

from pbo_runtime.config.model import Subsystem
from pbo_runtime.edit.live import Edit, LiveChangeRefused, LiveDescription
from pbo_runtime.edit.write_back import WriteRefused, write_checked


def saved_text(live: LiveDescription) -> str:
    """The original file's text with every live change replayed on it."""
    if not os.path.isfile(live.file):
        raise LiveChangeRefused(f"{live.file} is no file of its own (an inline subsystem?): pbo save writes a file's "
                                "changes back, and this run has none to start from")
    yaml = round_trip()
    with open(live.file, encoding="utf-8") as stream:
        original = stream.read()
    doc = yaml.load(original)
    before = {name: list(members) for name, members in doc["configurations"].items()}
    for edit in live.edits:
        _replay(doc, edit)
    out = io.StringIO()
    yaml.dump(doc, out)
    touched = {"tasks": {name for edit in live.edits if edit.kind != "application" for name in (edit.task, edit.new) if name},
               "applications": {edit.task for edit in live.edits if edit.kind == "application"},
               "configurations": {name for name, members in doc["configurations"].items()
                                  if list(members) != before.get(name)}}
    return merged(original, out.getvalue(), touched)


def round_trip() -> YAML:
    """ruamel.yaml's round trip, writing as the shipped files do."""
    yaml = YAML(typ="rt")
    yaml.preserve_quotes = True
    yaml.width = 4096  # long flow mappings stay on their line, as written
    yaml.indent(mapping=2, sequence=4, offset=2)  # `  - item` under its key, as the shipped files write lists
    return yaml


_KEY = {0: re.compile(r"^([A-Za-z_][\w-]*)\s*:"), 2: re.compile(r"^  ([A-Za-z_][\w-]*)\s*:")}


def chunks(text: str, indent: int) -> list[tuple[str | None, str]]:
    """(key, text) of each entry at `indent`, from its key's line to the next key's; None: the text before the first."""
    chunks: list[tuple[str | None, str]] = []
    key: str | None = None
    lines: list[str] = []
    for line in text.splitlines(keepends=True):
        match = _KEY[indent].match(line)
        if match:
            chunks.append((key, "".join(lines)))
            key, lines = match.group(1), [line]
        else:
            lines.append(line)
    chunks.append((key, "".join(lines)))
    return chunks


def merged(original: str, dumped: str, touched: dict[str, set[str]]) -> str:
    """`dumped`'s text where the changes are, `original`'s everywhere else (same keys, same order)."""
    kept = dict(chunks(original, 0))
    parts = []
    for key, text in chunks(dumped, 0):
        if key not in touched or key not in kept:  # untouched: the original's text; new: the dump's
            parts.append(kept.get(key, text))
            continue
        entries = dict(chunks(kept.get(key, ""), 2))
        parts.extend(entries.get(name, text) if name not in touched[key] and name in entries else text
                     for name, text in chunks(text, 2))
    return "".join(parts)


def save_live(live: LiveDescription, path: str) -> bool:
    """Write the live subsystem to `path`; True if `pbo check` on it gives the live subsystem back."""
    try:  # written even if it does not check clean: the reply warns
        result = write_checked(path, saved_text(live), even_with_errors=True)
    except WriteRefused as exc:
        raise LiveChangeRefused(str(exc)) from None
    return result.subsystem is not None and same_subsystem(result.subsystem, live.subsystem)


def same_subsystem(saved: Subsystem, live: Subsystem) -> bool:
    """The same tasks (module, RTPU, timing, params, ports) and configurations; status blocks may differ."""
    def tasks(subsystem: Subsystem) -> dict[str, Any]:
        return {name: (t.module, t.rtpu, t.period, t.priority, t.critical, dict(t.params),
                       [(b.port.name, b.variable) for b in t.bindings], t.aperiodic)
                for name, t in subsystem.tasks.items()}

    return (tasks(saved) == tasks(live)
            and {n: c.tasks for n, c in saved.configurations.items()} == {n: c.tasks for n, c in live.configurations.items()})


def flow(value: Any) -> Any:
    """A plain value as ruamel nodes, mappings and lists in flow style (as the shipped files write tasks)."""
    if isinstance(value, dict):
        mapping = CommentedMap((key, flow(item)) for key, item in value.items())
        mapping.fa.set_flow_style()
        return mapping
    if isinstance(value, list):
        sequence = CommentedSeq(flow(item) for item in value)
        sequence.fa.set_flow_style()
        return sequence
    return value


def _flow_steps(steps: list[Any]) -> CommentedSeq:
    """An application's steps as the shipped files write them: one a line, `- reach: ready`, values in flow style."""
    return CommentedSeq(step if isinstance(step, str) else CommentedMap((key, flow(value)) for key, value in step.items())
                        for step in steps)


def _replay(doc: Any, edit: Edit) -> None:
    tasks = doc["tasks"]
    configurations = doc["configurations"]
    if edit.kind == "spawn":
        tasks[edit.task] = flow(edit.entry)
        for name in edit.configurations:
            configurations[name].append(edit.task)
    elif edit.kind == "kill":
        del tasks[edit.task]
        for members in configurations.values():
            while edit.task in members:
                members.remove(edit.task)
    elif edit.kind == "replace":
        position = list(tasks).index(edit.task)
        tasks.insert(position, edit.new, flow(edit.entry))
        del tasks[edit.task]
        for members in configurations.values():
            for index, member in enumerate(members):
                if member == edit.task:
                    members[index] = edit.new
    elif edit.kind == "application":
        if doc.get("applications") is None:
            doc["applications"] = CommentedMap()
        doc["applications"][edit.task] = _flow_steps(edit.entry)
    elif edit.kind == "set":
        entry = tasks[edit.task]
        if "params" not in entry or entry["params"] is None:
            entry["params"] = flow({})
        if edit.member:  # a member of a combined task: its own params
            entry = entry["params"]["members"][edit.member - 1]
            if "params" not in entry or entry["params"] is None:
                entry["params"] = flow({})
        entry["params"][edit.param] = flow(edit.entry)
    else:
        raise AssertionError(f"unknown live edit {edit.kind!r}")
