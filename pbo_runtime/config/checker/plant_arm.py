"""The plant's robot as the joint loops' check reads it (its ARM, EE, start pose and joint names),
kept on disk (`result_cache`) for a registered robot, so a later `pbo check` loads no simulator.

The plant describes the robot as it would load it (`describe_robot`, which for the MuJoCo plant
compiles a model); what it answers depends on the robot's registered description, the plant's
options, the plant's own code (every source file of its top-level package) and the libraries it
declares (`DESCRIBED_WITH`): the entry is named by all of them. A robot file is described anew
each time (its meshes and includes are files the key does not follow).
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pbo_runtime.objects import registry, result_cache
from pbo_runtime.objects.arm import is_robot_file


@dataclass(frozen=True)
class PlantArm:
    """What the joint loops' check reads of the plant's robot."""

    arm: np.ndarray
    ee: np.ndarray
    q0: np.ndarray
    joint_names: tuple[str, ...]


def describe_plant_arm(plant_type: str, model: str, base_dir: Path, options: dict[str, Any]) -> PlantArm:
    """The robot a plant of `plant_type` would load for `model` and its robot `options`; whatever the
    plant's `describe_robot` raises when it cannot."""
    plant = registry.plant_class(plant_type)
    key = _entry_name(plant, plant_type, model, options)
    if key is None:
        return _plant_arm(plant.describe_robot(model, str(base_dir), options))
    kept = result_cache.cached_arrays(key, lambda: _arrays(_plant_arm(plant.describe_robot(model, str(base_dir), options))))
    return PlantArm(kept["arm"], kept["ee"], kept["q0"], tuple(str(name) for name in kept["joint_names"]))


def _plant_arm(robot: Any) -> PlantArm:
    return PlantArm(np.asarray(robot.arm, dtype=np.float64), np.asarray(robot.ee, dtype=np.float64),
                    np.asarray(robot.q0, dtype=np.float64), tuple(str(name) for name in robot.joint_names))


def _arrays(found: PlantArm) -> dict[str, np.ndarray]:
    return {"arm": found.arm, "ee": found.ee, "q0": found.q0, "joint_names": np.array(found.joint_names, dtype=str)}


def _entry_name(plant: type, plant_type: str, model: str, options: dict[str, Any]) -> str | None:
    """The cache entry's name, or None when the answer may depend on what the name cannot follow (a
    robot file, a robot that is not a plain description, a plant whose code is not in files)."""
    if is_robot_file(model):
        return None
    try:
        description = registry.registered_robot(model)
    except Exception:
        return None
    if not dataclasses.is_dataclass(description) or isinstance(description, type):
        return None
    parts: list[bytes | str] = ["plant arm", plant_type, model, repr(sorted(options.items()))]
    for field in dataclasses.fields(description):
        value = getattr(description, field.name)
        parts.append(field.name)
        if isinstance(value, np.ndarray):
            parts.append(value.tobytes() + repr((value.dtype.str, value.shape)).encode())
        else:
            parts.append(repr(value))
    sources = _package_sources(plant)
    if not sources:
        return None
    libraries = tuple(getattr(plant, "DESCRIBED_WITH", ()))
    return result_cache.fingerprint(*parts, sources=sources, libraries=libraries)


def _package_sources(plant: type) -> tuple[str, ...]:
    """Every .py file of the top-level package the plant class is defined in, sorted."""
    module = sys.modules.get(plant.__module__)
    top = sys.modules.get(plant.__module__.partition(".")[0])
    folder = getattr(top, "__path__", None)
    if module is None or not folder:
        return ()
    return tuple(str(path) for root in folder for path in sorted(Path(root).rglob("*.py")))
