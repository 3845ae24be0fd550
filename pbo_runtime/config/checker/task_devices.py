"""The devices a task's module opens by a param (its DEVICES): among the task's resources, of the
kind the module needs, with the driver options it needs.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from pbo_runtime.config.checker.base import CheckerBase
from pbo_runtime.config.checker.model import _Task
from pbo_runtime.config.checker.words import did_you_mean
from pbo_runtime.config.yaml_nodes import YList, YMap


class TaskDeviceChecks(CheckerBase):
    """Rules for the devices a task's module opens (E608-E611)."""

    if TYPE_CHECKING:  # rules of other mixins this one calls; the whole checker has them
        def driver_class(self, driver: str) -> Any: ...
        def drivers_of_kind(self, kind: str) -> str: ...
        def plant_lacks(self, device: str) -> tuple[str, str] | None: ...

    def check_task_devices(self, task: _Task, spec: YMap, module_class: Any) -> bool:
        """The devices a module opens by a param (its DEVICES): among the task's resources (E608), with
        the driver options the module needs (E609). What `pbo run` would refuse in init or in on."""
        uses = getattr(module_class, "DEVICES", None)
        listed = spec.get("resources")
        if not isinstance(uses, Mapping) or not uses or task.built_params is None:
            return True
        if isinstance(listed, YList) and len(listed) != len(task.resources):
            return True  # a resource is wrong, and was reported there: which ones it meant is unknown
        resources = [device for device, _ in task.resources]
        params = spec.get("params") if isinstance(spec.get("params"), YMap) else None
        ok = True
        for field, needs in uses.items():
            device = getattr(task.built_params, str(field), None)
            if not isinstance(device, str) or not device:
                continue  # no device named: the module opens none
            given = params is not None and field in params
            if device not in resources:
                ok = False
                declared = device in self.device_names
                listing = ", ".join(resources) if resources else "none"
                what = f"opens device '{device}' (params: {field}" + ("" if given else ", by default") + ")"
                notes = []
                if "resources" in spec:
                    notes.append((spec.value_loc("resources"), f"the resources of task '{task.name}': {listing}"))
                if given:
                    assert params is not None
                    hint = (did_you_mean(device, resources, "resources") if resources else "the task has no resources")
                    hint += f"; or add '{device}' to resources:" if declared else f"; 'devices' does not declare '{device}'"
                    self.error("E608", f"task '{task.name}' (module '{task.module}') {what}, which is not among its resources",
                               params.value_loc(field), hint, notes)
                else:
                    where = spec.value_loc("resources") if "resources" in spec else task.loc
                    fix = (
                        f"add '{device}' to resources:"
                        if declared
                        else f"declare device '{device}' under devices: and add it to resources:"
                    )
                    if resources:
                        fix += f", or name one of its resources with params: {{{field}: {resources[0]}}}"
                    self.error(
                        "E608",
                        f"task '{task.name}' (module '{task.module}') {what}, which is not among its resources ({listing})",
                        where,
                        fix,
                        notes,
                    )
                continue
            ok = self.check_device_options(task, spec, device, needs, str(field)) and ok
        return ok

    def check_device_options(self, task: _Task, spec: YMap, device: str, needs: Any, field: str = "device") -> bool:
        """E610: the device is of the kind the module needs (its driver's KIND); E609: it has every
        driver option the module needs (its value, or the driver's default)."""
        device_spec = self.out.devices.get(device)
        cls = self.driver_class(device_spec.driver) if device_spec is not None else None
        if device_spec is None or cls is None or not isinstance(needs, Mapping):
            return True  # the device or its driver is wrong or unknown: reported there, or checked when opened
        wanted_kind = needs.get("kind")
        kind = getattr(cls, "KIND", "")
        if wanted_kind is not None and kind != wanted_kind:
            params = spec.get("params")
            where = params.value_loc(field) if isinstance(params, YMap) and field in params else spec.value_loc("module")
            found = f"a device of kind {kind}" if kind else "a device of no declared kind"
            self.error("E610", f"task '{task.name}' (module '{task.module}') opens device '{device}', {found} (driver "
                               f"{device_spec.driver}), but the module needs a device of kind {wanted_kind}",
                       where, f"name a device whose driver is of kind {wanted_kind} ({self.drivers_of_kind(wanted_kind)})",
                       [(device_spec.loc, f"device '{device}' has driver {device_spec.driver}")])
            return False
        lacks = self.plant_lacks(device)
        if lacks is not None:
            params = spec.get("params")
            where = params.value_loc(field) if isinstance(params, YMap) and field in params else spec.value_loc("module")
            self.error("E611", f"task '{task.name}' (module '{task.module}') opens {lacks[0]}", where, lacks[1],
                       [(device_spec.loc, f"device '{device}' has driver {device_spec.driver}")])
            return False
        defaults = getattr(cls, "OPTION_DEFAULTS", {}) or {}
        node = self.device_nodes.get(device)
        for option, wanted in needs.items():
            if option == "kind":
                continue
            if option in device_spec.options:
                has, where, how = (
                    device_spec.options[option],
                    (node.value_loc(option) if node is not None else device_spec.loc),
                    "",
                )
            elif option in defaults:
                has, where, how = defaults[option], device_spec.loc, f" (driver {device_spec.driver}'s default)"
            else:
                continue  # a driver without the option: it cannot be checked here
            if has == wanted:
                continue
            self.error(
                "E609",
                f"task '{task.name}' (module '{task.module}') needs device '{device}' with {option}: {wanted}, "
                f"but the device has {option}: {has}{how}",
                spec.value_loc("module"),
                f"choose a module for a device with {option}: {has}, or give device '{device}' {option}: {wanted} "
                f"(if no other task needs it as it is)",
                [(where, f"device '{device}' has {option}: {has}{how}")],
            )
            return False
        return True
