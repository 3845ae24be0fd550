"""The library registry: modules, drivers, plants and robots by name, through entry points.

A YAML file names a module (`module: pid_joint`); it resolves only through the entry-point
groups `pbo.modules`, `pbo.drivers`, `pbo.plants` and `pbo.robots` (a function that returns a
robot's description, whose `dims` the checker reads), never to arbitrary importable code.
Third-party libraries register in the same groups.
"""

from __future__ import annotations

import functools
from typing import Any

from pbo_runtime.errors import ModuleError
from pbo_runtime.objects import distributions
from pbo_runtime.objects.version import installed_version as installed_version  # looked up here too

MODULES = "pbo.modules"
DRIVERS = "pbo.drivers"
PLANTS = "pbo.plants"
ROBOTS = "pbo.robots"

_KIND = {MODULES: "module", DRIVERS: "driver", PLANTS: "plant", ROBOTS: "robot model"}


@functools.cache
def _registered(group: str) -> dict[str, distributions.EntryPoint]:
    """A group's entry points by name (the first of a name), read once: reading them opens every
    installed distribution's metadata, milliseconds that a task spawned live would spend between
    two cycles of its RTPU for each module not looked up before."""
    found: dict[str, distributions.EntryPoint] = {}
    for ep in distributions.entry_points(group):
        found.setdefault(ep.name, ep)
    return found


def names(group: str) -> tuple[str, ...]:
    """Every name registered in a group, sorted."""
    return tuple(sorted(_registered(group)))


@functools.cache
def load(group: str, name: str) -> Any:
    """The object registered under `name`, or ModuleError listing the valid names."""
    found = _registered(group).get(name)
    if found is None:
        raise ModuleError(f"no {_KIND.get(group, group)} named '{name}' (registered: {', '.join(names(group)) or 'none'})")
    try:
        return found.load()
    except Exception as exc:  # a broken library must not look like a typo in the YAML
        raise ModuleError(f"{_KIND.get(group, group)} '{name}' is registered but failed to import: {exc!r}") from exc


def module_class(name: str) -> Any:
    return load(MODULES, name)


def driver_class(name: str) -> Any:
    return load(DRIVERS, name)


def plant_class(name: str) -> Any:
    return load(PLANTS, name)


def registered_robot(name: str) -> Any:
    """What the `pbo.robots` entry point `name` makes: a robot description, or the path of a robot file."""
    return load(ROBOTS, name)()


def robot_dims(model: str) -> dict[str, int]:
    """The dims a robot model gives (e.g. {"NDOF": 6} for puma560); ModuleError for an unknown model."""
    return dict(registered_robot(model).dims)


def import_library() -> list[str]:
    """Import every registered module and driver now; the names that failed (each says why when used).

    An RTPU does this before its first task turns on: a task spawned live later (`pbo spawn`,
    `pbo replace`) then finds its module imported, instead of importing (and compiling) it between
    two cycles of the tasks already running there."""
    failed = []
    for group in (MODULES, DRIVERS):
        for name in names(group):
            try:
                load(group, name)
            except ModuleError:
                failed.append(name)
    return failed
