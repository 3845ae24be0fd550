"""The job dictionary and the application workspace's rules (Onika §4.4.1-4.4.2), as plain data.

Every job is an *action* or an *action requiring an object*; every named object has a type. Each
icon has a left and a right edge: an action's right edge is flat; an action requiring an object of
type T has a notch T on its right; an object of type T has the matching tab T on its left. Two
icons may sit side by side when the right edge of the left one fits the left edge of the right
one (`interlocks`): flat against flat, notch T against tab T. An application is an icon too: a
complete one is an action; an incomplete one whose gaps are all of type T is an action requiring
an object of type T (one object fills every gap); one with gaps of several types is *incomplete*
and fits as an action that leaves its gaps open.

Everything here returns JSON-ready data (lists, dicts, str, numbers), so `pbo check --format json`
and the local API can hand it on as it is. `row_gaps` answers the workspace's question for a
partial application the user is assembling: where each gap is and of which object type.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from pbo_runtime.config.model import ACTION, ACTION_REQUIRING_OBJECT, INCOMPLETE, ApplicationSpec, ApplicationStep, Subsystem

FLAT, NOTCH, TAB = "flat", "notch", "tab"
OBJECT = "object"  # the class of an object icon


def edges(kind: str, object_type: str | None = None) -> dict[str, dict[str, Any]]:
    """The left and right edges of an icon of class `kind` (ACTION, ACTION_REQUIRING_OBJECT, INCOMPLETE, OBJECT)."""
    flat: dict[str, Any] = {"shape": FLAT, "object_type": None}
    if kind == ACTION_REQUIRING_OBJECT:
        return {"left": dict(flat), "right": {"shape": NOTCH, "object_type": object_type}}
    if kind == OBJECT:
        return {"left": {"shape": TAB, "object_type": object_type}, "right": dict(flat)}
    return {"left": dict(flat), "right": dict(flat)}


def interlocks(left: Mapping[str, Any], right: Mapping[str, Any]) -> bool:
    """Whether an icon with edges `right` may sit just right of one with edges `left` (both as `edges` makes them)."""
    a, b = left["right"], right["left"]
    if a["shape"] == FLAT:
        return bool(b["shape"] == FLAT)
    return bool(a["shape"] == NOTCH and b["shape"] == TAB and a["object_type"] == b["object_type"])


def icon_edges(subsystem: Subsystem, name: str) -> dict[str, dict[str, Any]] | None:
    """The edges of the job, application or object called `name`; None if there is none."""
    if name in subsystem.jobs:
        job = subsystem.jobs[name]
        return edges(job.kind, job.object_type)
    if name in subsystem.applications:
        application = subsystem.applications[name]
        return edges(application.kind, application.object_type)
    if name in subsystem.objects:
        return edges(OBJECT, subsystem.objects[name].type)
    return None


def may_follow(subsystem: Subsystem, left: str, right: str) -> bool:
    """Whether icon `right` may sit just right of icon `left` in an application (both by name)."""
    a, b = icon_edges(subsystem, left), icon_edges(subsystem, right)
    return a is not None and b is not None and interlocks(a, b)


def job_dictionary(subsystem: Subsystem) -> dict[str, Any]:
    """Every object type, job, application and object with its class and edges (Onika's job dictionary)."""
    variables_of: dict[str, list[str]] = {}
    for variable in subsystem.variables.values():
        if variable.object is not None:
            variables_of.setdefault(variable.object, []).append(variable.name)
    object_types = {
        name: {"index": index, "type": kind.dtype, "shape": list(kind.shape), "unit": kind.unit, "doc": kind.doc,
               "declared": kind.declared, "variables": variables_of.get(name, []),
               "range": [kind.range.low, kind.range.high] if kind.range is not None else None,
               "objects": [o.name for o in subsystem.objects.values() if o.type == name]}
        for index, (name, kind) in enumerate(subsystem.object_types.items())
    }
    jobs = {
        name: {"class": job.kind, "configuration": job.configuration, "object": job.object, "object_type": job.object_type,
               "pre": job.pre, "post": job.post, "timeout": job.timeout, "edges": edges(job.kind, job.object_type)}
        for name, job in subsystem.jobs.items()
    }
    objects = {
        name: {"class": OBJECT, "type": obj.type, "value": obj.value.tolist(), "doc": obj.doc, "edges": edges(OBJECT, obj.type)}
        for name, obj in subsystem.objects.items()
    }
    applications = {name: describe_application(subsystem, name) for name in subsystem.applications}
    return {"object_types": object_types, "jobs": jobs, "applications": applications, "objects": objects}


def describe_application(subsystem: Subsystem, name: str) -> dict[str, Any]:
    """An application as plain data: its class and edges as a step of another, its steps, its gaps."""
    application: ApplicationSpec = subsystem.applications[name]
    steps = [_step_entry(number, step) for number, step in enumerate(application.steps, 1)]
    return {
        "class": application.kind,
        "complete": application.complete,
        "object_type": application.object_type,
        "edges": edges(application.kind, application.object_type),
        "steps": steps,
        "gaps": [{"step": g.step, "job": g.job, "object_type": g.object_type} for g in application.gaps],
    }


def _step_entry(number: int, step: ApplicationStep) -> dict[str, Any]:
    """A step as plain data; a step that decides with its kind, condition, bounds and rows (`decision`)."""
    # what fills the step: a named object, or a value written out (a job's, or an application's fill)
    value = next(iter(step.arguments.values()), None) if step.arguments else step.fill
    entry = {"step": number, "job": step.job, "application": step.is_application, "object": step.object, "value": value}
    decision = step.decision
    if decision is not None:
        entry["decision"] = {"kind": decision.kind, "condition": decision.condition, "times": decision.times,
                             "max": decision.most, "timeout": decision.timeout,
                             "rows": [[_step_entry(n, s) for n, s in enumerate(row, 1)] for row in decision.rows]}
    return entry


def row_gaps(subsystem: Subsystem, row: Sequence[Any]) -> dict[str, Any]:
    """Where the gaps of a partial application are, and of which object type (Onika §4.4.2, Figure 4).

    `row` is the workspace's row of icons, left to right: each item a job's, an application's or an
    object's name (an object fills the step just left of it), or a step as a file writes it,
    `{job: object name}` or `{job: {variable: value}}`. The answer, by position in `row` (`item`,
    0-based) and by step (`step`, 1-based, objects not counted):
    `steps`: each job or application with its class and the object that fills it;
    `gaps`: each step that still lacks its object, its type, and `insert_at`, where an object goes;
    `problems`: items that are no icon of the dictionary, or do not interlock with their left
    neighbour; `complete`: no gap and no problem (the application could run).
    """
    steps: list[dict[str, Any]] = []
    problems: list[dict[str, Any]] = []
    open_step: dict[str, Any] | None = None  # the step just left, while it needs an object
    previous = ""  # the item just left, by name
    for item, entry in enumerate(row):
        name, given = _split(entry)
        if name is None:
            problems.append({"item": item, "message": f"item {item} is no icon name: {entry!r}"})
            open_step, previous = None, ""
            continue
        if name in subsystem.objects and given is None:
            obj = subsystem.objects[name]
            if open_step is not None and open_step["object_type"] == obj.type:
                open_step["object"] = name
            else:
                after = (f"'{previous}', which needs an object of type {open_step['object_type']}" if open_step is not None
                         else f"'{previous}', which takes no object there" if previous else "the start of the application")
                problems.append({"item": item, "message": f"object '{name}' (type {obj.type}) does not interlock with {after}"})
            open_step, previous = None, name
            continue
        previous = name
        if name in subsystem.jobs:
            job = subsystem.jobs[name]
            kind, object_type, what = job.kind, job.object_type, "job"
        elif name in subsystem.applications:
            application = subsystem.applications[name]
            kind, object_type, what = application.kind, application.object_type, "application"
        else:
            problems.append({"item": item, "message": f"'{name}' is no job, application or object of this subsystem"})
            open_step = None
            continue
        step: dict[str, Any] = {"item": item, "step": len(steps) + 1, "name": name, "kind": what, "class": kind,
                "object_type": object_type, "object": None}
        steps.append(step)
        open_step = None
        if given is not None:
            problem = _given_problem(subsystem, name, kind, object_type, given)
            if problem:
                problems.append({"item": item, "message": problem})
            else:
                step["object"] = given if isinstance(given, str) else "(a value)"
            continue
        if kind == ACTION_REQUIRING_OBJECT:
            open_step = step
    gaps = []
    for step in steps:
        if step["object"] is not None:
            continue
        if step["class"] in (ACTION_REQUIRING_OBJECT, INCOMPLETE):  # INCOMPLETE: object_type None, fill it inside
            gaps.append({"item": step["item"], "step": step["step"], "job": step["name"], "object_type": step["object_type"],
                         "insert_at": step["item"] + 1})
    return {"steps": steps, "gaps": gaps, "problems": problems, "complete": not gaps and not problems}


def _split(entry: Any) -> tuple[str | None, Any]:
    """(icon name, what a `{name: given}` step gives it, or None)."""
    if isinstance(entry, str) and entry:
        return entry, None
    if isinstance(entry, Mapping) and len(entry) == 1:
        (name, given), = entry.items()
        if isinstance(name, str) and name:
            return name, given
    return None, None


def _given_problem(subsystem: Subsystem, name: str, kind: str, object_type: str | None, given: Any) -> str:
    """Why `{name: given}` does not interlock ("" if it does): the step takes no object, or one of another type."""
    if kind == ACTION:
        return f"'{name}' takes no object"
    if kind == INCOMPLETE:
        return f"'{name}' has gaps of several object types: no one object fills them"
    if isinstance(given, str):
        obj = subsystem.objects.get(given)
        if obj is None:
            return f"'{name}' is given object '{given}', which is no object of this subsystem"
        if obj.type != object_type:
            return f"'{name}' needs an object of type {object_type}, and '{given}' is of type {obj.type}"
        return ""
    if isinstance(given, Mapping) and len(given) == 1:
        return ""  # a value written out: `pbo check` judges its numbers when the application is saved
    return f"'{name}' is given {given!r}: give an object's name, or {{variable: value}}"


def dictionary_lines(subsystem: Subsystem) -> list[str]:
    """The job dictionary in a few lines of text, for `pbo check`: icons grouped by class and object type."""
    groups: dict[tuple[str, str | None], list[str]] = {}
    for name, job in subsystem.jobs.items():
        groups.setdefault((job.kind, job.object_type), []).append(name)
    for name, application in subsystem.applications.items():
        groups.setdefault((application.kind, application.object_type), []).append(name)
    for name, obj in subsystem.objects.items():
        groups.setdefault((OBJECT, obj.type), []).append(name)
    titles = {ACTION: "actions", ACTION_REQUIRING_OBJECT: "actions requiring an object", INCOMPLETE: "incomplete",
              OBJECT: "objects"}
    lines = []
    for kind in titles:
        parts = [", ".join(names) + (f" ({object_type})" if object_type else "")
                 for (k, object_type), names in groups.items() if k == kind]
        if parts:
            lines.append(f"{titles[kind]}: {'; '.join(parts)}")
    return lines
