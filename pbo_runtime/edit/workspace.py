"""The application workspace's row (Onika §4.4.2) as the steps a file writes, and as the steps a run is sent.

The HMI's workspace holds one row of interlocking icons: each step a job or an application, each
step that requires an object followed by the object that fills it, or by a gap of its type. The
browser sends the row as `[{"name": step, "object": object name or null}, ...]`, left to right.

- `file_steps`: the row as `applications:` writes it: `reach` (an action, or a gap left open),
  `{reach: ready}` (a named object). A row with a gap is an incomplete application: it may be
  saved and used as an action requiring an object, but not run.
- `run_steps`: the same row with every named object written out as its value now (`{reach: {q_d:
  [...]}}`, or `{approach: {joint_position: [...]}}` for an application), so the run is given the
  values the user sees and edits in the file, whatever the values the run read at its start.
- `row_problems`: why the row cannot be saved (an icon the file does not have, an object that does
  not interlock) or run (its gaps), each a line the user reads, from `job_dictionary.row_gaps`.

A step that decides (config.decisions) comes as `{"kind": "if" | "try" | "repeat" | "wait",
"condition": ..., "times": ..., "max": ..., "timeout": "2 s", "rows": [[step, ...], ...]}`, its rows
rows of the same kind (then/else, try/fallback, the repeated steps); each row is checked as the
row is, and the whole application again by the checker when it is saved or run.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pbo_runtime.config.model import Subsystem
from pbo_runtime.edit.job_dictionary import row_gaps

# An application's name: a plain identifier, as a live application's (it travels in the control queue)
NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,39}$")
MAX_ROW = 64  # steps: an application a person assembles, not a generated sequence


class RowRefused(ValueError):
    """The row cannot be saved or run as it is: the message says why and what to do."""


@dataclass(frozen=True)
class Step:
    """One step of the row: a job or an application, and the named object that fills it (None: none, or a gap)."""

    name: str
    object: str | None = None
    decision: Mapping[str, Any] | None = None  # a step that decides: its kind and settings, as the browser sent them
    rows: tuple[tuple[Step, ...], ...] = ()  # a step that decides: its rows of steps


def parse_row(row: Any) -> list[Step]:
    """The browser's row as Steps; RowRefused naming the first item that is not `{"name": str, "object": str | null}`."""
    if not isinstance(row, list) or not row:
        raise RowRefused("the workspace is empty: drop jobs from the dictionary into it first")
    if len(row) > MAX_ROW:
        raise RowRefused(f"the row has {len(row)} steps, more than the {MAX_ROW} an application may have here")
    return _parse_steps(row, "")


ROW_NAMES = {"if": ("then", "else"), "try": ("try", "fallback"), "repeat": ("repeat",), "wait": ()}
_SETTINGS = {"if": ("condition",), "try": (), "repeat": ("times", "until", "max"), "wait": ("condition", "timeout")}


def _parse_steps(row: list[Any], where: str) -> list[Step]:
    steps = []
    for number, item in enumerate(row, 1):
        if isinstance(item, Mapping) and item.get("kind") in ROW_NAMES:
            steps.append(_parse_decision(item, f"{where}step {number}"))
            continue
        name = item.get("name") if isinstance(item, Mapping) else None
        given = item.get("object") if isinstance(item, Mapping) else None
        if not isinstance(name, str) or not name or (given is not None and (not isinstance(given, str) or not given)):
            raise RowRefused(f"{where}step {number} of the row is not {{\"name\": job, \"object\": object or null}}: {item!r}")
        steps.append(Step(name, given))
    return steps


def _parse_decision(item: Mapping[str, Any], where: str) -> Step:
    kind = str(item["kind"])
    rows = item.get("rows", [])
    names = ROW_NAMES[kind]
    if not isinstance(rows, list) or len(rows) != len(names) or not all(isinstance(r, list) for r in rows):
        raise RowRefused(f"{where} ({kind}) must have {len(names)} row(s) of steps ({', '.join(names) or 'none'})")
    settings = {key: item[key] for key in _SETTINGS[kind] if item.get(key) not in (None, "")}
    for key, value in settings.items():
        if not isinstance(value, (str, int)) or isinstance(value, bool):
            raise RowRefused(f"{where} ({kind}): {key} must be text or a whole number, got {value!r}")
    parsed = tuple(tuple(_parse_steps(r, f"{where} ({kind}, {label}): ")) for r, label in zip(rows, names, strict=True))
    return Step(kind, None, {"kind": kind, **settings}, parsed)


def check_name(name: Any) -> str:
    """An application's name as given, if it is one; RowRefused otherwise."""
    if not isinstance(name, str) or not NAME.match(name):
        raise RowRefused(f"an application's name is a letter or '_' then letters, digits or '_', at most 40 characters, "
                         f"got: {name!r}")
    return name


def file_steps(steps: Sequence[Step]) -> list[Any]:
    """The row as `applications:` writes it: a name alone, `{name: object}`, or a step that decides with its rows."""
    return [_decision_file_step(step, file_steps) if step.decision is not None
            else step.name if step.object is None else {step.name: step.object} for step in steps]


def _decision_file_step(step: Step, written: Any) -> dict[str, Any]:
    """A step that decides as a file writes it; `written` writes its rows (as names, or with values)."""
    assert step.decision is not None
    kind = step.decision["kind"]
    out: dict[str, Any] = {}
    if kind in ("if", "wait"):
        out[kind] = step.decision.get("condition", "")
    for label, row in zip(ROW_NAMES[kind], step.rows, strict=True):
        if row or label != "else":
            out[label] = written(row)
    for key in ("times", "until", "max", "timeout"):
        if key in step.decision:
            out[key] = step.decision[key]
    return out  # its kind first: `if`, `wait` put their condition there, `try`, `repeat` their row


def _leaves(steps: Sequence[Step]) -> list[tuple[Step, str]]:
    """The jobs and applications of a row and of the rows inside its steps that decide, each with where it is."""
    found: list[tuple[Step, str]] = []

    def walk(row: Sequence[Step], where: str) -> None:
        for number, step in enumerate(row, 1):
            if step.decision is None:
                found.append((step, f"{where}step {number}"))
                continue
            for label, inner in zip(ROW_NAMES[step.decision["kind"]], step.rows, strict=True):
                walk(inner, f"{where}step {number} ({step.name}, {label}): ")
    walk(steps, "")
    return found


def row_problems(subsystem: Subsystem, steps: Sequence[Step]) -> tuple[list[str], list[str]]:
    """(problems, gaps): why the row is no application of this file; which of its steps lack their object."""
    leaves = _leaves(steps)  # every job and application, wherever it is: each interlocks with its own object
    answer = row_gaps(subsystem, file_steps([step for step, _ in leaves]))
    places = [where for _, where in leaves]
    problems = [f"{places[problem['item']]}: {problem['message']}" for problem in answer["problems"]]
    gaps = [f"{places[gap['item']]} '{gap['job']}' needs an object of type {gap['object_type']}" if gap["object_type"]
            else f"{places[gap['item']]} '{gap['job']}' has gaps of several object types inside it" for gap in answer["gaps"]]
    return problems, gaps


def checked_row(subsystem: Subsystem, row: Any, run: bool) -> list[Step]:
    """The row's steps if it can be saved (run False) or run (run True); RowRefused saying why not."""
    steps = parse_row(row)
    problems, gaps = row_problems(subsystem, steps)
    if problems:
        raise RowRefused(f"the icons do not interlock: {'; '.join(problems)}")
    if run and gaps:
        count = f"{len(gaps)} gap" + ("" if len(gaps) == 1 else "s")
        raise RowRefused(f"the application has {count} and cannot run: {'; '.join(gaps)}; drop an object of that type "
                         f"on each gap")
    return steps


def run_steps(subsystem: Subsystem, steps: Sequence[Step]) -> list[str | dict[str, Any]]:
    """The row's steps with each named object written out as its value now (see the module's docstring)."""
    written: list[str | dict[str, Any]] = []
    for step in steps:
        if step.decision is not None:
            written.append(_decision_file_step(step, lambda row: run_steps(subsystem, row)))
            continue
        if step.object is None:
            written.append(step.name)
            continue
        value = subsystem.objects[step.object].value.tolist()
        if step.name in subsystem.jobs:
            variable = subsystem.jobs[step.name].object
            assert variable is not None, "row_problems let only a job that takes an object have one"
            written.append({step.name: {variable: value}})
        else:  # an incomplete application: the object, written under its type's name, fills every gap
            written.append({step.name: {subsystem.objects[step.object].type: value}})
    return written
