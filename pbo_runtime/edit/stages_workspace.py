"""An application file's `run:` (config.parallel) as the HMI's workspace shows and writes it.

The workspace of an application file is a row of `parallel` steps, one for each stage of `run:`,
each with one arm for every subsystem of the file: the arm holds that subsystem's steps in the
stage, as the workspace's row holds a subsystem's application (`edit.workspace`), or is empty
when the stage does not name it (the subsystem holds its configuration meanwhile).

- `stages_workspace`: the file's subsystems, each with its job dictionary, and its stages, each
  arm's steps as the dictionary writes an application's (`{app: NAME}` as that one step).
- `checked_stages`: the browser's stages, `[{"arms": {subsystem: row}}, ...]`, each arm's row
  checked against its own subsystem as a complete application's row is; a step taken from
  another subsystem's dictionary (its `subsystem` says whose) is refused: its job and objects
  are that subsystem's table's, which this arm's run does not have.
- `save_stages`: `run:` written back through `edit.write_back` (beside the file, checked as
  `pbo check APP.yaml` checks it, then moved over it); every other line is the file's own.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from typing import Any

from ruamel.yaml.comments import CommentedMap, CommentedSeq

from pbo_runtime.config.application import Application, ApplicationCheck
from pbo_runtime.config.model import Subsystem
from pbo_runtime.config.parallel import stage_application, with_stage
from pbo_runtime.edit.job_dictionary import describe_application, job_dictionary
from pbo_runtime.edit.live_save import chunks, flow, round_trip
from pbo_runtime.edit.workspace import MAX_ROW, ROW_NAMES, RowRefused, checked_row, file_steps
from pbo_runtime.edit.write_back import WriteRefused, write_checked_application

MAX_STAGES = 32  # stages a person lays out, not a generated plan


def stages_workspace(application: Application) -> dict[str, Any]:
    """The file's subsystems (name, file, job dictionary) and its stages as the workspace draws them."""
    subsystems = {key: {"name": sub.name, "file": sub.file, "dictionary": job_dictionary(sub)}
                  for key, sub in application.subsystems.items()}
    stages = []
    for number, stage in enumerate(application.stages, 1):
        arms: dict[str, Any] = {}
        for key, part in stage.items():
            subsystem = application.subsystems[key]
            if "app" in part:
                name = part["app"]
                arms[key] = {"app": name, "steps": [{"step": 1, "job": name, "application": True, "object": None,
                                                     "value": None}]}
                continue
            staged = with_stage(subsystem, number, part["steps"])
            arms[key] = {"steps": describe_application(staged, stage_application(number))["steps"]}
        stages.append({"arms": arms})
    return {"application": application.name, "file": application.file, "subsystems": subsystems, "stages": stages}


def checked_stages(application: Application, stages: Any) -> list[dict[str, Any]]:
    """The stages as `run:` writes them, `[{"parallel": {subsystem: steps or {app: NAME}}}, ...]`; RowRefused saying
    which stage and arm is wrong, and why."""
    if not isinstance(stages, list) or not stages:
        raise RowRefused("the workspace is empty: drop a parallel step into it, then each subsystem's steps into its arms")
    if len(stages) > MAX_STAGES:
        raise RowRefused(f"the application has {len(stages)} stages, more than the {MAX_STAGES} taken here")
    written = []
    for number, stage in enumerate(stages, 1):
        arms = stage.get("arms") if isinstance(stage, Mapping) else None
        if not isinstance(arms, Mapping):
            raise RowRefused(f"stage {number} is not {{\"arms\": {{subsystem: [step, ...]}}}}: {stage!r}"[:300])
        parallel: dict[str, Any] = {}
        for key, row in arms.items():
            if key not in application.subsystems:
                raise RowRefused(f"stage {number} (parallel) has an arm '{key}', which is no subsystem of "
                                 f"{application.file} (subsystems: {', '.join(application.subsystems)})")
            if isinstance(row, list) and not row:
                continue  # an empty arm: the subsystem holds its configuration through the stage
            where = f"stage {number} (parallel), arm '{key}'"
            _refuse_strangers(row, key, where)
            try:
                steps = checked_row(application.subsystems[key], row, run=True)
            except RowRefused as refused:
                raise RowRefused(f"{where}: {refused}") from None
            parallel[key] = _arm_steps(application.subsystems[key], file_steps(steps))
        if not parallel:
            raise RowRefused(f"stage {number} (parallel) has no step in any arm: drop a subsystem's steps into its arm, "
                             "or remove the stage")
        written.append({"parallel": parallel})
    return written


def _arm_steps(subsystem: Subsystem, steps: list[Any]) -> Any:
    """An arm that is one of the subsystem's applications, alone, is written `{app: NAME}`, as the shipped files do."""
    if len(steps) == 1 and isinstance(steps[0], str) and steps[0] in subsystem.applications:
        return {"app": steps[0]}
    return steps


def _refuse_strangers(row: Any, key: str, where: str) -> None:
    """RowRefused for the first step of `row` (or of the rows inside its steps) taken from another subsystem's dictionary."""
    if not isinstance(row, list):
        return
    if len(row) > MAX_ROW:
        raise RowRefused(f"{where} has {len(row)} steps, more than the {MAX_ROW} an application may have here")
    for number, item in enumerate(row, 1):
        if not isinstance(item, Mapping):
            continue
        owner = item.get("subsystem")
        if owner is not None and owner != key:
            name = item.get("name") or item.get("kind")
            raise RowRefused(f"{where}: step {number} '{name}' is of subsystem '{owner}': an arm runs its own subsystem's "
                             f"jobs, on its table, with its objects; drop '{name}' of '{key}' here, or put it in "
                             f"the arm of '{owner}'")
        if item.get("kind") in ROW_NAMES:
            for label, inner in zip(ROW_NAMES[str(item["kind"])], item.get("rows") or [], strict=False):
                _refuse_strangers(inner, key, f"{where}, step {number} ({item['kind']}, {label})")


def save_stages(file: str, stages: list[dict[str, Any]]) -> ApplicationCheck:
    """Write `stages` as the file's `run:`; the check of the new file. WriteRefused (the file is as it was) if it
    does not check clean."""
    with open(file, encoding="utf-8") as stream:
        original = stream.read()
    yaml = round_trip()
    doc = yaml.load(original)
    if not isinstance(doc, CommentedMap):
        raise WriteRefused(f"not saved: {file} is not a mapping of sections: run pbo check {file}")
    before = doc.get("run")
    if isinstance(before, CommentedMap):
        raise WriteRefused(f"not saved: run: of {file} picks each subsystem's configuration or application (run: "
                           "{SUBSYSTEM: {config: NAME}}); the workspace writes stages (run: [parallel: ...]): change "
                           "one into the other in the file first")
    old = list(before) if isinstance(before, CommentedSeq) else []
    # a stage as it was keeps its node, with its comments and layout; a changed one is written anew
    doc["run"] = CommentedSeq(old[i] if i < len(old) and _plain(old[i]) == stage else
                              CommentedMap(parallel=_arms(stage["parallel"])) for i, stage in enumerate(stages))
    if isinstance(before, CommentedSeq):
        doc["run"].ca.items.update({i: before.ca.items[i] for i in range(len(stages))
                                    if i in before.ca.items and i < len(old) and _plain(old[i]) == stages[i]})
    out = io.StringIO()
    yaml.dump(doc, out)
    dumped = dict(chunks(out.getvalue(), 0))
    kept = chunks(original, 0)
    parts = [dumped["run"] if key == "run" else text for key, text in kept]
    if "run" not in dict(kept):
        parts.append(("" if original.endswith("\n") else "\n") + dumped["run"])
    return write_checked_application(file, "".join(parts).rstrip("\n") + "\n")


def _plain(node: Any) -> Any:
    """A ruamel node as plain dicts, lists and scalars, to compare with a stage."""
    if isinstance(node, Mapping):
        return {str(key): _plain(value) for key, value in node.items()}
    if isinstance(node, list):
        return [_plain(value) for value in node]
    return node


def _arms(parallel: Mapping[str, Any]) -> CommentedMap:
    """A stage's arms, one a line: `left: [reach: ready]`, `left: {app: wave}`, as the shipped file writes them."""
    return CommentedMap((key, flow(steps)) for key, steps in parallel.items())

