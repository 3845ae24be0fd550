"""`run:` as stages in an application file: `parallel:` runs several subsystems' steps at once and joins.

    run:
      - parallel: {left: [reach: ready], right: [reach: home]}   # steps, as a subsystem's application writes them
      - parallel: {left: {app: wave}}                            # or one of the subsystem's applications

Stages run in order; a stage ends when every subsystem it names has run its steps to the end (the
join), and only then does the next begin. A subsystem a stage does not name holds its
configuration meanwhile. A stage's steps are checked as an application of that subsystem, so
every step (a job, an application, a step that decides) interlocks as in the subsystem's file.
The join is kept on this machine (supervisor.stages): stages are refused with `hosts:`.
"""

from __future__ import annotations

import json
from typing import Any, Callable

from pbo_runtime.config.decisions import paths
from pbo_runtime.config.loader import check_loaded, load_document, with_application
from pbo_runtime.config.transitions import transitions_of
from pbo_runtime.config.model import Location, Subsystem
from pbo_runtime.config.yaml_nodes import YList, YMap, load_text, location_of, plain
from pbo_runtime.errors import ConfigError, ConfigErrors

Error = Callable[..., None]  # (code, message, loc, hint)
EXAMPLE = "e.g. run: [{parallel: {left: [reach: ready], right: [reach: home]}}, {parallel: {left: {app: wave}}}]"


def stage_application(number: int) -> str:
    """The name a stage's steps run under in its subsystem."""
    return f"stage_{number}"


def with_stage(subsystem: Subsystem, number: int, steps: list[Any]) -> Subsystem:
    """The subsystem of `subsystem`'s file with stage `number`'s steps as one more application, checked
    with the whole file; ConfigErrors says what is wrong."""
    doc, errors = load_document(subsystem.file)
    if errors or not isinstance(doc, YMap):
        raise ConfigErrors(errors or [ConfigError("the file is not a mapping", subsystem.file, 0, 0)])
    where = Location(f"<run: stage {number}>", 1, 1)
    try:  # JSON is YAML on one line: the safe loader reads it, each step located in it
        node = load_text(f"value: {json.dumps(steps)}\n", where.file)["value"]
    except ConfigError as exc:
        raise ConfigErrors([exc]) from None
    result = check_loaded(with_application(doc, stage_application(number), node, where), subsystem.file)
    if result.errors or result.subsystem is None:
        raise ConfigErrors(result.errors)
    return result.subsystem


def check_stages(entries: YList, subsystems: dict[str, Subsystem], placed: bool, error: Error,
                 did_you_mean: Callable[[str, Any, str], str]) -> list[dict[str, dict[str, Any]]]:
    """The stages of `run:`, each subsystem -> {"steps": [...]} or {"app": NAME}; every mistake reported."""
    stages: list[dict[str, dict[str, Any]]] = []
    if placed:
        error("E813", "run: stages (parallel:) join on one machine, but this application places its subsystems on hosts",
              entries.loc, "run the stages' steps without hosts:, or give each subsystem its own {app: NAME} in run:")
        return stages
    for index, stage in enumerate(entries):
        number = index + 1
        loc = entries.item_loc(index)
        if not isinstance(stage, YMap) or list(stage) != ["parallel"] or not isinstance(stage["parallel"], YMap) \
                or not stage["parallel"]:
            error("E813", f"run: stage {number} must be parallel: {{SUBSYSTEM: STEPS, ...}}", location_of(stage, loc), EXAMPLE)
            continue
        branches = stage["parallel"]
        chosen: dict[str, dict[str, Any]] = {}
        for key, value in branches.items():
            where = branches.value_loc(key)
            if key not in subsystems:
                error("E813", f"run: stage {number} runs subsystem '{key}', which this application does not have",
                      branches.key_loc(key), did_you_mean(str(key), subsystems, "subsystems"))
                continue
            picked = _branch(number, str(key), value, where, subsystems[key], error)
            if picked is not None:
                chosen[str(key)] = picked
        stages.append(chosen)
    return stages


def _branch(number: int, key: str, value: Any, loc: Location, subsystem: Subsystem, error: Error) -> dict[str, Any] | None:
    if isinstance(value, YMap) and list(value) == ["app"]:
        name = value["app"]
        if name not in subsystem.applications:
            error("E813", f"run: stage {number}: subsystem '{key}' has no application '{name}'", value.value_loc("app"),
                  f"its applications: {', '.join(subsystem.applications) or 'none'}")
            return None
        if not subsystem.applications[name].complete:
            error("E813", f"run: stage {number}: application '{name}' of subsystem '{key}' is incomplete", value.value_loc("app"),
                  "a step lacks its object: pbo check its file")
            return None
        return {"app": str(name)}
    if not isinstance(value, YList) or not value:
        error("E813", f"run: stage {number}: subsystem '{key}' takes a list of steps or {{app: NAME}}, got {plain(value)!r}",
              location_of(value, loc), "e.g. left: [reach: ready], or left: {app: wave}")
        return None
    steps = plain(value)
    try:
        staged = with_stage(subsystem, number, steps)
    except ConfigErrors as refused:
        found = [line.split("]: ", 1)[1] for line in str(refused).splitlines() if "error[" in line and "]: " in line]
        error("E813", f"run: stage {number}: the steps of subsystem '{key}' do not interlock: {'; '.join(found) or refused}", loc,
              f"the steps are checked as an application of {subsystem.file}")
        return None
    if not staged.applications[stage_application(number)].complete:
        error("E813", f"run: stage {number}: a step of subsystem '{key}' lacks its object", loc,
              "give each job its object, e.g. reach: ready")
        return None
    return {"steps": steps}


def stage_lines(stages: list[dict[str, dict[str, Any]]], subsystems: dict[str, Subsystem]) -> list[str]:
    """What `pbo check APP` says of the stages: each subsystem's part, and the switches of each of its paths."""
    lines = []
    for number, stage in enumerate(stages, 1):
        lines.append(f"  stage {number}, in parallel: " + "; ".join(
            f"{key} " + (f"application '{part['app']}'" if "app" in part else f"{len(part['steps'])} step(s)")
            for key, part in stage.items()))
        for key, part in stage.items():
            subsystem, name = subsystems[key], part.get("app")
            if name is None:
                subsystem, name = with_stage(subsystem, number, part["steps"]), stage_application(number)
            listed, every = paths(subsystem, name)
            for path in listed:
                switches = "; ".join(f"{t.job} ({t.after if t.before in (None, t.after) else f'{t.before} -> {t.after}'})"
                                     for t in transitions_of(subsystem, path.jobs))
                lines.append(f"    {key}" + (f", {path.label}" if path.label else "") + f": {switches or 'no job'}")
            if every > len(listed):
                lines.append(f"    {key}: ... and {every - len(listed)} more path(s)")
    return lines
