"""`run:` as stages in an application file: `parallel:` runs several subsystems' steps at once and joins.

    run:
      - parallel: {left: [reach: ready], right: [reach: home]}   # steps, as a subsystem's application writes them
      - parallel: {left: {app: wave}}                            # or one of the subsystem's applications

Stages run in order; a stage ends when every subsystem it names has run its steps to the end (the
join), and only then does the next begin. A subsystem a stage does not name holds its
configuration meanwhile. A stage's steps are checked as an application of that subsystem, so
every step (a job, an application, a step that decides) interlocks as in the subsystem's file.
The join is kept on this machine (supervisor.stages): stages are refused with `hosts:`.

Subsystems of one stage run at once, so each must drive its own devices (E814). A device its
subsystem's plant simulates is that subsystem's alone (each subsystem runs its own plant); a device
outside the run is named by its driver's `outside_device(options)` (a robot behind ros2_control: its
DDS domain and command topic), and two subsystems naming the same one, on channels that overlap,
would both drive it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from typing import Any, Protocol

from pbo_runtime.config.decisions import paths
from pbo_runtime.config.loader import check_loaded, load_document, with_application
from pbo_runtime.config.model import ApplicationStep, Location, Subsystem
from pbo_runtime.config.transitions import Transition, transitions_of
from pbo_runtime.config.yaml_nodes import YList, YMap, load_text, location_of, plain
from pbo_runtime.errors import ConfigError, ConfigErrors
from pbo_runtime.objects import registry


class Error(Protocol):
    """Reports one mistake of the file: its code, what is wrong, where, and a hint."""

    def __call__(self, code: str, message: str, loc: Location, hint: str = "") -> None: ...


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
        _refuse_shared_devices(number, chosen, subsystems, loc, error)
        stages.append(chosen)
    return stages


_Driven = tuple[str, str, str, tuple[int, ...] | None]  # (subsystem, device, task, its channels: None for all)


def _refuse_shared_devices(number: int, chosen: dict[str, dict[str, Any]], subsystems: dict[str, Subsystem],
                           loc: Location, error: Error) -> None:
    """E814 at the stage: two of its subsystems drive one device outside the run (on channels that overlap)."""
    driven: dict[str, list[_Driven]] = {}
    for key, part in chosen.items():
        subsystem, name = subsystems[key], part.get("app")
        if name is None:
            subsystem, name = with_stage(subsystem, number, part["steps"]), stage_application(number)
        for outside, device, task, channels in _devices_driven(subsystem, name):
            driven.setdefault(outside, []).append((key, device, task, channels))
    for outside, users in driven.items():
        clash = next(((a, b) for i, a in enumerate(users) for b in users[i + 1:] if a[0] != b[0] and _overlap(a[3], b[3])), None)
        if clash is None:
            continue
        (first, device_a, task_a, _), (second, device_b, task_b, _) = clash
        error("E814", f"run: stage {number}: subsystems '{first}' and '{second}' both drive {outside}: device '{device_a}' "
                      f"of '{first}' (task '{task_a}') and device '{device_b}' of '{second}' (task '{task_b}')", loc,
              "subsystems of one stage run at once, each with its own devices: give one of them another device "
              "(its own topic, domain or channels), or run them in stages one after the other")


def _overlap(a: tuple[int, ...] | None, b: tuple[int, ...] | None) -> bool:
    return a is None or b is None or bool(set(a) & set(b))


def _devices_driven(subsystem: Subsystem, application: str) -> list[_Driven]:
    """(the device outside the run, its name here, the task, its channels) for the tasks the application's jobs turn on."""
    tasks: dict[str, None] = {}
    for job in _jobs(subsystem, subsystem.applications[application].steps, (application,)):
        for task in subsystem.configurations[subsystem.jobs[job].configuration].tasks:
            tasks[task] = None
    found = []
    for task in tasks:
        spec = subsystem.tasks[task]
        for device in spec.resources:
            outside = _outside_device(subsystem, device)
            if outside is not None:
                found.append((outside, device, task, spec.resource_channels.get(device)))
    return found


def _jobs(subsystem: Subsystem, steps: tuple[ApplicationStep, ...], seen: tuple[str, ...]) -> list[str]:
    """Every job a row of steps may run, on any path, through the applications it uses."""
    jobs: list[str] = []
    for step in steps:
        if step.decision is not None:
            for row in step.decision.rows:
                jobs.extend(_jobs(subsystem, row, seen))
        elif step.is_application:
            if step.job not in seen and step.job in subsystem.applications:
                jobs.extend(_jobs(subsystem, subsystem.applications[step.job].steps, (*seen, step.job)))
        elif step.job in subsystem.jobs:
            jobs.append(step.job)
    return jobs


def _outside_device(subsystem: Subsystem, device: str) -> str | None:
    """What names the device outside the run (its driver's `outside_device`), None for one of the subsystem's own."""
    spec = subsystem.devices.get(device)
    if spec is None:
        return None
    try:
        named = getattr(registry.driver_class(spec.driver), "outside_device", None)
    except Exception:  # a driver that cannot be loaded is the subsystem's check's to report
        return None
    return None if named is None else named(spec.options)


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


def stage_lines(stages: list[dict[str, dict[str, Any]]], subsystems: dict[str, Subsystem],
                table: Callable[[list[Transition], str], list[str]]) -> list[str]:
    """What `pbo check APP` says of the stages: each subsystem's part, and for each of its paths the switch
    table `table` writes (what each job turns off and on), as `pbo check` writes an application's. A part's
    first job switches from the configuration the subsystem's part of an earlier stage left on, when
    every path of it leaves the same one."""
    lines = []
    holding: dict[str, set[str | None]] = {}  # subsystem -> the configurations its earlier parts may leave on
    for number, stage in enumerate(stages, 1):
        lines.append(f"  stage {number}, in parallel: " + "; ".join(
            f"{key} " + (f"application '{part['app']}'" if "app" in part else f"{len(part['steps'])} step(s)")
            for key, part in stage.items()))
        for key, part in stage.items():
            subsystem, name = subsystems[key], part.get("app")
            if name is None:
                subsystem, name = with_stage(subsystem, number, part["steps"]), stage_application(number)
            listed, every = paths(subsystem, name)
            held = holding.get(key, {None})
            before = next(iter(held)) if len(held) == 1 else None
            for path_number, path in enumerate(listed, 1):
                label = f", path {path_number}: {path.label}" if len(listed) > 1 or path.label else ""
                lines.append(f"    {key}{label}" + ("" if path.jobs else ": no job"))
                lines.extend(table(_switches(subsystem, path.jobs, before), "      "))
            if every > len(listed):
                lines.append(f"    {key}: ... and {every - len(listed)} more path(s)")
            holding[key] = {None} if every > len(listed) else {
                subsystem.jobs[path.jobs[-1]].configuration if path.jobs else was for path in listed for was in held}
    return lines


def _switches(subsystem: Subsystem, jobs: tuple[str, ...], before: str | None) -> list[Transition]:
    """The transitions of `jobs`, the first from configuration `before` (None: from nothing on)."""
    opener = next((job for job, spec in subsystem.jobs.items() if spec.configuration == before), None)
    if opener is None or not jobs:
        return transitions_of(subsystem, jobs)
    return [dataclasses.replace(t, step=t.step - 1) for t in transitions_of(subsystem, (opener, *jobs))[1:]]
