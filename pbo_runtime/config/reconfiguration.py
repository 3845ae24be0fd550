"""What each executive needs to apply a switch by itself: per configuration, who runs and who writes.

Built once from the checked `Subsystem` in every process, so a plan in the table's header needs
to carry only a configuration's index and an activation time.
"""

from __future__ import annotations

import math
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
        self.views: list[ConfigurationView] = []
        for index, (name, configuration) in enumerate(subsystem.configurations.items()):
            writers: dict[str, tuple[int, float]] = {}
            for task_name in configuration.tasks:
                task = subsystem.tasks[task_name]
                for binding in task.bindings:
                    if not binding.port.kind.is_input and binding.port.kind.every_cycle:
                        writers[binding.variable] = (task.index, task.period)
            self.views.append(ConfigurationView(index, name, frozenset(configuration.tasks), writers))
        self.by_name = {view.name: view for view in self.views}
        self.task_names = {task.index: task.name for task in subsystem.tasks.values()}

    def index(self, name: str) -> int:
        return self.by_name[name].index

    def writer_of(self, configuration: int, variable: str) -> tuple[int, float]:
        return self.views[configuration].writers.get(variable, (-1, math.inf))
