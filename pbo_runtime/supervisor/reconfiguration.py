"""What each executive needs to apply a switch by itself: per configuration, who runs and who writes.

Built once from the checked `Subsystem` in every process, so a plan in the table's header needs
to carry only a configuration's index and an activation time.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from pbo_runtime.config.model import Subsystem


@dataclass(frozen=True)
class ConfigurationView:
    index: int
    name: str
    members: frozenset[str]
    writers: dict[str, tuple[int, float]]  # variable -> (writer task index, its period); job control: (-1, inf)


class Reconfiguration:
    """The configurations of a subsystem, by index (file order), as executives use them."""

    def __init__(self, subsystem: Subsystem) -> None:
        writes = {name: (task.index, task.period, [b.variable for b in task.bindings
                                                   if not b.port.kind.is_input and b.port.kind.every_cycle])
                  for name, task in subsystem.tasks.items()}
        self._build({name: c.tasks for name, c in subsystem.configurations.items()}, writes)

    @classmethod
    def of_members(cls, configurations: Mapping[str, Iterable[str]],
                   writes: Mapping[str, tuple[int, float, list[str]]]) -> Reconfiguration:
        """From plain data: members per configuration, and per task (index, period, variables it writes
        every cycle). What an RTPU builds from a live description without looking up any module."""
        self = cls.__new__(cls)
        self._build(configurations, writes)
        return self

    def _build(self, configurations: Mapping[str, Iterable[str]], writes: Mapping[str, tuple[int, float, list[str]]]) -> None:
        self.views: list[ConfigurationView] = []
        for index, (name, members) in enumerate(configurations.items()):
            members = tuple(members)
            writers: dict[str, tuple[int, float]] = {}
            for task_name in members:
                task_index, period, variables = writes[task_name]
                for variable in variables:
                    writers[variable] = (task_index, period)
            self.views.append(ConfigurationView(index, name, frozenset(members), writers))
        self.by_name = {view.name: view for view in self.views}
        self.task_names = {task_index: name for name, (task_index, _, _) in writes.items()}

    def index(self, name: str) -> int:
        return self.by_name[name].index

    def writer_of(self, configuration: int, variable: str) -> tuple[int, float]:
        return self.views[configuration].writers.get(variable, (-1, math.inf))
