"""What the HMI's monitor needs of a subsystem file: its tasks with the parameters tunable live, its variables.

The status reply of a run names tasks, RTPUs and states, not modules nor parameters; the monitor
offers `pbo set TASK PARAM VALUE` for the parameters a task's module declares tunable (its
`TUNABLE`, taken by its `tune` component), with the value the file gives (or the module's
default), and lists the state variables with their shapes so a plot can pick elements of them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from pbo_runtime.config.model import Subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.objects import registry


def plain(value: Any) -> Any:
    """A parameter's value as JSON-able data (arrays and tuples as lists)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def tunables(module: str, params: dict[str, Any]) -> dict[str, Any]:
    """The module's live-tunable parameters and their values: the file's, else the module's default."""
    try:
        cls = registry.module_class(module)
    except PboError:
        return {}
    defaults = {}
    if dataclasses.is_dataclass(getattr(cls, "Params", None)):
        defaults = {f.name: f.default for f in dataclasses.fields(cls.Params) if f.default is not dataclasses.MISSING}
    return {name: plain(params.get(name, defaults.get(name))) for name in getattr(cls, "TUNABLE", ())}


def played_devices(subsystem: Subsystem) -> dict[str, list[dict[str, Any]]]:
    """The devices the operator plays (`pbo play`), each with its controls: the driver's
    `operator_controls(options)` (name, unit, min, max), for those whose options make it played."""
    played = {}
    for name, device in subsystem.devices.items():
        try:
            controls = getattr(registry.driver_class(device.driver), "operator_controls", None)
        except PboError:
            continue
        found = controls(dict(device.options)) if callable(controls) else None
        if found:
            played[name] = found
    return played


def monitor_layout(subsystem: Subsystem) -> dict[str, Any]:
    """{"subsystem", "plant", "configurations": {name: [task]}, "tasks": {task: {module, rtpu, period, critical,
    tunable: {param: value}}}, "variables": {name: {dtype, shape, doc}}, "played": {device: [control]}}, in file order."""
    return {
        "played": played_devices(subsystem),
        "subsystem": subsystem.name,
        "plant": subsystem.plant.model if subsystem.plant is not None else None,
        "configurations": {name: list(c.tasks) for name, c in subsystem.configurations.items()},
        "tasks": {name: {"module": t.module, "rtpu": t.rtpu, "period": t.period, "critical": t.critical,
                         "tunable": tunables(t.module, dict(t.params))} for name, t in subsystem.tasks.items()},
        "variables": {name: {"dtype": v.dtype, "shape": list(v.shape), "doc": v.doc} for name, v in subsystem.variables.items()},
    }
