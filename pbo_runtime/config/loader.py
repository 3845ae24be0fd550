"""Load a subsystem's YAML file (and its includes), check it, and build the frozen `Subsystem`.

`check_file` is what `pbo check` and the supervisor call: it never raises for anything in the
files, it returns every error and warning. `load_subsystem` is the strict form: a `Subsystem`
or `ConfigErrors` listing everything wrong. Module classes are found by name through
`module_lookup` (the library registry by default; tests pass fakes).
"""

from __future__ import annotations

import gc
import os
from collections.abc import Callable, Collection, Iterable
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pbo_runtime.config import bus_model
from pbo_runtime.config.checker import Checked, ModuleLookup, check_document, describe
from pbo_runtime.config.file_kind import ALLOW_UNSTABLE_LOOPS
from pbo_runtime.config.model import Location, Subsystem
from pbo_runtime.config.root import OUTSIDE_ROOT, confined, leaves_root
from pbo_runtime.config.yaml_nodes import YList, YMap, load_file, load_text
from pbo_runtime.errors import ConfigError, ConfigErrors
from pbo_runtime.objects import registry

# Sections whose entries an included file may add to (names must not clash).
_MERGED_SECTIONS = ("devices", "dims", "variables", "object_types", "objects", "tasks", "configurations", "jobs",
                    "applications")


@dataclass
class CheckResult:
    """Every problem of a file, and the subsystem when there is no error."""

    subsystem: Subsystem | None
    errors: list[ConfigError] = field(default_factory=list)
    warnings: list[ConfigError] = field(default_factory=list)
    initial_values: dict[str, np.ndarray] = field(default_factory=dict)  # variable -> its `initial:` value
    inferred: tuple[str, ...] = ()  # variables whose type or shape came from their ports, when there is no error
    robot_dims: dict[str, int] = field(default_factory=dict)  # dims taken from the plant's robot, when there is no error
    robot_notes: list[str] = field(default_factory=list)  # what loading the plant's robot file changed
    robot_limits: list[dict[str, Any]] = field(default_factory=list)  # each joint's limits: what the robot interface enforces

    @property
    def ok(self) -> bool:
        return not self.errors


def _default_names() -> Iterable[str]:
    return registry.names(registry.MODULES)


#: Set to "1" in a run's environment by `pbo run --allow-unstable-loops`: its processes load the file
#: with an unstable joint loop (E326) as a warning.


def check_file(
    path: str | os.PathLike[str],
    module_lookup: ModuleLookup = registry.module_class,
    *,
    module_names: Callable[[], Iterable[str]] | None = None,
    root: str | os.PathLike[str] | None = None,
    text: str | None = None,
    waive: Collection[str] = (),
) -> CheckResult:
    """Check a subsystem file and its includes; every problem ends in the result, never raised.

    `module_names` lists the registered modules for "did you mean"; by default the registry's
    names when `module_lookup` is the registry's. `root`: no file outside this tree is read
    (`config.root`; by default the confinement in force, none for pbo check). `text`: the file's
    content when it is not on disk (the HMI editor's unsaved file), its includes found beside `path`.
    Errors of the codes in `waive` become warnings (`pbo run --allow-unstable-loops`: E326).
    """
    # A large file makes hundreds of thousands of small objects and no reference cycles that
    # matter: the cyclic GC would only rescan the growing heap again and again.
    enabled = gc.isenabled()
    gc.disable()
    try:
        with confined(root) if root is not None else nullcontext():
            return _check_file(path, module_lookup, module_names, text, waive)
    finally:
        if enabled:
            gc.enable()


def _check_file(
    path: str | os.PathLike[str],
    module_lookup: ModuleLookup,
    module_names: Callable[[], Iterable[str]] | None,
    text: str | None,
    waive: Collection[str] = (),
) -> CheckResult:
    if module_names is None and module_lookup is registry.module_class:
        module_names = _default_names
    file = os.fspath(path)
    errors: list[ConfigError] = []
    try:
        doc = _load_with_includes(file, [], errors, text)
        checked = Checked() if doc is _UNREADABLE else check_document(doc, file, module_lookup, module_names)
    except Exception as exc:  # the promise is "never a traceback"; a bug becomes a message to report
        checked = Checked()
        checked.errors.append(
            ConfigError(f"internal error while loading: {exc!r}", file, hint="please report this with the file you checked")
        )
    waived = [e for e in checked.errors if e.code in waive]
    if waived:
        checked.errors = [e for e in checked.errors if e.code not in waive]
        checked.warnings += [ConfigError(e.message, e.file, e.line, e.column, e.hint, "warning", e.code, e.notes) for e in waived]
    return _result(checked, file, errors)


def check_loaded(doc: Any, file: str, module_lookup: ModuleLookup = registry.module_class) -> CheckResult:
    """Check a document already loaded (and changed: a live change, `edit.live`) as `check_file` checks a file."""
    names = _default_names if module_lookup is registry.module_class else None
    return _result(check_document(doc, file, module_lookup, names), file, [])


def with_application(doc: YMap, name: str, steps: YList, loc: Location) -> YMap:
    """A copy of `doc` with application `name` (replaced if it has one) of `steps`, written at `loc`;
    `doc` stays as it was, and every other key keeps where it was written."""
    copy = doc.shallow_copy()
    existing = doc.get("applications")
    applications = existing.shallow_copy() if isinstance(existing, YMap) else YMap(loc)
    applications.put(name, steps, loc, loc)
    where = (doc.key_loc("applications"), doc.value_loc("applications")) if "applications" in doc else (loc, loc)
    copy.put("applications", applications, *where)
    return copy



def load_document(file: str, root: str | os.PathLike[str] | None = None) -> tuple[Any, list[ConfigError]]:
    """A file's document with its includes merged in (what `check_file` checks), and what kept it from loading."""
    errors: list[ConfigError] = []
    with confined(root) if root is not None else nullcontext():
        doc = _load_with_includes(file, [], errors)
    return (None if doc is _UNREADABLE else doc), errors


def _result(checked: Checked, file: str, errors: list[ConfigError]) -> CheckResult:
    errors.extend(checked.errors)
    errors.sort(key=_position)
    warnings = sorted(checked.warnings, key=_position)
    subsystem = None if errors else _assemble(checked, file)
    if subsystem is not None:
        errors = _bus_errors(subsystem)
        if errors:
            subsystem = None
    if errors:
        return CheckResult(subsystem, errors, warnings)
    return CheckResult(
        subsystem,
        errors,
        warnings,
        dict(checked.initial_values),
        tuple(checked.inferred),
        dict(checked.robot_dims),
        list(checked.robot_notes),
        list(checked.robot_limits),
    )


def _bus_errors(subsystem: Subsystem) -> list[ConfigError]:
    """Configurations whose predicted bus load (TR eq. 1-2) exceeds the bandwidth: E510."""
    errors = []
    try:
        over = bus_model.over_bandwidth(subsystem)
    except bus_model.BusModelError as exc:  # the rules above should have caught it: say so, don't crash
        return [ConfigError(f"cannot predict the bus load: {exc}", subsystem.file, 1, 1, code="E901",
                            hint="please report this with the file you checked")]
    for name, report in over:
        heaviest = max(report.tasks, key=lambda t: t.rate_bytes_per_s)
        loc = subsystem.configurations[name].loc
        errors.append(ConfigError(
            f"configuration '{name}' needs {report.total / 1e3:,.1f} kB/s of bus, {report.share:.0%} of the "
            f"{report.bandwidth / 1e6:g} MB/s bandwidth (TR eq. 1-2); the heaviest task is '{heaviest.task}' "
            f"at {heaviest.rate_bytes_per_s / 1e3:,.1f} kB/s",
            loc.file, loc.line, loc.column, code="E510",
            hint="lengthen periods, move variables out of the per-cycle ports, combine tasks (TR 4.5), or "
                 "raise bus: {bandwidth: ...} if the backplane is faster (see pbo bus FILE)",
        ))
    return errors


def load_subsystem(
    path: str | os.PathLike[str],
    module_lookup: ModuleLookup = registry.module_class,
    *,
    module_names: Callable[[], Iterable[str]] | None = None,
    waive: Collection[str] | None = None,
) -> Subsystem:
    """The checked subsystem, or ConfigErrors with every error of the file (but those of the codes in `waive`;
    by default E326 when `pbo run --allow-unstable-loops` set ALLOW_UNSTABLE_LOOPS for the run's processes)."""
    if waive is None:
        waive = ("E326",) if os.environ.get(ALLOW_UNSTABLE_LOOPS) == "1" else ()
    result = check_file(path, module_lookup, module_names=module_names, waive=waive)
    if result.errors or result.subsystem is None:
        raise ConfigErrors(result.errors)
    return result.subsystem


def format_diagnostics(result: CheckResult) -> str:
    """Errors and warnings in file/line order, then a count line like '2 errors, 1 warning'."""
    problems = sorted([*result.errors, *result.warnings], key=_position)
    lines = [p.format() for p in problems]
    lines.append(f"{_count(len(result.errors), 'error')}, {_count(len(result.warnings), 'warning')}")
    return "\n".join(lines)


def _count(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _position(error: ConfigError) -> tuple[str, int, int]:
    return (error.file, error.line, error.column)


def _assemble(checked: Checked, file: str) -> Subsystem:
    return Subsystem(
        name=checked.name,
        file=file,
        rtpus=checked.rtpus,
        bus=checked.bus,
        plant=checked.plant,
        devices=dict(checked.devices),
        dims=dict(checked.dims),
        variables=dict(checked.variables),
        tasks=dict(checked.tasks),
        configurations=dict(checked.configurations),
        jobs=dict(checked.jobs),
        applications=dict(checked.applications),
        init_order=checked.init_order,
        object_types=dict(checked.object_types),
        objects=dict(checked.objects),
        robot_notes=tuple(checked.robot_notes),
    )


def _load_with_includes(file: str, stack: list[str], errors: list[ConfigError], text: str | None = None) -> Any:
    """The file's document with the mappings of its `include:` files merged in, includes first.

    Problems of the includes themselves (missing file, cycle, clash, outside the root) go to
    `errors`; the merged document still gets checked so the user sees everything at once.
    """
    try:
        doc = _load_document(file) if text is None else load_text(text, file)
    except ConfigError as exc:
        errors.append(exc)
        return _UNREADABLE
    if not isinstance(doc, YMap) or "include" not in doc:
        return doc
    includes = doc["include"]
    inc_loc = doc.value_loc("include")
    if isinstance(includes, str):
        includes_list: list[tuple[Any, Location]] = [(includes, inc_loc)]
    elif isinstance(includes, YList):
        includes_list = [(item, includes.item_loc(i)) for i, item in enumerate(includes)]
    else:
        errors.append(
            _error(
                f"'include' must be a list of file paths, got: {describe(includes)}",
                inc_loc,
                "e.g. include: [common/puma_variables.yaml]",
            )
        )
        return doc
    merged = YMap(doc.loc)
    here = os.path.dirname(file)
    chain = [*stack, os.path.realpath(file)]
    for item, loc in includes_list:
        if not isinstance(item, str) or not item:
            errors.append(_error(f"an include must be a file path, got: {describe(item)}", loc))
            continue
        if "\0" in item:  # no file system takes one: os.path would raise
            errors.append(_error(f"an include must be a file path, got: {item!r}, which holds a NUL character", loc,
                                 "write the path as plain text, e.g. include: [common/puma_variables.yaml]"))
            continue
        target = os.path.normpath(os.path.join(here, item))
        root = leaves_root(target)
        if root is not None:  # refused before it is opened: neither its content nor whether it exists is told
            errors.append(ConfigError(f"included file '{item}' is outside {root}, the folder this server reads", loc.file,
                                      loc.line, loc.column, "the local API reads the subsystem file's folder and below "
                                      "only; move the included file into it", code=OUTSIDE_ROOT))
            continue
        if os.path.realpath(target) in chain:
            errors.append(
                _error(
                    f"'{item}' includes itself (through {' -> '.join(os.path.basename(c) for c in chain)})",
                    loc,
                    "remove one of the includes",
                )
            )
            continue
        if not os.path.isfile(target):
            errors.append(
                _error(
                    f"included file '{item}' does not exist (looked for {target})",
                    loc,
                    "include paths are relative to the including file",
                )
            )
            continue
        part = _load_with_includes(target, chain, errors)
        if part is _UNREADABLE:
            continue
        if not isinstance(part, YMap):
            errors.append(_error(f"included file '{item}' must be a mapping of sections, got: {describe(part)}", loc))
            continue
        _merge_into(merged, part, errors)
    _merge_into(merged, doc, errors)
    return merged


_UNREADABLE = object()
PLACEMENT_KEY = "host"  # an inline subsystem's host (config.application), beside its own keys
INLINE = "#"  # "app.yaml#operator": the subsystem written inline under `subsystems: {operator: ...}` of app.yaml


def inline_reference(application_file: str, key: str) -> str:
    """The name by which every process loads a subsystem written inline in an application file."""
    return f"{application_file}{INLINE}{key}"


def _load_document(file: str) -> Any:
    """A subsystem file's document, or the inline subsystem an `app.yaml#key` reference points at.

    Locations stay those of the application file, so an inline subsystem's errors point into it.
    """
    path, mark, key = file.rpartition(INLINE)
    if not mark or os.path.exists(file):
        return load_file(file)
    root = load_file(path)
    entries = root.get("subsystems") if isinstance(root, YMap) else None
    node = entries.get(key) if isinstance(entries, YMap) else None
    if not isinstance(node, YMap):
        raise ConfigError(f"no inline subsystem '{key}' under subsystems: in {path}", path, 1, 1,
                          "write it as a mapping: subsystems: {name: {subsystem: name, rtpus: [...], ...}}")
    if PLACEMENT_KEY in node:  # the host it runs on is the application's to read, not a key of the subsystem
        placed = node
        node = YMap(placed.loc)
        for k, v in placed.items():
            if k != PLACEMENT_KEY:
                node.put(k, v, placed.key_loc(k), placed.value_loc(k))
    return node


def _merge_into(target: YMap, source: YMap, errors: list[ConfigError]) -> None:
    for key, value in source.items():
        if key == "include" and key in target:
            continue  # each file's include list was followed already
        if key not in target:
            target.put(key, value, source.key_loc(key), source.value_loc(key))
            continue
        existing = target[key]
        if key in _MERGED_SECTIONS and isinstance(existing, YMap) and isinstance(value, YMap):
            combined = YMap(existing.loc)
            for k, v in existing.items():
                combined.put(k, v, existing.key_loc(k), existing.value_loc(k))
            for k, v in value.items():
                if k in combined:
                    first = combined.key_loc(k)
                    errors.append(
                        _error(
                            f"'{k}' in '{key}' is defined twice: here and at {first}",
                            value.key_loc(k),
                            "an included file and the including file must not define the same name",
                        )
                    )
                    continue
                combined.put(k, v, value.key_loc(k), value.value_loc(k))
            target.put(key, combined, target.key_loc(key), target.value_loc(key))
        else:
            first = target.key_loc(key)
            errors.append(_error(f"'{key}' is given twice: here and at {first}", source.key_loc(key), "set it in one file only"))


def _error(message: str, loc: Location, hint: str = "") -> ConfigError:
    return ConfigError(message, loc.file, loc.line, loc.column, hint)
