"""Analog input (TR §4.6.1): the voltages of the ADC channels a task was lent, as a state variable.

The task's YAML says which channels it uses: `resources: [{device: adc0, channels: 6-7}]`; the
output variable has one element per channel, in channel order. Real-time safe cycle: one driver call.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from modules._channels import check_one_element_a_channel, open_channels
from pbo_runtime import OutVar, PortBasedObject, Status


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
        check_one_element_a_channel(params.device, shapes, channels)

    def init(self, params: AnalogInputParams) -> None:
        adc = open_channels(self, params.device, "adc", "read", "output", self.v.size)
        self._read = adc.read
        self._flat = self.v.reshape(-1)

    def cycle(self) -> Status:
        self._read(self._flat)
        return Status.CONTINUE
