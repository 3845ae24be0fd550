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
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pbo_runtime.config.job_dictionary import row_gaps
from pbo_runtime.config.model import Subsystem

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


def parse_row(row: Any) -> list[Step]:
    """The browser's row as Steps; RowRefused naming the first item that is not `{"name": str, "object": str | null}`."""
    if not isinstance(row, list) or not row:
        raise RowRefused("the workspace is empty: drop jobs from the dictionary into it first")
    if len(row) > MAX_ROW:
        raise RowRefused(f"the row has {len(row)} steps, more than the {MAX_ROW} an application may have here")
    steps = []
    for number, item in enumerate(row, 1):
        name = item.get("name") if isinstance(item, Mapping) else None
        given = item.get("object") if isinstance(item, Mapping) else None
        if not isinstance(name, str) or not name or (given is not None and (not isinstance(given, str) or not given)):
            raise RowRefused(f"step {number} of the row is not {{\"name\": job, \"object\": object or null}}: {item!r}")
        steps.append(Step(name, given))
    return steps


def check_name(name: Any) -> str:
    """An application's name as given, if it is one; RowRefused otherwise."""
    if not isinstance(name, str) or not NAME.match(name):
        raise RowRefused(f"an application's name is a letter or '_' then letters, digits or '_', at most 40 characters, "
                         f"got: {name!r}")
    return name


def file_steps(steps: Sequence[Step]) -> list[str | dict[str, str]]:
    """The row as `applications:` writes it: a name alone, or `{name: object}`."""
    return [step.name if step.object is None else {step.name: step.object} for step in steps]


def row_problems(subsystem: Subsystem, steps: Sequence[Step]) -> tuple[list[str], list[str]]:
    """(problems, gaps): why the row is no application of this file; which of its steps lack their object."""
    answer = row_gaps(subsystem, file_steps(steps))
    problems = [f"step {problem['item'] + 1}: {problem['message']}" for problem in answer["problems"]]
    gaps = [f"step {gap['step']} '{gap['job']}' needs an object of type {gap['object_type']}" if gap["object_type"]
            else f"step {gap['step']} '{gap['job']}' has gaps of several object types inside it" for gap in answer["gaps"]]
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
