"""Application files: several subsystems run in parallel, joined by links (TR §5, DESIGN §9).

    application: two_arms
    subsystems:                     # name -> its subsystem file, relative to this file
      leader: leader.yaml
      follower: follower.yaml
    links:                          # periodic links (triple buffers), by name
      arm_state: {type: float64, shape: [6], transport: shm}     # transport: shm | zenoh

A link's ends are tasks of the subsystems: one `link_sender` (params: {link: arm_state}) in one
subsystem, one `link_receiver` in another, each with its port `value` linked to a variable of
the link's type and shape. `check_application` checks the file like `pbo check` checks a
subsystem: every subsystem file in full, then the links against the tasks, every mistake with
file:line:col, a code (E8xx, docs/error-codes.md) and a hint.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbo_runtime._config_loader import CheckResult, check_file
from pbo_runtime._config_model import NOWHERE, Location, Subsystem
from pbo_runtime._errors import ConfigError
from pbo_runtime._links import TRANSPORTS
from pbo_runtime._yaml_nodes import YList, YMap, load_file, location_of

SENDER, RECEIVER = "link_sender", "link_receiver"
_TOP_KEYS = ("application", "subsystems", "links")
_LINK_KEYS = ("type", "shape", "transport")


@dataclass(frozen=True)
class LinkSpec:
    name: str
    dtype: str
    shape: tuple[int, ...]
    transport: str = "shm"
    sender: tuple[str, str] = ("", "")  # (subsystem, task)
    receiver: tuple[str, str] = ("", "")
    loc: Location = NOWHERE


@dataclass
class Application:
    name: str
    file: str
    subsystems: dict[str, Subsystem] = field(default_factory=dict)  # by the application's name for it
    links: dict[str, LinkSpec] = field(default_factory=dict)


@dataclass
class ApplicationCheck:
    application: Application | None
    errors: list[ConfigError] = field(default_factory=list)
    warnings: list[ConfigError] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors


def is_application_file(path: str | os.PathLike[str]) -> bool:
    """True if the file's first top-level key is `application:` (a subsystem file starts otherwise)."""
    try:
        with open(path, encoding="utf-8") as text:
            for line in text:
                stripped = line.strip()
                if stripped and not stripped.startswith("#") and not line[0].isspace():
                    return stripped.startswith("application:")
    except OSError:
        return False
    return False


def check_application(path: str | os.PathLike[str]) -> ApplicationCheck:
    """Every problem of an application file and of its subsystems' files; never raises on bad input."""
    file = str(path)
    result = ApplicationCheck(None)
    try:
        root = load_file(file)
    except ConfigError as exc:
        result.errors.append(exc)
        return result

    def error(code: str, message: str, loc: Location, hint: str = "") -> None:
        result.errors.append(ConfigError(message, loc.file, loc.line, loc.column, hint, code=code))

    if not isinstance(root, YMap):
        error("E801", "an application file must be a mapping with application, subsystems and links",
              location_of(root, Location(file, 1, 1)))
        return result
    for key in root:
        if key not in _TOP_KEYS:
            error("E801", f"unknown key '{key}' in an application file", root.key_loc(key),
                  f"an application file has: {', '.join(_TOP_KEYS)}")
    name = root.get("application")
    if not isinstance(name, str) or not name:
        error("E801", "application must be a name", root.value_loc("application") if "application" in root else root.loc,
              "e.g. application: two_arms")
        name = "application"
    application = Application(name, file)
    _check_subsystems(root, Path(file).parent, application, result, error)
    _check_links(root, application, error)
    if not result.errors:
        _check_link_ends(application, error)
    if not result.errors:
        result.application = application
    return result


def _check_subsystems(root: YMap, folder: Path, application: Application, result: ApplicationCheck, error) -> None:
    entries = root.get("subsystems")
    if not isinstance(entries, YMap) or not entries:
        error("E801", "subsystems must map each subsystem's name to its file",
              root.value_loc("subsystems") if "subsystems" in root else root.loc, "e.g. subsystems: {leader: leader.yaml}")
        return
    names: dict[str, str] = {}
    for key, value in entries.items():
        loc = entries.value_loc(key)
        if not isinstance(value, str):
            error("E802", f"subsystem '{key}' must be the path of its subsystem file", loc,
                  "inline subsystems are not supported yet: put it in its own file and name it here")
            continue
        path = folder / value
        if not path.is_file():
            error("E802", f"subsystem '{key}': no file '{value}' (looked for {path})", loc,
                  "paths are relative to the application file")
            continue
        checked: CheckResult = check_file(path)
        result.errors.extend(checked.errors)
        result.warnings.extend(checked.warnings)
        if checked.subsystem is None:
            if not checked.errors:
                error("E802", f"subsystem '{key}': '{value}' could not be loaded", loc)
            continue
        own = checked.subsystem.name
        if own in names:
            error("E802", f"subsystems '{names[own]}' and '{key}' are both named '{own}' in their files", loc,
                  "each subsystem's `subsystem:` name must be unique: it names its shared memory")
            continue
        names[own] = key
        application.subsystems[key] = checked.subsystem


def _check_links(root: YMap, application: Application, error) -> None:
    entries = root.get("links", YMap(root.loc))
    if not isinstance(entries, YMap):
        error("E803", "links must map each link's name to its type, shape and transport", location_of(entries, root.loc))
        return
    for name, spec in entries.items():
        loc = entries.key_loc(name)
        if not isinstance(spec, YMap):
            error("E803", f"link '{name}' must be a mapping", entries.value_loc(name), "e.g. {type: float64, shape: [6]}")
            continue
        for key in spec:
            if key not in _LINK_KEYS:
                error("E803", f"link '{name}': unknown key '{key}'", spec.key_loc(key), f"a link has: {', '.join(_LINK_KEYS)}")
        dtype = spec.get("type", "float64")
        try:
            np.dtype(dtype)
        except TypeError:
            error("E803", f"link '{name}': type '{dtype}' is not a numpy dtype", spec.value_loc("type"), "e.g. float64, int32")
            continue
        shape = spec.get("shape", YList(loc))
        if not isinstance(shape, list) or not all(isinstance(n, int) and n > 0 for n in shape):
            error("E803", f"link '{name}': shape must be a list of positive integers, got {shape!r}",
                  spec.value_loc("shape") if "shape" in spec else loc, "e.g. shape: [6]")
            continue
        transport = spec.get("transport", "shm")
        if transport not in TRANSPORTS:
            error("E803", f"link '{name}': unknown transport '{transport}'", spec.value_loc("transport"),
                  f"transports: {', '.join(TRANSPORTS)}")
            continue
        application.links[name] = LinkSpec(name, str(np.dtype(dtype)), tuple(shape), transport, loc=loc)


def _check_link_ends(application: Application, error) -> None:
    """Each link: exactly one sender and one receiver, in different subsystems, ports of its payload."""
    ends: dict[str, dict[str, list[tuple[str, str, Location]]]] = {n: {SENDER: [], RECEIVER: []} for n in application.links}
    for key, subsystem in application.subsystems.items():
        for task in subsystem.tasks.values():
            if task.module not in (SENDER, RECEIVER):
                continue
            link = task.params.get("link")
            if link not in application.links:
                error("E804", f"task '{task.name}' of subsystem '{key}' uses link '{link}', which the application does not declare",
                      task.loc, f"links: {', '.join(application.links) or 'none'}; declare it under links:")
                continue
            spec = application.links[link]
            binding = next(b for b in task.bindings if b.port.name == "value")
            variable = subsystem.variables[binding.variable]
            if (np.dtype(variable.dtype), tuple(variable.shape)) != (np.dtype(spec.dtype), spec.shape):
                error("E806", f"task '{task.name}' of subsystem '{key}' links variable '{variable.name}' "
                              f"({variable.dtype} {list(variable.shape)}) to link '{link}', which carries "
                              f"{spec.dtype} {list(spec.shape)}", task.loc,
                      "the variable and the link must have the same type and shape")
                continue
            ends[link][task.module].append((key, task.name, task.loc))
    for name, spec in application.links.items():
        senders, receivers = ends[name][SENDER], ends[name][RECEIVER]
        for role, found in ((SENDER, senders), (RECEIVER, receivers)):
            if not found:
                error("E805", f"link '{name}' has no {role} task", spec.loc,
                      f"add a task with module: {role}, params: {{link: {name}}} to one subsystem")
            for extra in found[1:]:
                error("E805", f"link '{name}' has a second {role}: task '{extra[1]}' of subsystem '{extra[0]}' "
                              f"(the first is '{found[0][1]}' of '{found[0][0]}')", extra[2],
                      "a link joins one sender and one receiver")
        if senders and receivers and senders[0][0] == receivers[0][0]:
            error("E805", f"link '{name}' joins two tasks of the same subsystem '{senders[0][0]}'", spec.loc,
                  "within a subsystem, tasks share state variables: use a variable, not a link")
        if senders and receivers:
            application.links[name] = LinkSpec(name, spec.dtype, spec.shape, spec.transport,
                                               senders[0][:2], receivers[0][:2], spec.loc)
