"""pbo-runtime: dynamically reconfigurable real-time control from port-based objects.

The names a module author needs; everything else lives in private modules.
"""

from __future__ import annotations

from pbo_runtime.errors import (
    ConfigError,
    ConfigErrors,
    InternalError,
    LifecycleError,
    ModuleError,
    ParamError,
    PboError,
    TableLayoutError,
)
from pbo_runtime.objects.module import NoParams, PortBasedObject, Status
from pbo_runtime.objects.ports import InBoth, InConst, InVar, OutBoth, OutConst, OutVar, PortKind, PortSpec

__all__ = [
    "ConfigError",
    "ConfigErrors",
    "InBoth",
    "InConst",
    "InVar",
    "InternalError",
    "LifecycleError",
    "ModuleError",
    "NoParams",
    "OutBoth",
    "OutConst",
    "OutVar",
    "ParamError",
    "PboError",
    "PortBasedObject",
    "PortKind",
    "PortSpec",
    "Status",
    "TableLayoutError",
]
