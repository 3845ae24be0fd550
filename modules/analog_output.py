"""Analog output (TR §4.6.1): a state variable driven onto the DAC channels a task was lent.

The task's YAML says which channels it uses: `resources: [{device: dac0, channels: 0-1}]`; the
input variable has one element per channel, in channel order. Turned off, the channels hold
their last value; killed, the driver sets them to 0 V. Real-time safe cycle: one driver call.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from modules._channels import check_one_element_a_channel, open_channels
from pbo_runtime import InVar, PortBasedObject, Status


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
        check_one_element_a_channel(params.device, shapes, channels)

    def init(self, params: AnalogOutputParams) -> None:
        dac = open_channels(self, params.device, "dac", "write", "input", self.v.size)
        self._write = dac.write
        self._flat = self.v.reshape(-1)

    def on(self) -> None:
        self._write(self._flat)

    def cycle(self) -> Status:
        self._write(self._flat)
        return Status.CONTINUE
