"""Analog input (TR §4.6.1): the voltages of the ADC channels a task was lent, as a state variable.

The task's YAML says which channels it uses: `resources: [{device: adc0, channels: 6-7}]`; the
output variable has one element per channel, in channel order. Real-time safe cycle: one driver call.
"""

from __future__ import annotations

from typing import ClassVar
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pbo_runtime import ModuleError, OutVar, PortBasedObject, Status


@dataclass(frozen=True)
class AnalogInputParams:
    device: str = "adc"  # the YAML device this task opens (an ADC, listed in its resources)


class AnalogInput(PortBasedObject):
    """v = the lent ADC channels' voltages. Real-time safe cycle."""

    Params = AnalogInputParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {"device": {"kind": "adc"}}

    v = OutVar("v_in", shape=None, doc="voltages of the lent ADC channels, V, in channel order (one element each)")

    @classmethod
    def check_links(cls, params: Any, shapes: Mapping[str, tuple[int, ...]], dims: Mapping[str, int],
                    channels: Mapping[str, int], options: Mapping[str, Mapping[str, Any]]) -> None:
        """One element of v a channel the task opens (what init checks)."""
        lent, shape = channels.get(params.device), shapes.get("v")
        if lent is not None and shape is not None and math.prod(shape) != lent:
            raise ValueError(f"port 'v' links a variable of {math.prod(shape)} elements, but the task opens {lent} "
                             f"channels of device '{params.device}': one element a channel")

    def init(self, params: AnalogInputParams) -> None:
        adc = self.open_device(params.device)
        if not callable(getattr(adc, "read", None)) or getattr(adc, "KIND", "") != "adc":
            raise ModuleError(f"device '{params.device}' is not an ADC; give it driver: adc")
        if self.v.size != len(adc.channels):
            raise ModuleError(f"the output variable has {self.v.size} elements, but device '{params.device}' lends "
                              f"{len(adc.channels)} channels {list(adc.channels)}: make them agree")
        self._read = adc.read
        self._flat = self.v.reshape(-1)

    def cycle(self) -> Status:
        self._read(self._flat)
        return Status.CONTINUE
