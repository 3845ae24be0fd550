"""Robot descriptions the simulated plant can build, by name, and their MuJoCo models."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.robots.description import DH_COLUMNS, DYN_COLUMNS, RobotDescription
from drivers.robots.puma560 import puma560
from drivers.robots.redundant7 import redundant7

_ROBOTS: dict[str, Callable[[], RobotDescription]] = {
    "puma560": puma560,
    "redundant7": redundant7,
}


def robot_names() -> tuple[str, ...]:
    return tuple(sorted(_ROBOTS))


def robot(name: str) -> RobotDescription:
    """The description registered as `name`; the error lists the known names."""
    try:
        make = _ROBOTS[name]
    except KeyError:
        raise ValueError(f"unknown robot model {name!r}; known models: {', '.join(robot_names())}") from None
    return make()


def __getattr__(name: str) -> Any:
    """`to_mjcf` imports MuJoCo, which takes a second: only the plant needs it, never `pbo check`
    (which reads a description's dims through the entry-point group pbo.robots)."""
    if name == "to_mjcf":
        from drivers.robots.mjcf import to_mjcf

        return to_mjcf
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DH_COLUMNS", "DYN_COLUMNS", "RobotDescription", "robot", "robot_names", "to_mjcf"]
