"""What the analog modules share: a task's port has one element a channel of the device it was lent."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from pbo_runtime import ModuleError, PortBasedObject


def check_one_element_a_channel(device: str, shapes: Mapping[str, tuple[int, ...]], channels: Mapping[str, int]) -> None:
    """ValueError when port 'v' links a variable whose size is not the number of channels lent (the checker's check)."""
    lent, shape = channels.get(device), shapes.get("v")
    if lent is not None and shape is not None and math.prod(shape) != lent:
        raise ValueError(f"port 'v' links a variable of {math.prod(shape)} elements, but the task opens {lent} "
                         f"channels of device '{device}': one element a channel")


def open_channels(module: PortBasedObject, device: str, kind: str, method: str, direction: str, size: int) -> Any:
    """The lent device, refused unless it is of `kind`, has `method` and lends `size` channels (init's check)."""
    opened = module.open_device(device)
    if not callable(getattr(opened, method, None)) or getattr(opened, "KIND", "") != kind:
        raise ModuleError(f"device '{device}' is not a{'n' if kind == 'adc' else ''} {kind.upper()}; give it driver: {kind}")
    if size != len(opened.channels):
        raise ModuleError(f"the {direction} variable has {size} elements, but device '{device}' lends "
                          f"{len(opened.channels)} channels {list(opened.channels)}: make them agree")
    return opened
