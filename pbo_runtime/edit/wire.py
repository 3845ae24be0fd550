"""What an RTPU reads of a run's live description: the plain data `edit.live.to_wire` writes, made
into task specs again (`from_wire`, `task_from_wire`).

Apart from `edit.live` so an RTPU process (and the fork server it is forked from) has it without
importing the checker, the loader and the YAML parser, which only the supervisor's side of a
live change runs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from pbo_runtime.config.model import NOWHERE, ConfigurationSpec, PortBinding, Subsystem, TaskSpec
from pbo_runtime.objects import registry


def from_wire(base: Subsystem, data: Mapping[str, Any], module_lookup: Callable[[str], Any] = registry.module_class) -> Subsystem:
    """The live subsystem `to_wire` describes, on the file's `base` (its variables, devices, RTPUs)."""
    tasks = {name: task_from_wire(base, name, t, module_lookup) for name, t in data["tasks"].items()}
    configurations = {name: ConfigurationSpec(name, tuple(members), base.configurations[name].loc
                                              if name in base.configurations else NOWHERE)
                      for name, members in data["configurations"].items()}
    return dataclasses.replace(base, tasks=tasks, configurations=configurations, init_order=tuple(data["init_order"]))


def task_from_wire(base: Subsystem, name: str, t: Mapping[str, Any],
                   module_lookup: Callable[[str], Any] = registry.module_class) -> TaskSpec:
    """One task's spec from `to_wire`'s data (its module is looked up: do it only for a task to host)."""
    module_class = module_lookup(t["module"])
    ports = {port.name: port for port in module_class.ports_for(module_class.build_params(dict(t["params"])))}
    bindings = tuple(PortBinding(ports[port], variable, tuple(shape)) for port, variable, shape in t["bindings"])
    known = base.tasks.get(name)
    return TaskSpec(name, t["module"], t["rtpu"], float(t["period"]), int(t["priority"]), bool(t["critical"]),
                    dict(t["params"]), bindings, tuple(t["resources"]), int(t["index"]),
                    known.loc if known is not None else NOWHERE, t["wcet"], bool(t["aperiodic"]),
                    t["min_interarrival"], {d: tuple(c) for d, c in t["resource_channels"].items()},
                    dict(t["fresh_within"]))
