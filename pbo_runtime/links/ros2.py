"""The door to the ROS 2 messages for modules and drivers: `ros2_messages`, imported only when asked."""

from __future__ import annotations

from types import ModuleType

from pbo_runtime.errors import require_extra


def ros2_messages(what: str) -> ModuleType:
    """`pbo_runtime.links.ros2_messages` (the ROS 2 types, topic names, QoS), or MissingExtra saying
    that `what` needs the 'ros2' extra: call it in `init`, never at import (the core has no cyclonedds)."""
    require_extra("cyclonedds", what)
    from pbo_runtime.links import ros2_messages as messages

    return messages
