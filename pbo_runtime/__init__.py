"""pbo-runtime: dynamically reconfigurable real-time control from port-based objects.

The names module, driver and plant authors import; everything else lives in the wings
(objects/, config/, table/, task/, ...) and may change without notice.
"""

from __future__ import annotations

import importlib

TYPE_CHECKING = False  # typing's, without importing typing: `pbo --version` imports only what it needs

# name -> the wing that defines it: imported when first used (`pbo --version` and `pbo --help` load no
# numpy), as `from pbo_runtime import PortBasedObject` always did.
_WHERE = {
    "ANY_DTYPE": "pbo_runtime.objects.ports",
    "ARM_COLUMNS": "pbo_runtime.objects.arm",
    "Arm": "pbo_runtime.objects.arm",
    "ConfigError": "pbo_runtime.errors",
    "ConfigErrors": "pbo_runtime.errors",
    "DdsProcess": "pbo_runtime.links.dds_process",
    "DeviceDriver": "pbo_runtime.objects.driver",
    "EE_COLUMNS": "pbo_runtime.objects.arm",
    "GRAVITY": "pbo_runtime.objects.arm",
    "InBoth": "pbo_runtime.objects.ports",
    "InConst": "pbo_runtime.objects.ports",
    "InVar": "pbo_runtime.objects.ports",
    "InternalError": "pbo_runtime.errors",
    "LifecycleError": "pbo_runtime.errors",
    "LinkFullError": "pbo_runtime.links.message_link",
    "MAX_PRIORITY": "pbo_runtime.links.message_link",
    "ModuleError": "pbo_runtime.errors",
    "NoParams": "pbo_runtime.objects.module",
    "OperatorInput": "pbo_runtime.ipc.operator_input",
    "OutBoth": "pbo_runtime.objects.ports",
    "OutConst": "pbo_runtime.objects.ports",
    "OutVar": "pbo_runtime.objects.ports",
    "OutputError": "pbo_runtime.errors",
    "ParamError": "pbo_runtime.errors",
    "PboError": "pbo_runtime.errors",
    "PortBasedObject": "pbo_runtime.objects.module",
    "PortKind": "pbo_runtime.objects.ports",
    "PortSpec": "pbo_runtime.objects.ports",
    "ROBOT_OPTIONS": "pbo_runtime.objects.arm",
    "ROBOT_SUFFIXES": "pbo_runtime.objects.arm",
    "ResourceLimitError": "pbo_runtime.errors",
    "Status": "pbo_runtime.objects.module",
    "TableLayoutError": "pbo_runtime.errors",
    "Waypoints": "pbo_runtime.objects.waypoints",
    "arm_gains": "pbo_runtime.objects.arm_inertia",
    "arm_model": "pbo_runtime.objects.arm",
    "attach_segment": "pbo_runtime.ipc.shm",
    "below_the_cycle": "pbo_runtime.objects.helper_threads",
    "process_below_the_cycle": "pbo_runtime.objects.helper_threads",
    "create_segment": "pbo_runtime.ipc.shm",
    "format_channels": "pbo_runtime.config.channels",
    "inertia_range": "pbo_runtime.objects.arm_inertia",
    "is_robot_file": "pbo_runtime.objects.arm",
    "module_class": "pbo_runtime.objects.registry",
    "open_log": "pbo_runtime.reports.data_log",
    "param": "pbo_runtime.objects.ranges",
    "read_log": "pbo_runtime.reports.data_log",
    "registered_robot": "pbo_runtime.objects.registry",
    "require_extra": "pbo_runtime.errors",
    "ros2_messages": "pbo_runtime.links.ros2",
    "serve_dds_process": "pbo_runtime.links.dds_process",
    "sleep_while_cycling": "pbo_runtime.objects.waits",
    "unlink_quietly": "pbo_runtime.ipc.shm",
}

if TYPE_CHECKING:  # what the type checkers and editors see: the same names, eagerly
    from typing import Any

    from pbo_runtime.config.channels import format_channels
    from pbo_runtime.errors import (
        ConfigError,
        ConfigErrors,
        InternalError,
        LifecycleError,
        ModuleError,
        OutputError,
        ParamError,
        PboError,
        ResourceLimitError,
        TableLayoutError,
        require_extra,
    )
    from pbo_runtime.ipc.operator_input import OperatorInput
    from pbo_runtime.ipc.shm import attach_segment, create_segment, unlink_quietly
    from pbo_runtime.links.dds_process import DdsProcess, serve_dds_process
    from pbo_runtime.links.message_link import MAX_PRIORITY, LinkFullError
    from pbo_runtime.links.ros2 import ros2_messages
    from pbo_runtime.objects.arm import (
        ARM_COLUMNS,
        EE_COLUMNS,
        GRAVITY,
        ROBOT_OPTIONS,
        ROBOT_SUFFIXES,
        Arm,
        arm_model,
        is_robot_file,
    )
    from pbo_runtime.objects.arm_inertia import arm_gains, inertia_range
    from pbo_runtime.objects.driver import DeviceDriver
    from pbo_runtime.objects.helper_threads import below_the_cycle, process_below_the_cycle
    from pbo_runtime.objects.module import NoParams, PortBasedObject, Status
    from pbo_runtime.objects.ports import ANY_DTYPE, InBoth, InConst, InVar, OutBoth, OutConst, OutVar, PortKind, PortSpec
    from pbo_runtime.objects.ranges import param
    from pbo_runtime.objects.registry import module_class, registered_robot
    from pbo_runtime.objects.waits import sleep_while_cycling
    from pbo_runtime.objects.waypoints import Waypoints
    from pbo_runtime.reports.data_log import open_log, read_log


def __getattr__(name: str) -> Any:
    if name == "__version__":
        from pbo_runtime.objects.registry import installed_version

        value: Any = installed_version()
    elif name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
    else:
        raise AttributeError(f"module 'pbo_runtime' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE, "__version__"])


__all__ = [
    "ANY_DTYPE",
    "ARM_COLUMNS",
    "EE_COLUMNS",
    "GRAVITY",
    "MAX_PRIORITY",
    "ROBOT_OPTIONS",
    "ROBOT_SUFFIXES",
    "Arm",
    "ConfigError",
    "ConfigErrors",
    "DdsProcess",
    "DeviceDriver",
    "InBoth",
    "InConst",
    "InVar",
    "InternalError",
    "LifecycleError",
    "LinkFullError",
    "ModuleError",
    "NoParams",
    "OperatorInput",
    "OutBoth",
    "OutConst",
    "OutVar",
    "OutputError",
    "ParamError",
    "PboError",
    "PortBasedObject",
    "PortKind",
    "PortSpec",
    "ResourceLimitError",
    "Status",
    "TableLayoutError",
    "Waypoints",
    "arm_gains",
    "arm_model",
    "attach_segment",
    "below_the_cycle",
    "create_segment",
    "format_channels",
    "inertia_range",
    "is_robot_file",
    "module_class",
    "open_log",
    "param",
    "process_below_the_cycle",
    "read_log",
    "registered_robot",
    "require_extra",
    "ros2_messages",
    "serve_dds_process",
    "sleep_while_cycling",
    "unlink_quietly",
]
