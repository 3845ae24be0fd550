"""Save the job canvas as a job (Onika §4.3.3): its tasks, a configuration and a job, written into the subsystem file.

The canvas's tasks that are on become the job's configuration: the file's own configuration when
the canvas holds exactly its tasks (as loaded from it), else a new configuration named after the
job. Each task's entry is added to `tasks:`; a task the canvas changed keeps its name only when
no configuration of the file runs the file's entry (a saved job never changes another one). Whether the job is
an *action* or an *action requiring an object* is the job model's to infer (`pbo check`: a task
reads a variable marked `object:` that no task of the configuration writes); `object: none` makes
it an action that leaves such a variable as it is.

The file is written the way `pbo save` writes one (`edit.live_save`): ruamel.yaml's round trip
for the entries that change, the original text everywhere else, comments and order kept. The new
text goes through `edit.write_back`: checked beside the file first, so a refused save leaves the
file as it was.
"""

from __future__ import annotations

import io
import re
from collections.abc import Sequence
from typing import Any

from ruamel.yaml.comments import CommentedMap

from pbo_runtime.config.model import ACTION_REQUIRING_OBJECT
from pbo_runtime.config.yaml_nodes import load_text, plain
from pbo_runtime.edit.canvas import CanvasError, CanvasTask
from pbo_runtime.edit.live import NAME
from pbo_runtime.edit.live_save import chunks, flow, merged, round_trip
from pbo_runtime.edit.write_back import WriteRefused, write_checked
from pbo_runtime.errors import ConfigError

OBJECT_CHOICES = ("inferred", "none")  # the job model infers it; or an action that leaves the object variable as it is


class JobRefused(ValueError):
    """The job cannot be saved: what is wrong, in one line (the file is untouched)."""


def entry_of(task: CanvasTask) -> dict[str, Any]:
    """The task's entry as plain data, its values' YAML text loaded by the project's safe loader."""
    entry: dict[str, Any] = {"module": task.module}
    for key, text in task.fields.items():
        if text.strip():
            entry[key] = _loaded(text, f"{key} of task '{task.name}'")
    params = {key: _loaded(text, f"modifier '{key}' of task '{task.name}'") for key, text in task.params.items() if text.strip()}
    if params:
        entry["params"] = params
    ports = {key: text.strip() for key, text in task.ports.items() if text.strip()}
    if ports:
        entry["ports"] = ports
    return entry


def _loaded(text: str, what: str) -> Any:
    try:
        return plain(load_text(f"value: {text}\n", f"<{what}>")["value"])
    except (ConfigError, TypeError, KeyError) as exc:
        raise JobRefused(f"{what} is not a YAML value: {text!r} ({exc})") from None


def _section(doc: Any, key: str) -> Any:
    """The document's mapping `key`, made (block style) when it is missing or empty."""
    section = doc.get(key)
    if not isinstance(section, CommentedMap) or not section:
        section = CommentedMap(section or {})
        doc[key] = section
    return section


def job_text(original: str, name: str, tasks: Sequence[CanvasTask], loaded_from: str | None,
             object_choice: str = "inferred") -> tuple[str, str, list[str]]:
    """The file's text with the job saved: (text, the job's configuration, the tasks added or changed)."""
    if not NAME.match(name):
        raise JobRefused(f"a job's name is an identifier of at most 40 characters (letters, digits, _), got: {name!r}")
    if object_choice not in OBJECT_CHOICES:
        raise JobRefused(f"object must be one of {', '.join(OBJECT_CHOICES)}, got: {object_choice!r}")
    members = [t for t in tasks if t.on]
    if not members:
        raise JobRefused("the canvas has no task that is on: a job runs a configuration of at least one task")
    yaml = round_trip()
    doc = yaml.load(original)
    if not isinstance(doc, CommentedMap):
        raise JobRefused("the subsystem file is not a mapping of sections; pbo check says what is wrong")
    jobs = doc.get("jobs")
    if isinstance(jobs, dict) and name in jobs:
        raise JobRefused(f"the file has a job '{name}' already: choose another name")
    file_tasks = _section(doc, "tasks")
    configurations = _section(doc, "configurations")
    names = [t.name for t in members]
    touched: list[str] = []
    for task in members:
        entry = entry_of(task)
        if task.name in file_tasks and plain(file_tasks[task.name]) == entry:
            continue
        users = [c for c, listed in configurations.items() if task.name in (listed or [])]
        if task.name in file_tasks and users:
            raise JobRefused(f"task '{task.name}' on the canvas differs from the file's, which configuration(s) "
                             f"{', '.join(users)} run: rename it on the canvas to keep both")
        file_tasks[task.name] = flow(entry)
        touched.append(task.name)
    if loaded_from and not touched and list(configurations.get(loaded_from) or []) == names:
        configuration = loaded_from  # the canvas is that configuration, unchanged
    elif name in configurations:
        if list(configurations[name] or []) != names:
            raise JobRefused(f"the file has a configuration '{name}' with other tasks ({', '.join(configurations[name] or [])}): "
                             "choose another name for the job")
        configuration = name
    else:
        configurations[name] = flow(names)
        configuration = name
    job: dict[str, Any] = {"configuration": configuration}
    if object_choice == "none":
        job["object"] = "none"
    _section(doc, "jobs")[name] = flow(job)
    out = io.StringIO()
    yaml.dump(doc, out)
    changed = {"tasks": set(touched), "configurations": {configuration}, "jobs": {name}}
    return merged_sections(original, out.getvalue(), changed), configuration, touched


def merged_sections(original: str, dumped: str, changed: dict[str, set[str]]) -> str:
    """`pbo save`'s merge (the original's text but for the changed entries), where a changed section the
    original wrote in flow style (`tasks: {}`) or lacks is taken whole from the round trip's text."""
    new = dict(chunks(dumped, 0))
    block = {key for key, text in chunks(original, 0) if key in changed
             and re.match(rf"^{re.escape(key)}\s*:\s*(#.*)?$", text.splitlines()[0] if text else "")}
    base = "".join(new.get(key, text) if key in changed and key not in block else text
                   for key, text in chunks(original, 0))
    return merged(base, dumped, {key: entries for key, entries in changed.items() if key in block})


def save_job(file: str, name: str, tasks: Sequence[CanvasTask], loaded_from: str | None = None,
             object_choice: str = "inferred") -> dict[str, Any]:
    """Write the job into `file` if the file then checks clean; what was saved, or JobRefused (file untouched)."""
    try:
        with open(file, encoding="utf-8") as stream:
            original = stream.read()
    except OSError as exc:
        raise JobRefused(f"cannot read {file}: {exc.strerror or exc}") from None
    try:
        text, configuration, touched = job_text(original, name, tasks, loaded_from, object_choice)
    except CanvasError as exc:
        raise JobRefused(str(exc)) from None
    try:
        result = write_checked(file, text)
    except WriteRefused as refused:
        if not refused.first:
            raise JobRefused(str(refused)) from None
        raise JobRefused(f"saving job '{name}' would leave {file} with {len(refused.errors)} error(s), the first: "
                         f"{refused.first}") from None
    assert result.subsystem is not None  # write_checked refuses a file that does not load
    job = result.subsystem.jobs[name]
    kind = "an action requiring an object" + (f" of type {job.object_type}" if job.object_type else "") \
        if job.kind == ACTION_REQUIRING_OBJECT else "an action"
    return {"file": file, "job": name, "class": job.kind, "object": job.object, "object_type": job.object_type,
            "configuration": configuration, "tasks": touched,
            "message": f"saved job '{name}' ({kind}) to {file}: configuration '{configuration}'"
                       + (f", tasks written: {', '.join(touched)}" if touched else "")}
