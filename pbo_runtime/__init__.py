"""pbo-runtime: dynamically reconfigurable real-time control from port-based objects.

The names module, driver and plant authors import; everything else lives in the wings
(objects/, config/, table/, task/, ...) and may change without notice.
"""

from __future__ import annotations

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
from pbo_runtime.links.message_link import MAX_PRIORITY, LinkFullError
from pbo_runtime.links.ros2 import ros2_messages
from pbo_runtime.objects.arm import ARM_COLUMNS, EE_COLUMNS, GRAVITY, ROBOT_OPTIONS, ROBOT_SUFFIXES, Arm, arm_model, is_robot_file
from pbo_runtime.objects.driver import DeviceDriver
from pbo_runtime.objects.module import NoParams, PortBasedObject, Status
from pbo_runtime.objects.ports import ANY_DTYPE, InBoth, InConst, InVar, OutBoth, OutConst, OutVar, PortKind, PortSpec
from pbo_runtime.objects.ranges import param
from pbo_runtime.objects.registry import installed_version, module_class, registered_robot
from pbo_runtime.objects.waypoints import Waypoints
from pbo_runtime.reports.data_log import open_log, read_log
from pbo_runtime.objects.waits import sleep_while_cycling
from pbo_runtime.objects.helper_threads import below_the_cycle

__version__ = installed_version()

__all__ = [
    "ANY_DTYPE",
    "ARM_COLUMNS",
    "Arm",
    "EE_COLUMNS",
    "GRAVITY",
    "ROBOT_OPTIONS",
    "ROBOT_SUFFIXES",
    "MAX_PRIORITY",
    "ConfigError",
    "ConfigErrors",
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
    "arm_model",
    "attach_segment",
    "below_the_cycle",
    "create_segment",
    "format_channels",
    "is_robot_file",
    "module_class",
    "open_log",
    "param",
    "read_log",
    "registered_robot",
    "require_extra",
    "ros2_messages",
    "sleep_while_cycling",
    "unlink_quietly",
]
