"""The simulated 8-channel, 16-bit analog-to-digital converter (TR §4.6.1), served by the plant.

Channels 0-5 carry vendor B's force/torque gauges, 6-7 the DAC's channels 0-1 (a loopback
cable): see `drivers.mujoco_arm.plant`. The plant converts every channel each step (+-10 V in
int16 counts, `VOLTS_PER_COUNT` = 0.305 mV); a read copies the lent channels of one conversion.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.io.board import BoardDriver
from drivers.mujoco_arm.registers import ADC_CHANNELS, VOLTS_PER_COUNT
from pbo_runtime import DeviceDriver


class Adc(BoardDriver):
    """Reads voltages of the channels it was lent. No options. Real-time safe reads."""

    PORTS = ADC_CHANNELS
    KIND = "adc"
    volts_per_count = VOLTS_PER_COUNT

    def __init__(self, registers: str, options: Mapping[str, Any], *, channels: tuple[int, ...] | None = None,
                 io: DeviceDriver | None = None) -> None:
        super().__init__(registers, options, channels=channels)
        self._adc = self._regs.adc
        self._counts = np.zeros(len(self.channels), dtype=np.int16)
        self._scale = np.full(len(self.channels), VOLTS_PER_COUNT)  # an array: a Python scalar would be boxed per call

    def read(self, volts_out: np.ndarray) -> int:
        """Fill volts_out (one float64 per lent channel, in channel order) from one conversion, V;
        return the plant step of that conversion (a new number: a new conversion)."""
        step = self._read_consistent(self._adc, self._counts)
        np.copyto(volts_out, self._counts)
        np.multiply(volts_out, self._scale, out=volts_out)
        return step

    def read_counts(self, counts_out: np.ndarray) -> int:
        """Fill counts_out (int16, one per lent channel) with the raw counts of one conversion."""
        return self._read_consistent(self._adc, counts_out)

    def _release_views(self) -> None:
        self.__dict__.pop("_adc", None)
