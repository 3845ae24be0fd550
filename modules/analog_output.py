"""Analog output (TR §4.6.1): a state variable driven onto the DAC channels a task was lent.

The task's YAML says which channels it uses: `resources: [{device: dac0, channels: 0-1}]`; the
input variable has one element per channel, in channel order. Turned off, the channels hold
their last value; killed, the driver sets them to 0 V. Real-time safe cycle: one driver call.
"""

from __future__ import annotations

from typing import ClassVar
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pbo_runtime import InVar, ModuleError, PortBasedObject, Status


@dataclass(frozen=True)
class AnalogOutputParams:
    device: str = "dac"  # the YAML device this task opens (a DAC, listed in its resources)


class AnalogOutput(PortBasedObject):
    """The lent DAC channels = v. Real-time safe cycle."""

    Params = AnalogOutputParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {"device": {"kind": "dac"}}

    v = InVar("v_out", shape=None, doc="voltages for the lent DAC channels, V, in channel order (one element each)")

    @classmethod
    def check_links(cls, params: Any, shapes: Mapping[str, tuple[int, ...]], dims: Mapping[str, int],
                    channels: Mapping[str, int], options: Mapping[str, Mapping[str, Any]]) -> None:
        """One element of v a channel the task opens (what init checks)."""
        lent, shape = channels.get(params.device), shapes.get("v")
        if lent is not None and shape is not None and math.prod(shape) != lent:
            raise ValueError(f"port 'v' links a variable of {math.prod(shape)} elements, but the task opens {lent} "
                             f"channels of device '{params.device}': one element a channel")

    def init(self, params: AnalogOutputParams) -> None:
        dac = self.open_device(params.device)
        if not callable(getattr(dac, "write", None)) or getattr(dac, "KIND", "") != "dac":
            raise ModuleError(f"device '{params.device}' is not a DAC; give it driver: dac")
        if self.v.size != len(dac.channels):
            raise ModuleError(f"the input variable has {self.v.size} elements, but device '{params.device}' lends "
                              f"{len(dac.channels)} channels {list(dac.channels)}: make them agree")
        self._write = dac.write
        self._flat = self.v.reshape(-1)

    def on(self) -> None:
        self._write(self._flat)

    def cycle(self) -> Status:
        self._write(self._flat)
        return Status.CONTINUE
