"""`pbo save FILE`: the live subsystem as YAML, the original file's comments and key order kept.

The original file is read again by ruamel.yaml's round-trip mode, which keeps comments, key
order and flow style, and each live change (`LiveDescription.edits`) is replayed on it in order:
a spawned task's entry appended to `tasks:` and its configuration, a killed one removed from
both, a replaced one's entry put in its place, a set parameter changed where it is written.
ruamel.yaml only writes here: every file is still loaded by the project's own safe loader
(`config.yaml_nodes`), and the saved file is checked by it before `pbo save` says it is done.
"""

from __future__ import annotations

import io
import os
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap, CommentedSeq

from pbo_runtime.config.live import Edit, LiveChangeRefused, LiveDescription
from pbo_runtime.config.loader import check_file
from pbo_runtime.config.model import Subsystem


def saved_text(live: LiveDescription) -> str:
    """The original file's text with every live change replayed on it."""
    if not os.path.isfile(live.file):
        raise LiveChangeRefused(f"{live.file} is no file of its own (an inline subsystem?): pbo save writes a file's "
                                "changes back, and this run has none to start from")
    yaml = YAML(typ="rt")
    yaml.preserve_quotes = True
    yaml.width = 4096  # long flow mappings stay on their line, as written
    with open(live.file, encoding="utf-8") as stream:
        doc = yaml.load(stream)
    for edit in live.edits:
        _replay(doc, edit)
    out = io.StringIO()
    yaml.dump(doc, out)
    return out.getvalue()


def save_live(live: LiveDescription, path: str) -> bool:
    """Write the live subsystem to `path`; True if `pbo check` on it gives the live subsystem back."""
    text = saved_text(live)
    try:
        with open(path, "w", encoding="utf-8") as stream:
            stream.write(text)
    except OSError as exc:
        raise LiveChangeRefused(f"cannot write {path}: {exc.strerror or exc}") from None
    result = check_file(path)
    return result.subsystem is not None and same_subsystem(result.subsystem, live.subsystem)


def same_subsystem(saved: Subsystem, live: Subsystem) -> bool:
    """The same tasks (module, RTPU, timing, params, ports) and configurations; status blocks may differ."""
    def tasks(subsystem: Subsystem) -> dict[str, Any]:
        return {name: (t.module, t.rtpu, t.period, t.priority, t.critical, dict(t.params),
                       [(b.port.name, b.variable) for b in t.bindings], t.aperiodic)
                for name, t in subsystem.tasks.items()}

    return (tasks(saved) == tasks(live)
            and {n: c.tasks for n, c in saved.configurations.items()} == {n: c.tasks for n, c in live.configurations.items()})


def _flow(value: Any) -> Any:
    """A plain value as ruamel nodes, mappings and lists in flow style (as the shipped files write tasks)."""
    if isinstance(value, dict):
        mapping = CommentedMap((key, _flow(item)) for key, item in value.items())
        mapping.fa.set_flow_style()
        return mapping
    if isinstance(value, list):
        sequence = CommentedSeq(_flow(item) for item in value)
        sequence.fa.set_flow_style()
        return sequence
    return value


def _replay(doc: Any, edit: Edit) -> None:
    tasks = doc["tasks"]
    configurations = doc["configurations"]
    if edit.kind == "spawn":
        tasks[edit.task] = _flow(edit.entry)
        for name in edit.configurations:
            configurations[name].append(edit.task)
    elif edit.kind == "kill":
        del tasks[edit.task]
        for members in configurations.values():
            while edit.task in members:
                members.remove(edit.task)
    elif edit.kind == "replace":
        position = list(tasks).index(edit.task)
        tasks.insert(position, edit.new, _flow(edit.entry))
        del tasks[edit.task]
        for members in configurations.values():
            for index, member in enumerate(members):
                if member == edit.task:
                    members[index] = edit.new
    elif edit.kind == "set":
        entry = tasks[edit.task]
        if "params" not in entry or entry["params"] is None:
            entry["params"] = _flow({})
        entry["params"][edit.param] = _flow(edit.entry)
    else:
        raise AssertionError(f"unknown live edit {edit.kind!r}")
