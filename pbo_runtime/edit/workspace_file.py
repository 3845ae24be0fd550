"""What the HMI's user level writes to the subsystem file: an application, a named object's value.

Both go through ruamel.yaml's round trip as `pbo save` does (`edit.live_save`): comments, key
order and flow style are kept, and only the entry that changed is taken from the dump; every other
line is the file's own. The new text goes through `edit.write_back`: written beside the file,
checked there by the checker of `pbo check`, and moved over the file only when it has no error, so
a refused save leaves the file as it was. A
warning stays a warning (an incomplete application is W701: kept, reusable, not runnable).

The file is the one `pbo hmi FILE` was given or the run's own, never a path from a request: the
API passes it in.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from typing import Any

from ruamel.yaml.comments import CommentedMap, CommentedSeq

from pbo_runtime.config.loader import CheckResult, check_file
from pbo_runtime.config.model import Subsystem
from pbo_runtime.config.values import as_value, range_problem
from pbo_runtime.edit.live_save import merged, round_trip
from pbo_runtime.edit.write_back import WriteRefused, write_checked
from pbo_runtime.errors import PboError


class SaveRefused(PboError):
    """The file was not changed: what was asked is wrong, or the file would not check clean."""


def save_application(file: str, name: str, steps: list[Any], replace: bool = False) -> CheckResult:
    """Write application `name` with `steps` (as `applications:` writes them) to `file`; the check of the new file."""
    def change(doc: CommentedMap) -> None:
        applications = doc.get("applications")
        if applications is None:
            applications = doc["applications"] = CommentedMap()
        if name in applications and not replace:
            raise SaveRefused(f"application '{name}' exists in {file}: choose another name, or replace it")
        applications[name] = CommentedSeq(step if isinstance(step, str) else CommentedMap(step) for step in steps)

    return _write_checked(file, change, {"applications": {name}})


def save_object(file: str, subsystem: Subsystem, name: str, value: Any) -> CheckResult:
    """Write named object `name`'s value to `file`, checked against its type first; the check of the new file."""
    obj = subsystem.objects.get(name)
    if obj is None:
        raise SaveRefused(f"no object '{name}' in {file} (objects: {', '.join(subsystem.objects) or 'none'})")
    kind = subsystem.object_types[obj.type]
    try:  # the checker's rule for a value in a file: numbers of the dtype, finite, one for each element
        array = as_value(value, kind.dtype, kind.shape, f"object '{name}' (type {obj.type})")
    except ValueError as exc:
        raise SaveRefused(str(exc)) from None
    problem = range_problem(array, kind.name, kind.range)
    if problem:
        raise SaveRefused(f"object '{name}' (type {obj.type}): {problem}")

    def change(doc: CommentedMap) -> None:
        objects = doc.get("objects")
        if objects is None or name not in objects:
            raise SaveRefused(f"object '{name}' is declared in a file {file} includes ({obj.loc.file}): "
                              f"change its value there")
        entry = objects[name]
        written = array.tolist()
        if isinstance(written, list):
            written = _flow_list(written)
        entry["value"] = written

    return _write_checked(file, change, {"objects": {name}})


def _flow_list(values: list[Any]) -> CommentedSeq:
    """A list of numbers (or of lists) in flow style, `[0.3, -0.5]`, as the shipped files write values."""
    sequence = CommentedSeq(_flow_list(v) if isinstance(v, list) else v for v in values)
    sequence.fa.set_flow_style()
    return sequence


def _write_checked(file: str, change: Callable[[CommentedMap], None], touched: dict[str, set[str]]) -> CheckResult:
    """`change` made on the file's round-trip document, written over the file only if the result checks clean."""
    try:
        with open(file, encoding="utf-8") as stream:
            original = stream.read()
    except OSError as exc:
        raise SaveRefused(f"cannot read {file}: {exc.strerror or exc}") from None
    yaml = round_trip()
    doc = yaml.load(original)
    if not isinstance(doc, CommentedMap):
        raise SaveRefused(f"{file} is not a mapping of sections: run pbo check {file}")
    change(doc)
    out = io.StringIO()
    yaml.dump(doc, out)
    text = merged(original, out.getvalue(), touched).rstrip("\n") + "\n"  # a blank line ruamel moved to the end
    try:
        write_checked(file, text)
    except WriteRefused as refused:
        raise SaveRefused(str(refused)) from None
    return check_file(file)
