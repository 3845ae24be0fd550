"""A module's own check of what its task links and opens (`PortBasedObject.check_links`): what its
`init` would refuse that the file already shows (a frame the arm has not, a variable of more
elements than the channels it reads), reported at check time as E323.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pbo_runtime.config.checker.base import CheckerBase, named_by
from pbo_runtime.config.checker.model import _Task
from pbo_runtime.config.model import Location
from pbo_runtime.config.yaml_nodes import YMap


class ModuleLinkChecks(CheckerBase):
    """E323: a module refuses its task's links, dims or channels."""

    if TYPE_CHECKING:  # the DeviceChecks rule this one calls; the whole checker has it
        def ports_of(self, device: str) -> int | None: ...

    def check_module_links(self, task: _Task, spec: YMap, module_class: Any) -> bool:
        check = getattr(module_class, "check_links", None)
        if check is None or task.built_params is None:
            return True
        shapes = {b.port.name: b.shape for b in task.bindings}
        channels: dict[str, int] = {}
        for device, _ in task.resources:
            count = len(task.channels[device]) if device in task.channels else self.ports_of(device)
            if count:
                channels[device] = count
        try:
            options = {
                device: dict(self.out.devices[device].options) for device, _ in task.resources if device in self.out.devices
            }
            check(task.built_params, shapes, dict(self.out.dims), channels, options)
        except (ValueError, TypeError) as exc:
            params = spec.get("params")
            where: Location | None
            if "resources" in spec and "channel" in str(exc):  # the fix is in the channels it opens, or the variable
                where = spec.value_loc("resources")
            else:
                where = named_by(params, str(exc)) if isinstance(params, YMap) else None
            self.error("E323", f"task '{task.name}' (module '{task.module}'): {exc}", where or task.loc,
                       f"what module '{task.module}' would refuse in its init (pbo lexicon {task.module})")
            return False
        return True

